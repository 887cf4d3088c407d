"""Fusing a split's beliefs along its flights (benchmark.evaluation.sequence), on synthetic flights
whose truth, wrong matches and odometry noise are known."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from benchmark.evaluation.fusion import CircularGrid, OdometryNoise, gaussian_belief
from benchmark.evaluation.sequence import (
    FusionSettings,
    SplitFrames,
    flight_rows,
    fuse_split,
    summarize_sequence,
)

GRID = CircularGrid(720)
NOISE = OdometryNoise()  # the yardstick: 0.2 deg/s bias, 0.2 deg per step, 3 % scale


def _wrap(a: np.ndarray) -> np.ndarray:
    return np.angle(np.exp(1j * a))


def around(hats: np.ndarray):
    """A position belief function: a 20 m Gaussian around each row's ``hats (N, 2)``."""
    hats = torch.as_tensor(hats, dtype=torch.float64)
    return lambda rows, grid: gaussian_belief(grid, hats[rows.clamp_min(0)], 20.0)


def synthetic_split(
    n_flights: int = 6,
    samples: int = 32,
    dt: float = 2.0,
    outliers: float = 0.3,
    kappa: float = 60.0,
    seed: int = 0,
    noise: OdometryNoise = NOISE,
) -> SplitFrames:
    """Flights turning slowly at ~10 m/s; a fraction ``outliers`` of frames believes a random yaw
    and a random position; odometry drawn with ``noise`` in the levelled frame."""
    rng = np.random.default_rng(seed)
    rows = []
    for f in range(n_flights):
        yaw = _wrap(rng.uniform(-np.pi, np.pi) + np.cumsum(rng.normal(0, 0.08, samples)))
        travel = yaw + rng.uniform(-np.pi, np.pi)
        step = 10.0 * dt * np.stack([-np.sin(travel), np.cos(travel)], axis=1)  # yaw 0 = north
        pos = rng.uniform(-200, 200, 2) + np.concatenate([[[0, 0]], np.cumsum(step[1:], 0)])
        bias, scale = rng.normal(0, noise.gyro_bias_sigma), rng.normal(0, noise.scale_sigma)
        dyaw = _wrap(np.diff(yaw) + bias * dt + rng.normal(0, noise.yaw_walk_sigma, samples - 1))
        d_nav = np.diff(pos, axis=0)
        c, s = np.cos(yaw[:-1]), np.sin(yaw[:-1])  # Rz(-yaw_prev) d_nav: the levelled frame
        level = np.stack([c * d_nav[:, 0] + s * d_nav[:, 1], -s * d_nav[:, 0] + c * d_nav[:, 1]], 1)
        level = (1 + scale) * level + rng.normal(0, noise.position_step_sigma, level.shape)
        wrong = rng.random(samples) < outliers
        yaw_hat = np.where(
            wrong, rng.uniform(-np.pi, np.pi, samples), yaw + rng.normal(0, 0.1, samples)
        )
        pos_hat = np.where(wrong[:, None], rng.uniform(-400, 400, (samples, 2)),
                           pos + rng.normal(0, 15.0, (samples, 2)))  # fmt: skip
        rows.append(dict(flight=np.full(samples, 100 + f), time_s=np.arange(samples) * dt + 7.0,
                         yaw=yaw, yaw_hat=_wrap(yaw_hat), pos=pos, pos_hat=pos_hat,
                         dyaw=np.concatenate([[np.nan], dyaw]),
                         dxy=np.concatenate([[[np.nan, np.nan]], level])))  # fmt: skip
    cat = {k: np.concatenate([r[k] for r in rows]) for k in rows[0]}
    order = rng.permutation(len(cat["flight"]))  # any row order: fuse_split sorts by flight, time
    cat = {k: v[order] for k, v in cat.items()}
    n = len(order)
    psi = GRID.centres()
    beliefs = kappa * (torch.cos(psi[None] - torch.as_tensor(cat["yaw_hat"])[:, None]) - 1)
    zeros = np.zeros(n)
    return SplitFrames(
        flight=cat["flight"], time_s=cat["time_s"], yaw_beliefs=beliefs,
        yaw_hat=cat["yaw_hat"], pitch_hat=zeros - 0.3, roll_hat=zeros,
        position_hat=cat["pos_hat"],
        position_log_belief=around(cat["pos_hat"]),
        odo_dyaw=cat["dyaw"], odo_dxy=cat["dxy"], footprint_m=np.tile([2000.0, 1000.0], (n, 1)),
        yaw=cat["yaw"], pitch=zeros - 0.3, roll=zeros, position=cat["pos"],
        index=np.arange(n),
    )  # fmt: skip


def _by_mode(table):
    return {m: part for m, part in table.groupby("mode")}


class TestFlightRows:
    def test_groups_by_flight_in_time_order(self):
        flight = np.array([3, 1, 3, 1, 2])
        time = np.array([5.0, 2.0, 1.0, 0.0, 9.0])
        rows = flight_rows(flight, time)
        assert [r.tolist() for r in rows] == [[3, 1], [4], [2, 0]]


class TestFuseSplit:
    def test_fusion_recovers_the_heading_through_wrong_matches(self):
        frames = synthetic_split()
        table = fuse_split(frames, NOISE)
        s = summarize_sequence(table)
        # a third of the frames are wrong (uniform yaw: mean error ~ 30 deg over all frames)
        assert s["seq_frame_dpsi_deg"] > 20
        assert s["seq_filter_dpsi_deg"] < 0.5 * s["seq_frame_dpsi_deg"]
        assert s["seq_smooth_dpsi_deg"] < 3.0
        assert s["seq_smooth_acc10"] > 0.97
        assert s["seq_smooth_median_horizontal_m"] < s["seq_frame_median_horizontal_m"]
        assert s["seq_smooth_median_horizontal_m"] < 15.0

    def test_frame_mode_is_the_heads_own_estimate(self):
        frames = synthetic_split(n_flights=2, samples=8)
        frame = _by_mode(fuse_split(frames, NOISE))["frame"].set_index("index").sort_index()
        truth = np.abs(_wrap(frames.yaw_hat - frames.yaw))
        np.testing.assert_allclose(frame["dpsi_deg"].to_numpy(), np.degrees(truth), atol=1e-9)
        # same pitch and roll as the truth: the geodesic error is the yaw error
        np.testing.assert_allclose(frame["dphi_deg"].to_numpy(), np.degrees(truth), atol=1e-6)
        d = np.linalg.norm(frames.position_hat - frames.position, axis=1)
        np.testing.assert_allclose(frame["horizontal_m"].to_numpy(), d, atol=1e-9)

    def test_heading_only_leaves_the_heading_bit_identical(self):
        frames = synthetic_split(n_flights=3, samples=12)
        full, heading = fuse_split(frames, NOISE), fuse_split(frames, NOISE, position=False)
        assert list(full.columns) == list(heading.columns)
        for col in ("index", "flight", "sample", "t_s", "mode", "yaw_hat_deg", "dpsi_deg",
                    "dphi_deg"):  # fmt: skip
            assert full[col].equals(heading[col]), col
        fused = heading["mode"] != "frame"
        for col in ("E_hat_m", "N_hat_m", "horizontal_m"):
            assert heading.loc[fused, col].isna().all()
            assert heading.loc[~fused, col].equals(full.loc[~fused, col])  # the head's own

    def test_perfect_beliefs_and_exact_odometry_give_the_truth(self):
        zero = OdometryNoise(0.0, 0.0, 0.0, 0.0)
        frames = synthetic_split(n_flights=2, samples=10, outliers=0.0, kappa=400.0, noise=zero)
        exact = SplitFrames(**{**frames.__dict__, "yaw_hat": frames.yaw,
                               "yaw_beliefs": 400.0 * (torch.cos(GRID.centres()[None]
                                                      - torch.as_tensor(frames.yaw)[:, None]) - 1),
                               "position_hat": frames.position,
                               "position_log_belief": around(frames.position)})  # fmt: skip
        tiny = OdometryNoise(1e-4, 1e-4, 1e-4, 0.2)  # the filters need a blur of some width
        table = fuse_split(exact, tiny)
        for mode in ("filter", "smooth"):
            part = table[table["mode"] == mode]
            assert part["dpsi_deg"].max() < 0.05
            # a flight's first filtered sample is its own belief alone: a 20 m Gaussian mixed
            # with the uniform share, whose log is not a parabola, so the refined MAP between the
            # 10 m cells is off by up to a quarter cell; later samples have the odometry too
            assert part["horizontal_m"].max() < 3.0
            assert part.loc[part["sample"] > 0, "horizontal_m"].median() < 0.5

    def test_filter_never_reads_a_later_sample(self):
        frames = synthetic_split(n_flights=3, samples=12)
        rows = flight_rows(frames.flight, frames.time_s)
        last = rows[1][-1]  # the last sample of the second flight
        changed = frames.yaw_beliefs.clone()
        changed[last] = torch.roll(changed[last], 200)
        hat = frames.position_hat.copy()
        hat[last] += 300.0
        odo = frames.odo_dyaw.copy()
        odo[last] += 0.5
        later = SplitFrames(**{**frames.__dict__, "yaw_beliefs": changed, "position_hat": hat,
                               "position_log_belief": around(hat), "odo_dyaw": odo})  # fmt: skip
        a = fuse_split(frames, NOISE)
        b = fuse_split(later, NOISE)
        earlier = (a["mode"] == "filter") & (a["index"] != last)
        cols = ["yaw_hat_deg", "E_hat_m", "N_hat_m"]
        assert (a.loc[earlier, cols].to_numpy() == b.loc[earlier, cols].to_numpy()).all()
        assert not (a.loc[a["index"] == last, cols].to_numpy()
                    == b.loc[b["index"] == last, cols].to_numpy()).all()  # fmt: skip
        # the smoother reads the whole flight: earlier samples of that flight may move
        assert b[(b["mode"] == "smooth")].shape == a[(a["mode"] == "smooth")].shape

    def test_flights_of_other_lengths_are_padded_not_mixed(self):
        long = synthetic_split(n_flights=2, samples=12, seed=3)
        short_rows = flight_rows(long.flight, long.time_s)[0][:4]  # keep 4 samples of flight 1
        keep = np.concatenate([short_rows, flight_rows(long.flight, long.time_s)[1]])
        cut = SplitFrames(
            **{
                k: (
                    v[keep]
                    if isinstance(v, np.ndarray | torch.Tensor) and len(v) == len(long.flight)
                    else v
                )
                for k, v in long.__dict__.items()
            }
        )
        alone = SplitFrames(**{k: (v[short_rows] if isinstance(v, np.ndarray | torch.Tensor)
                                   and len(v) == len(long.flight) else v)
                               for k, v in long.__dict__.items()})  # fmt: skip
        both, single = fuse_split(cut, NOISE), fuse_split(alone, NOISE)
        for mode in ("filter", "smooth"):
            x = both[(both["mode"] == mode) & both["index"].isin(alone.index)]
            y = single[single["mode"] == mode]
            np.testing.assert_allclose(x["yaw_hat_deg"].to_numpy(), y["yaw_hat_deg"].to_numpy(),
                                       atol=1e-9)  # fmt: skip

    def test_bad_odometry_names_flight_and_sample(self):
        frames = synthetic_split(n_flights=1, samples=5)
        rows = flight_rows(frames.flight, frames.time_s)[0]
        odo = frames.odo_dyaw.copy()
        odo[rows[2]] = np.nan
        bad = SplitFrames(**{**frames.__dict__, "odo_dyaw": odo})
        with pytest.raises(ValueError, match=r"flight 100, sample 2"):
            fuse_split(bad, NOISE)

    def test_settings_are_checked(self):
        with pytest.raises(ValueError, match="outlier_weight"):
            FusionSettings(outlier_weight=1.5)
        frames = synthetic_split(n_flights=1, samples=3)
        with pytest.raises(ValueError, match="bins"):
            fuse_split(frames, NOISE, FusionSettings(yaw_bins=360))


class TestSummarizeSequence:
    def test_keys_and_values_against_numpy(self):
        table = fuse_split(synthetic_split(n_flights=2, samples=6), NOISE)
        s = summarize_sequence(table)
        part = table[table["mode"] == "smooth"]
        assert s["seq_smooth_dphi_deg"] == pytest.approx(part["dphi_deg"].mean())
        assert s["seq_smooth_acc10"] == pytest.approx(np.mean(part["dphi_deg"] <= 10))
        assert s["seq_frame_median_horizontal_m"] == pytest.approx(
            np.median(table[table["mode"] == "frame"]["horizontal_m"])
        )
        assert math.isfinite(s["seq_filter_median_dpsi_deg"])
