"""The odometry every UAV sample carries (benchmark.sim.odometry, issue 39 item 1).

References are independent of the module: true increments from scipy ``Rotation`` and complex
arguments on the pose columns, noise figures recovered from the draws by plain statistics.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

import benchmark.data as data
import benchmark.sim as sim
from benchmark.data import DatasetError, require_odometry
from benchmark.data.profiles import DATA_PROFILES, ODOMETRY_FIELDS
from benchmark.sim.odometry import (
    ODOMETRY_COLUMNS,
    ODOMETRY_STREAM,
    PROFILE_FIELDS,
    OdometryNoise,
    flight_odometry,
    odometry_noise,
    odometry_rng,
    plan_odometry,
)

ZERO = OdometryNoise(0.0, 0.0, 0.0, 0.0)


def wrap(a):
    return np.angle(np.exp(1j * np.asarray(a)))


def true_increments(E, N, U, yaw):
    """(dyaw (K-1,), levelled displacement (K-1, 3)) from scipy: Rz(yaw_prev)^-1 d_nav."""
    d_nav = np.stack([np.diff(E), np.diff(N), np.diff(U)], axis=1)
    level = Rotation.from_euler("z", yaw[:-1, None]).inv().apply(d_nav)
    return wrap(np.diff(yaw)), level


def random_flights(B, K, dt, seed=0):
    """A table of B flights of K samples (any headings, ~20 m steps, pitch and roll set)."""
    rng = np.random.default_rng(seed)
    yaw = wrap(rng.uniform(-np.pi, np.pi, (B, 1)) + np.cumsum(rng.uniform(-0.4, 0.4, (B, K)), 1))
    steps = rng.normal(0.0, 12.0, (B, K, 3)) * np.array([1.0, 1.0, 0.1])
    pos = np.cumsum(steps, axis=1) + rng.uniform(-500, 500, (B, 1, 3))
    return pd.DataFrame(
        dict(
            flight=np.repeat(np.arange(B), K),
            frame=np.tile(np.arange(K) * 60, B),
            time_s=np.tile(np.arange(K) * dt, B),
            E=pos[..., 0].ravel(), N=pos[..., 1].ravel(), U=pos[..., 2].ravel(),
            yaw=yaw.ravel(),
            pitch=rng.uniform(-0.8, 0.0, B * K), roll=rng.uniform(-0.2, 0.2, B * K),
        )
    )  # fmt: skip


def columns_of(table):
    return {k: table[k].to_numpy() for k in ("E", "N", "U", "yaw", "time_s")}


def one_flight(E, N, U, yaw, dt=2.0, noise=ZERO):
    K = len(yaw)
    t = np.arange(K) * dt
    return flight_odometry(
        np.asarray(E, float), np.asarray(N, float), np.asarray(U, float), np.asarray(yaw, float),
        t, noise=noise, rng=np.random.default_rng(0),
    )  # fmt: skip


class TestOdometryNoise:
    def test_defaults_are_the_issue_yardstick(self):
        n = OdometryNoise()
        assert n.gyro_bias_sigma == math.radians(0.2) and n.yaw_walk_sigma == math.radians(0.2)
        assert n.scale_sigma == 0.03 and n.position_step_sigma == 0.5

    def test_evaluation_keeps_the_same_class(self):
        from benchmark.evaluation.fusion import OdometryNoise as Fusion
        from benchmark.evaluation.fusion_odometry import OdometryNoise as Module

        assert Fusion is OdometryNoise and Module is OdometryNoise
        assert sim.OdometryNoise is OdometryNoise and data.OdometryNoise is OdometryNoise

    @pytest.mark.parametrize("bad", [-1e-3, math.nan, math.inf])
    def test_bad_figure_named(self, bad):
        with pytest.raises(ValueError, match="scale_sigma must be finite and >= 0"):
            OdometryNoise(scale_sigma=bad)


class TestOdometryNoiseFromProfile:
    def test_degrees_at_the_edge_radians_inside(self):
        p = dataclasses.replace(
            DATA_PROFILES["smoke"], odometry_gyro_bias_dps=0.5, odometry_yaw_walk_deg=0.25,
            odometry_scale_sigma=0.04, odometry_step_sigma_m=0.7,
        )  # fmt: skip
        want = OdometryNoise(math.radians(0.5), math.radians(0.25), 0.04, 0.7)
        assert odometry_noise(p) == want
        assert odometry_noise(p.to_dict()) == want  # a manifest's profile dict

    def test_profiles_state_at_least_the_yardstick(self):
        for p in DATA_PROFILES.values():
            n = odometry_noise(p)
            assert n.gyro_bias_sigma >= math.radians(0.2) and n.yaw_walk_sigma >= math.radians(0.2)
            assert n.scale_sigma >= 0.03

    def test_old_manifest_names_the_missing_fields(self):
        old = {k: v for k, v in DATA_PROFILES["smoke"].to_dict().items() if k not in PROFILE_FIELDS}
        with pytest.raises(ValueError, match=r"odometry_gyro_bias_dps.*re-simulate"):
            odometry_noise(old)

    def test_fields_and_columns_agree_with_the_data_package(self):
        assert PROFILE_FIELDS == ODOMETRY_FIELDS
        assert ODOMETRY_COLUMNS == data.ODOMETRY_COLUMNS == sim.ODOMETRY_COLUMNS


class TestFlightOdometry:
    def test_convention_north_at_yaw_zero_is_forward(self):
        odo = one_flight([0, 0, 0], [0, 10, 25], [100, 100, 101], [0, 0, 0])
        np.testing.assert_allclose(odo[1:, 1:], [[0, 10, 0], [0, 15, 1]], atol=1e-12)
        np.testing.assert_allclose(odo[1:, 0], 0.0)

    def test_convention_west_at_yaw_plus_90_is_forward(self):
        yaw = [math.pi / 2] * 3  # yaw +90 deg looks west (DEVELOPERS.md)
        odo = one_flight([0, -10, -20], [5, 5, 5], [0, 0, 0], yaw)
        np.testing.assert_allclose(odo[1:, 1:], [[0, 10, 0], [0, 10, 0]], atol=1e-12)

    def test_convention_x_is_right(self):
        # yaw 0 looks north, so east is right (+x); at yaw +90 (west) north is right
        assert one_flight([0, 7], [0, 0], [0, 0], [0, 0])[1, 1] == pytest.approx(7.0)
        right = one_flight([0, 0], [0, 7], [0, 0], [math.pi / 2] * 2)[1, 1:]
        np.testing.assert_allclose(right, [7, 0, 0], atol=1e-12)

    def test_convention_heading_increment_wraps(self):
        # 179 deg -> -179 deg is a turn of +2 deg (counter-clockwise), not -358
        odo = one_flight([0, 0], [0, 0], [0, 0], np.radians([179.0, -179.0]))
        assert odo[1, 0] == pytest.approx(math.radians(2.0))

    def test_convention_levelled_frame_ignores_pitch_and_roll(self):
        # The levelled frame is the body frame with pitch and roll removed: R_b^n Ry^T Rx^T = Rz.
        yaw, pitch, roll = 0.7, -0.6, 0.15
        body = Rotation.from_euler("ZXY", [yaw, pitch, roll])
        level = body * Rotation.from_euler("ZXY", [0.0, pitch, roll]).inv()
        step = level.apply([0.0, 12.0, -1.0])  # forward and down in the levelled frame
        odo = one_flight([0, step[0]], [0, step[1]], [0, step[2]], [yaw, yaw])
        np.testing.assert_allclose(odo[1, 1:], [0.0, 12.0, -1.0], atol=1e-12)

    def test_zero_noise_equals_true_increments(self):
        table = random_flights(3, 9, 0.5, seed=4)
        for _, rows in table.groupby("flight"):
            E, N, U, yaw = (rows[k].to_numpy() for k in ("E", "N", "U", "yaw"))
            odo = one_flight(E, N, U, yaw, dt=0.5)
            dyaw, level = true_increments(E, N, U, yaw)
            np.testing.assert_allclose(odo[1:, 0], dyaw, atol=1e-12)
            np.testing.assert_allclose(odo[1:, 1:], level, atol=1e-9)

    def test_first_sample_nan_and_shape(self):
        odo = one_flight([0, 1, 2], [0, 0, 0], [0, 0, 0], [0, 0, 0], noise=OdometryNoise())
        assert odo.shape == (3, 4) and np.isnan(odo[0]).all() and np.isfinite(odo[1:]).all()
        single = one_flight([0], [0], [0], [0])
        assert single.shape == (1, 4) and np.isnan(single).all()

    def test_measured_heading_stays_wrapped(self):
        noise = OdometryNoise(gyro_bias_sigma=1.0, yaw_walk_sigma=1.0)
        yaw = np.radians([170.0, -175.0, 178.0, -179.0] * 5)
        odo = flight_odometry(
            np.zeros(20), np.zeros(20), np.zeros(20), yaw, np.arange(20.0),
            noise=noise, rng=np.random.default_rng(3),
        )  # fmt: skip
        assert np.all(odo[1:, 0] > -math.pi) and np.all(odo[1:, 0] <= math.pi)

    def test_bad_input(self):
        with pytest.raises(ValueError, match="time_s must increase"):
            flight_odometry(
                np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3), np.array([0.0, 1.0, 1.0]),
                noise=ZERO, rng=np.random.default_rng(0),
            )  # fmt: skip
        with pytest.raises(ValueError, match="N must be 1-D of length K"):
            flight_odometry(
                np.zeros(3), np.zeros(2), np.zeros(3), np.zeros(3), np.arange(3.0),
                noise=ZERO, rng=np.random.default_rng(0),
            )  # fmt: skip
        with pytest.raises(ValueError, match="yaw must be finite"):
            flight_odometry(
                np.zeros(2), np.zeros(2), np.zeros(2), np.array([0.0, math.nan]), np.arange(2.0),
                noise=ZERO, rng=np.random.default_rng(0),
            )  # fmt: skip


class TestPlanOdometry:
    def test_noise_matches_the_stated_figures(self):
        """Over 4000 flights the draws give back the profile's stated figures: the per-flight
        gyro bias (deg/s), the heading noise per step (deg), the per-flight scale error and the
        per-step displacement noise (m), each within sampling tolerance."""
        profile = DATA_PROFILES["quick"]
        B, K, dt = 4000, 17, 2.0
        table = random_flights(B, K, dt, seed=1)
        odo = plan_odometry(
            table.flight, table.frame, columns_of(table), odometry_noise(profile), 5
        )
        odo = odo.reshape(B, K, 4)[:, 1:]
        E, N, U, yaw = (table[k].to_numpy().reshape(B, K) for k in ("E", "N", "U", "yaw"))
        truth = [true_increments(E[b], N[b], U[b], yaw[b]) for b in range(B)]
        dyaw = np.stack([t[0] for t in truth])
        level = np.stack([t[1] for t in truth])
        steps = K - 1

        # heading: residual = b dt + n_k; flight mean / dt estimates b (plus n's mean / dt)
        r = np.degrees(wrap(odo[..., 0] - dyaw))
        bias_hat = r.mean(axis=1) / dt
        walk = profile.odometry_yaw_walk_deg
        want = math.hypot(profile.odometry_gyro_bias_dps, walk / (dt * math.sqrt(steps)))
        assert bias_hat.std() == pytest.approx(want, rel=0.05)  # sd of a sd: 1.1 %
        assert abs(bias_hat.mean()) < 4 * want / math.sqrt(B)
        within = r - r.mean(axis=1, keepdims=True)
        assert math.sqrt((within**2).sum() / (B * (steps - 1))) == pytest.approx(walk, rel=0.03)

        # displacement: (1 + s) d + m; least squares per flight gives s (plus d.m / |d|^2)
        meas = odo[..., 1:]
        dd = (level**2).sum(axis=(1, 2))
        scale_hat = (level * meas).sum(axis=(1, 2)) / dd - 1.0
        sigma_m = profile.odometry_step_sigma_m
        want = math.sqrt(profile.odometry_scale_sigma**2 + sigma_m**2 * np.mean(1.0 / dd))
        assert scale_hat.std() == pytest.approx(want, rel=0.05)
        assert abs(scale_hat.mean()) < 4 * want / math.sqrt(B)
        resid = meas - (1.0 + scale_hat)[:, None, None] * level
        dof = B * (3 * steps - 1)
        assert math.sqrt((resid**2).sum() / dof) == pytest.approx(sigma_m, rel=0.03)
        for axis in range(3):  # the same noise on every axis of the levelled frame
            assert resid[..., axis].std() == pytest.approx(sigma_m, rel=0.05)

    def test_zero_noise_equals_true_increments(self):
        table = random_flights(20, 6, 0.5, seed=2)
        odo = plan_odometry(table.flight, table.frame, columns_of(table), ZERO, 0)
        for f, rows in table.groupby("flight"):
            dyaw, level = true_increments(*(rows[k].to_numpy() for k in ("E", "N", "U", "yaw")))
            got = odo[rows.index.to_numpy()]
            assert np.isnan(got[0]).all(), f
            np.testing.assert_allclose(got[1:, 0], dyaw, atol=1e-12)
            np.testing.assert_allclose(got[1:, 1:], level, atol=1e-9)

    def test_rows_in_any_order(self):
        table = random_flights(6, 5, 2.0, seed=3)
        odo = plan_odometry(table.flight, table.frame, columns_of(table), OdometryNoise(), 9)
        order = np.random.default_rng(0).permutation(len(table))
        shuffled = table.iloc[order].reset_index(drop=True)
        again = plan_odometry(shuffled.flight, shuffled.frame, columns_of(shuffled),
                              OdometryNoise(), 9)  # fmt: skip
        np.testing.assert_array_equal(again, odo[order])

    def test_deterministic_seeded_and_per_flight(self):
        table = random_flights(6, 5, 2.0, seed=3)
        noise = OdometryNoise()

        def run(t, seed=9):
            return plan_odometry(t.flight, t.frame, columns_of(t), noise, seed)

        odo = run(table)
        np.testing.assert_array_equal(run(table), odo)
        assert not np.allclose(run(table, seed=10)[5:], odo[5:])
        # one flight's own generator: (seed, ODOMETRY_STREAM, flight)
        rows = table.flight == 2
        ss = np.random.SeedSequence(9, spawn_key=(ODOMETRY_STREAM, 2))
        own = flight_odometry(
            *(table.loc[rows, k].to_numpy() for k in ("E", "N", "U", "yaw", "time_s")),
            noise=noise, rng=np.random.default_rng(ss),
        )  # fmt: skip
        np.testing.assert_array_equal(odo[rows.to_numpy()], own)
        assert odometry_rng(9, 2).random() == np.random.default_rng(ss).random()
        # changing one flight (its poses, its length) leaves every other flight's odometry
        changed = table[~((table.flight == 2) & (table.frame == 240))].copy()
        changed.loc[changed.flight == 4, "E"] += 3.0
        other = run(changed.reset_index(drop=True))
        keep = ~changed.flight.isin([2, 4]).to_numpy()
        np.testing.assert_array_equal(other[keep], odo[changed.index.to_numpy()][keep])
        assert not np.array_equal(other[(changed.flight == 4).to_numpy()],
                                  odo[(table.flight == 4).to_numpy()])  # fmt: skip


class TestRequireOdometry:
    def test_returns_the_columns_in_order(self):
        table = pd.DataFrame({c: [float(k)] for k, c in enumerate(reversed(ODOMETRY_COLUMNS))})
        np.testing.assert_array_equal(require_odometry(table, "x.parquet"), [[3.0, 2.0, 1.0, 0.0]])

    def test_names_file_and_missing_columns(self):
        table = pd.DataFrame({"odo_dyaw": [0.0], "odo_dx": [0.0]})
        with pytest.raises(DatasetError, match=r"/data/pairs.parquet: .*\['odo_dy', 'odo_dz'\]"):
            require_odometry(table, "/data/pairs.parquet")
