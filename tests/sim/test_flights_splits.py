"""The dataset plan: split definitions, leakage, labels (benchmark.sim.splits)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pandas as pd
import pytest
import torch
from scipy.spatial.transform import Rotation

from benchmark.data.profiles import DATA_PROFILES
from benchmark.geometry import euler_to_rotmat, relative_rotation
from benchmark.sim.flights import FlightSpec
from benchmark.sim.odometry import ODOMETRY_COLUMNS, OdometryNoise
from benchmark.sim.seeds import city_seed, sample_seed
from benchmark.sim.splits import (
    CONFIRM_SPLITS,
    CONFIRMS,
    LEAK_ANGLE_DEG,
    LEAK_DIST_M,
    LONG_GROUPS,
    LONG_SPLITS,
    R_COLUMNS,
    _groups,
    make_plan,
    relative_labels,
)
from benchmark.sim.towns import TOWN_ROLES, town_list


class FlatCity:
    n_lights = 6

    def __init__(self, offset: float, centres: int = 3) -> None:
        self.offset = offset
        self.flight_centres = np.array([[400.0 * k, -250.0 * k] for k in range(centres)])

    def light_angles(self, k):
        return (2 * math.pi * k / self.n_lights, math.radians(20.0 + 5.0 * k))

    def ground_height(self, E, N):
        return self.offset + 0.01 * np.asarray(E) + 0.0 * np.asarray(N)

    def clearance(self, E, N):
        return self.ground_height(E, N) + 25.0


def small_profile(**kw):
    base = dataclasses.replace(
        DATA_PROFILES["smoke"], n_standard=60, n_generalized_test=10, n_flight_per_pitch=5,
        n_pitch_per_bin=4, n_height_train=20, n_height_test=8, samples_per_flight=5,
        n_towns=(4, 1, 2, 2), n_town_pairs=(20, 5, 10, 10),
    )  # fmt: skip
    return dataclasses.replace(base, **kw)


CITIES = {("oxford", "now"): FlatCity(10.0), ("cambridge", "now"): FlatCity(3.0, 2),
          ("london", "now"): FlatCity(30.0), ("industrial", "now"): FlatCity(50.0, 2),
          ("industrial", "earlier"): FlatCity(50.0, 2)}  # fmt: skip
_TOWNS = town_list(small_profile().n_towns, 7, confirm_draw=1) + town_list((4, 1, 2, 2), 8)
for _k, _town in enumerate(_TOWNS):
    CITIES[(_town.name, "now")] = FlatCity(float(_k), 1)


@pytest.fixture(scope="module")
def plan():
    return make_plan(small_profile(), CITIES, seed=7)


def flights_of(plan, split):
    return set(plan.pairs.loc[plan.pairs.split == split, "flight"])


class TestMakePlan:
    def test_split_names_and_counts(self, plan):
        p = small_profile()
        counts = plan.pairs.split.value_counts()
        assert counts["standard/train"] == 48 and counts["standard/val"] == 6
        assert counts["standard/test"] == 6 and counts["generalized/test"] == 10
        for name in ("flight/pitch0", "flight/pitch-10", "flight/pitch-50"):
            assert counts[name] == p.n_flight_per_pitch
        for name in ("pitch0to-10/test", "pitch-10to-20/test", "pitch-40to-50/test"):
            assert counts[name] == p.n_pitch_per_bin
        for h in p.sat_heights_m:
            # capped by the size of standard/test (6 pairs)
            assert counts[f"height{h:g}/train"] == 20 and counts[f"height{h:g}/test"] == 6

    def test_standard_splits_disjoint_by_flight(self, plan):
        tr, va, te = (flights_of(plan, f"standard/{s}") for s in ("train", "val", "test"))
        assert tr and va and te
        assert not (tr & va) and not (tr & te) and not (va & te)
        for name in plan.splits:
            if name.startswith("frames/"):  # the naive split shares flights on purpose
                continue
            if name.startswith("pitch") or name.endswith("/test"):
                assert not (flights_of(plan, name) & tr), name

    def test_no_near_identical_frames_across_train_and_test(self, plan):
        train = plan.pairs[plan.pairs.split == "standard/train"]
        for name in ("standard/val", "standard/test", "pitch-20to-30/test"):
            for r in plan.pairs[plan.pairs.split == name].itertuples():
                same = train[train.city == r.city]
                d = np.sqrt((same.E - r.E) ** 2 + (same.N - r.N) ** 2 + (same.U - r.U) ** 2)
                dyaw = np.abs(np.angle(np.exp(1j * (same.yaw - r.yaw))))
                dpitch = np.abs(same.pitch - r.pitch)
                near = (d < LEAK_DIST_M) & (dyaw < math.radians(LEAK_ANGLE_DEG))
                assert not np.any(near & (dpitch < math.radians(LEAK_ANGLE_DEG))), name

    def test_cities_per_split(self, plan):
        city = plan.pairs.groupby("split").city.agg(set)
        assert city["standard/train"] == {"oxford", "cambridge"}
        assert city["generalized/test"] == {"london"}
        assert city["flight/pitch-10"] == {"industrial"}
        for s in ("train", "val"):  # generalized train/val are the standard ones
            a = plan.pairs[plan.pairs.split == f"standard/{s}"].uav_index.to_numpy()
            b = plan.pairs[plan.pairs.split == f"generalized/{s}"].uav_index.to_numpy()
            np.testing.assert_array_equal(a, b)

    def test_flight_test_sets(self, plan):
        for pitch in (0.0, -10.0, -50.0):
            rows = plan.pairs[plan.pairs.split == f"flight/pitch{pitch:g}"]
            np.testing.assert_allclose(rows.pitch, math.radians(pitch))
            agl = rows.U - CITIES[("industrial", "now")].ground_height(rows.sat_E, rows.sat_N)
            assert agl.between(70.0, 90.0).all()
            sat = plan.sat.set_index("sat_index").loc[rows.sat_index]
            assert (sat.variant == "earlier").all() and (sat.footprint_E_m == 2500.0).all()
            uav = plan.uav.set_index("uav_index").loc[rows.uav_index]
            assert uav.camera_effects.all()
        assert not plan.uav[plan.uav.group.str.startswith("standard")].camera_effects.any()

    def test_held_out_flights_are_shorter_and_training_data_unchanged(self, plan):
        """eval_samples_per_flight shortens the held-out groups' flights (same pair counts, more
        flights); training splits and the flight-test analogue keep samples_per_flight. The
        training poses are those of the plan without the option; standard/train (numbered first)
        is identical in every column, while towns/train's flights get other global flight numbers
        and so other illumination draws (the same distribution, another draw)."""
        short = make_plan(small_profile(eval_samples_per_flight=2), CITIES, seed=7)
        per_flight = short.pairs.groupby(["split", "flight"]).size().groupby("split").max()
        for name in ("standard/val", "standard/test", "generalized/test", "pitch-10to-20/test",
                     "towns/val", "towns/test", "towns/london"):  # fmt: skip
            assert per_flight[name] <= 2, name
            n = (short.pairs.split == name).sum()
            assert n == (plan.pairs.split == name).sum()
            assert short.pairs.loc[short.pairs.split == name, "flight"].nunique() == -(-n // 2)
        for name in ("standard/train", "towns/train", "flight/pitch0"):
            assert per_flight[name] == 5, name

        def rows(p, name):
            return p.pairs[p.pairs.split == name].reset_index(drop=True)

        pd.testing.assert_frame_equal(rows(plan, "standard/train"), rows(short, "standard/train"))
        a, b = rows(plan, "towns/train"), rows(short, "towns/train")
        poses = ["E", "N", "U", "yaw", "pitch", "roll", "city", "R00", "dE", "dN", "dU"]
        pd.testing.assert_frame_equal(a[poses], b[poses])
        assert not a.flight.equals(b.flight) and not a.light.equals(b.light)

    def test_pitch_bins(self, plan):
        for hi, lo in ((0, -10), (-10, -20), (-20, -30), (-30, -40), (-40, -50)):
            rows = plan.pairs[plan.pairs.split == f"pitch{hi:g}to{lo:g}/test"]
            deg = np.degrees(rows.pitch)
            assert ((deg >= lo - 1e-9) & (deg <= hi + 1e-9)).all()

    def test_height_sweep(self, plan):
        std = {
            s: set(plan.pairs.loc[plan.pairs.split == f"standard/{s}", "uav_index"])
            for s in ("train", "test")
        }
        ref = None
        for h in small_profile().sat_heights_m:
            for part in ("train", "test"):
                rows = plan.pairs[plan.pairs.split == f"height{h:g}/{part}"]
                assert set(rows.uav_index) <= std[part]
                ground = np.where(rows.city == "oxford", 10.0, 3.0) + 0.01 * rows.sat_E
                np.testing.assert_allclose(rows.sat_U - ground, h)
                sat = plan.sat.set_index("sat_index").loc[rows.sat_index]
                np.testing.assert_allclose(sat.footprint_E_m, 2000.0 * h / 1000.0)
                np.testing.assert_allclose(sat.footprint_N_m, 1000.0 * h / 1000.0)
                if part == "train":  # every height uses the same UAV images
                    ids = rows.uav_index.to_numpy()
                    ref = ids if ref is None else ref
                    np.testing.assert_array_equal(ids, ref)

    def test_one_satellite_image_per_centre_and_height(self, plan):
        key = ["city", "variant", "centre", "height_m", "footprint_E_m"]
        assert not plan.sat.duplicated(key).any()
        std = plan.pairs[plan.pairs.split == "standard/train"]
        # 3 oxford + 2 cambridge centres -> 5 distinct satellite images at 1000 m
        assert std.sat_index.nunique() == 5

    def test_convention_translation_label(self, plan):
        p = plan.pairs
        for d, c in (("dE", "E"), ("dN", "N"), ("dU", "U")):
            np.testing.assert_allclose(p[d], p[c] - p[f"sat_{c}"])
        std = p[p.split == "standard/test"]
        np.testing.assert_allclose(std.sat_height_m, 1000.0)
        cen = CITIES[("oxford", "now")].flight_centres
        ox = std[std.city == "oxford"]
        np.testing.assert_allclose(ox[["sat_E", "sat_N"]].to_numpy(), cen[ox.centre.to_numpy()])

    def test_rotation_label_matches_scipy(self, plan):
        p = plan.pairs
        # R_b^n = Rz(yaw) Rx(pitch) Ry(roll): intrinsic z-x'-y'' in scipy ("ZXY").
        R_uav = Rotation.from_euler("ZXY", p[["yaw", "pitch", "roll"]].to_numpy()).as_matrix()
        R_sat = Rotation.from_euler("ZXY", [0.0, -math.pi / 2, 0.0]).as_matrix()
        expected = R_uav @ R_sat.T
        got = p[R_COLUMNS].to_numpy().reshape(-1, 3, 3)
        np.testing.assert_allclose(got, expected, atol=1e-12)
        np.testing.assert_allclose(
            p[["sat_yaw", "sat_pitch", "sat_roll"]], [[0.0, -math.pi / 2, 0.0]] * len(p)
        )

    def test_rotation_label_matches_geometry_core(self, plan):
        p = plan.pairs
        t = torch.as_tensor(p[["yaw", "pitch", "roll"]].to_numpy())
        zero = torch.tensor(0.0, dtype=torch.float64)
        R_sat = euler_to_rotmat(zero, torch.tensor(-math.pi / 2, dtype=torch.float64), zero)
        R = relative_rotation(
            euler_to_rotmat(t[:, 0], t[:, 1], t[:, 2]), R_sat.expand(len(p), 3, 3)
        )
        np.testing.assert_allclose(p[R_COLUMNS].to_numpy().reshape(-1, 3, 3), R.numpy(), atol=1e-12)

    def test_deterministic_and_seeded(self, plan):
        again = make_plan(small_profile(), CITIES, seed=7)
        assert (
            again.pairs.equals(plan.pairs)
            and again.uav.equals(plan.uav)
            and again.sat.equals(plan.sat)
        )
        other = make_plan(small_profile(), CITIES, seed=8)
        assert not np.allclose(other.uav.E.to_numpy(), plan.uav.E.to_numpy())

    def test_uav_index_is_row_number(self, plan):
        np.testing.assert_array_equal(plan.uav.uav_index, np.arange(len(plan.uav)))
        np.testing.assert_array_equal(plan.sat.sat_index, np.arange(len(plan.sat)))


class TestConfirmationDraw:
    """Issue 38: confirm/* repeat standard/test, towns/test and generalized/test on new flights
    (and new towns) from seed groups of their own, leaving every other split as it was."""

    def test_sizes_equal_the_test_splits_they_repeat(self, plan):
        counts = plan.pairs.split.value_counts()
        for test, confirm in CONFIRMS.items():
            assert counts[confirm] == counts[test]
        assert plan.splits[-6:] == [*CONFIRM_SPLITS, *LONG_SPLITS]  # only the long ones after

    def test_new_flights_same_cities_new_towns(self, plan):
        pairs = plan.pairs
        for test, confirm in CONFIRMS.items():
            assert not flights_of(plan, test) & flights_of(plan, confirm)
        cities = {s: set(pairs.loc[pairs.split == s, "city"]) for s in pairs.split.unique()}
        assert cities["confirm/standard"] <= {"oxford", "cambridge"}
        assert cities["confirm/generalized"] == {"london"}
        assert all(c.startswith("town-confirm1-") for c in cities["confirm/towns"])
        assert not cities["confirm/towns"] & set().union(
            *(cities[f"towns/{r}"] for r in TOWN_ROLES)
        )
        confirm_styles = set(pairs.loc[pairs.split == "confirm/towns", "style"])
        assert confirm_styles <= {"oxford", "cambridge"}

    def test_confirm_standard_is_leak_checked_like_test(self, plan):
        from benchmark.sim.splits import POSE_COLUMNS as POSE
        from benchmark.sim.splits import _LeakIndex

        leak = _LeakIndex()
        train = plan.uav[plan.uav.group == "standard/train"]
        for style, rows in train.groupby("city"):
            leak.add(
                style, {k: rows[k].to_numpy() for k in ("E", "N", "U", "yaw", "pitch", "roll")}
            )
        confirm = plan.uav[plan.uav.group == "confirm/standard"]
        for style, rows in confirm.groupby("city"):
            assert not leak.leaks(style, {k: rows[k].to_numpy() for k in POSE})

    def test_other_splits_unchanged_without_the_draw(self, plan):
        # without the long splits too: they are planned after the draw (TestLongSplits)
        without = make_plan(small_profile(confirm_draw=0, n_long_flights=0), CITIES, seed=7)
        assert not set(CONFIRM_SPLITS) & set(without.splits)
        n_uav, n_sat, n_pairs = len(without.uav), len(without.sat), len(without.pairs)
        pd.testing.assert_frame_equal(without.uav, plan.uav.iloc[:n_uav])
        pd.testing.assert_frame_equal(without.sat, plan.sat.iloc[:n_sat])
        pd.testing.assert_frame_equal(without.pairs, plan.pairs.iloc[:n_pairs])

    def test_each_draw_has_its_own_flights(self, plan):
        second = make_plan(small_profile(confirm_draw=2), {**CITIES, **{
            (t.name, "now"): FlatCity(float(k), 1)
            for k, t in enumerate(town_list(small_profile().n_towns, 7, confirm_draw=2))
        }}, seed=7)  # fmt: skip
        a = plan.uav[plan.uav.group == "confirm/standard"][["E", "N", "yaw"]].to_numpy()
        b = second.uav[second.uav.group == "confirm/standard"][["E", "N", "yaw"]].to_numpy()
        assert a.shape == b.shape and not np.allclose(a, b)


def long_flight_seconds(spec):
    return (spec.samples - 1) * spec.frame_stride / spec.fps


class TestLongSplits:
    """Issue 39: long/{standard,towns,london}, test-only flights of >= 60 s (quick) planned after
    every other group, leaving every other split as it was."""

    def test_exist_with_the_stated_flight_length(self, plan):
        p = small_profile()
        assert p.n_long_flights == 2 and p.long_samples_per_flight == 6
        assert plan.splits[-3:] == list(LONG_SPLITS)
        for name in LONG_SPLITS:
            rows = plan.pairs[plan.pairs.split == name]
            per_flight = rows.groupby("flight").size()
            assert len(per_flight) == p.n_long_flights and (per_flight == 6).all(), name
            for _, f in rows.groupby("flight"):
                np.testing.assert_array_equal(f.frame, np.arange(6) * p.long_frame_stride)
                np.testing.assert_allclose(np.diff(f.time_s), 2.0)  # 60 frames at 30 fps
            uav = plan.uav.set_index("uav_index").loc[rows.uav_index]
            assert (uav.group == name).all() and not uav.camera_effects.any()

    def test_quick_flights_last_at_least_60_s(self):
        q = DATA_PROFILES["quick"]
        towns = town_list(q.n_towns, 0, confirm_draw=q.confirm_draw)
        groups = {g.name: g for g in _groups(q, ("oxford", "cambridge"), "london", "ind", towns)}
        for name in LONG_SPLITS:
            g = groups[name]
            assert long_flight_seconds(g.spec) >= 60.0, name
            assert g.spec.samples == 32 and g.n == 24 * 32 == 768, name
        assert groups["long/towns"].styles == tuple(t.name for t in towns if t.role == "test")
        assert groups["long/standard"].leak_check and not groups["long/london"].leak_check
        assert long_flight_seconds(groups["standard/test"].spec) < 60.0  # what long/* adds
        paper = DATA_PROFILES["paper"]
        spec = FlightSpec(
            samples=paper.long_samples_per_flight, frame_stride=paper.long_frame_stride
        )
        assert long_flight_seconds(spec) >= 60.0

    def test_seed_groups_never_collide(self):
        """The confirmation draw d uses groups 100 d + (0, 1, 2); the long groups are none of
        those, so no draw flies the long flights' curves."""
        for draw in range(1, 50):
            p = small_profile(confirm_draw=draw)
            towns = town_list(p.n_towns, 7, confirm_draw=draw)
            gids = [g.gid for g in _groups(p, ("oxford", "cambridge"), "london", "ind", towns)]
            assert len(gids) == len(set(gids)) and set(LONG_GROUPS) <= set(gids), draw

    def test_families(self, plan):
        pairs = plan.pairs
        city = {s: set(pairs.loc[pairs.split == s, "city"]) for s in LONG_SPLITS}
        assert city["long/standard"] <= {"oxford", "cambridge"}
        assert city["long/london"] == {"london"}
        test_towns = set(pairs.loc[pairs.split == "towns/test", "city"])
        assert city["long/towns"] <= test_towns
        for name in LONG_SPLITS:  # new flights, standard satellite images
            rows = pairs[pairs.split == name]
            for other in set(plan.splits) - {name}:
                assert not flights_of(plan, name) & flights_of(plan, other), (name, other)
            np.testing.assert_allclose(rows.sat_height_m, 1000.0)

    def test_long_standard_is_leak_checked_like_test(self, plan):
        from benchmark.sim.splits import POSE_COLUMNS as POSE
        from benchmark.sim.splits import _LeakIndex

        leak = _LeakIndex()
        train = plan.uav[plan.uav.group == "standard/train"]
        for style, rows in train.groupby("city"):
            leak.add(style, {k: rows[k].to_numpy() for k in POSE})
        for style, rows in plan.uav[plan.uav.group == "long/standard"].groupby("city"):
            assert not leak.leaks(style, {k: rows[k].to_numpy() for k in POSE})

    def test_other_splits_unchanged_without_them(self, plan):
        without = make_plan(small_profile(n_long_flights=0), CITIES, seed=7)
        assert not set(LONG_SPLITS) & set(without.splits)
        assert without.splits == plan.splits[: len(without.splits)]
        n_uav, n_sat, n_pairs = len(without.uav), len(without.sat), len(without.pairs)
        pd.testing.assert_frame_equal(without.uav, plan.uav.iloc[:n_uav])
        pd.testing.assert_frame_equal(without.sat, plan.sat.iloc[:n_sat])
        pd.testing.assert_frame_equal(without.pairs, plan.pairs.iloc[:n_pairs])

    def test_standard_only_has_none(self):
        assert DATA_PROFILES["quick"].standard_only().n_long_flights == 0


class TestMakePlanOdometry:
    """make_plan's odometry columns (benchmark.sim.odometry): per UAV row, carried to pairs."""

    def test_on_every_uav_and_pair_row(self, plan):
        for col in ODOMETRY_COLUMNS:
            assert plan.uav[col].dtype == np.float64 and plan.pairs[col].dtype == np.float64
        u = plan.uav.set_index("uav_index").loc[plan.pairs.uav_index]
        for col in ODOMETRY_COLUMNS:
            np.testing.assert_array_equal(plan.pairs[col].to_numpy(), u[col].to_numpy())

    def test_nan_exactly_on_each_flights_first_sample(self, plan):
        first = plan.uav.frame == plan.uav.groupby("flight").frame.transform("min")
        odo = plan.uav[list(ODOMETRY_COLUMNS)].to_numpy()
        assert np.isnan(odo[first.to_numpy()]).all()
        assert np.isfinite(odo[~first.to_numpy()]).all()

    def test_zero_noise_equals_the_true_increments(self):
        exact = small_profile(odometry_gyro_bias_dps=0.0, odometry_yaw_walk_deg=0.0,
                              odometry_scale_sigma=0.0, odometry_step_sigma_m=0.0)  # fmt: skip
        uav = make_plan(exact, CITIES, seed=7).uav
        for _, f in uav.groupby("flight"):
            f = f.sort_values("frame")
            yaw = f.yaw.to_numpy()
            d_nav = np.diff(f[["E", "N", "U"]].to_numpy(), axis=0)
            level = Rotation.from_euler("z", yaw[:-1, None]).inv().apply(d_nav)
            dyaw = np.angle(np.exp(1j * np.diff(yaw)))
            np.testing.assert_allclose(f.odo_dyaw.to_numpy()[1:], dyaw, atol=1e-12)
            np.testing.assert_allclose(f[["odo_dx", "odo_dy", "odo_dz"]].to_numpy()[1:], level,
                                       atol=1e-9)  # fmt: skip

    def test_profile_noise_is_used(self, plan):
        noisy = make_plan(small_profile(odometry_gyro_bias_dps=2.0), CITIES, seed=7)
        dyaw = (noisy.uav.odo_dyaw - plan.uav.odo_dyaw).abs()
        assert dyaw.max() > 0.0  # a larger bias moves the heading increments ...
        cols = ["odo_dx", "odo_dy", "odo_dz", *(c for c in plan.uav if not c.startswith("odo"))]
        pd.testing.assert_frame_equal(noisy.uav[cols], plan.uav[cols])  # ... and nothing else

    def test_default_noise_is_the_profile_s(self, plan):
        from benchmark.sim.odometry import odometry_noise

        assert odometry_noise(small_profile()) == OdometryNoise()


class TestRelativeLabels:
    def test_convention_level_uav_facing_north(self):
        import pandas as pd

        uav = pd.DataFrame(dict(E=[5.0], N=[-3.0], U=[100.0], yaw=[0.0], pitch=[0.0], roll=[0.0]))
        sat = pd.DataFrame(
            dict(E=[0.0], N=[0.0], U=[1000.0], yaw=[0.0], pitch=[-math.pi / 2], roll=[0.0])
        )
        lab = relative_labels(uav, sat)
        # R_uav^sat = I Rx(-90)^T = Rx(+90): columns are the images of the axes under Rx(90 deg)
        expected = Rotation.from_euler("x", 90, degrees=True).as_matrix()
        np.testing.assert_allclose(lab[R_COLUMNS].to_numpy().reshape(3, 3), expected, atol=1e-15)
        np.testing.assert_allclose(lab[["dE", "dN", "dU"]].to_numpy()[0], [5.0, -3.0, -900.0])


class TestSeeds:
    def test_sample_seeds_independent_of_order(self):
        a = np.random.default_rng(sample_seed(1, 17)).random(4)
        b = np.random.default_rng(sample_seed(1, 17)).random(4)
        c = np.random.default_rng(sample_seed(1, 18)).random(4)
        d = np.random.default_rng(sample_seed(2, 17)).random(4)
        np.testing.assert_array_equal(a, b)
        assert not np.allclose(a, c) and not np.allclose(a, d)

    def test_city_seeds_differ_per_style_and_variant(self):
        seeds = {city_seed(0, s, v) for s in ("oxford", "london") for v in ("now", "earlier")}
        assert len(seeds) == 4 and all(0 <= s < 2**31 for s in seeds)
        assert city_seed(0, "oxford") != city_seed(1, "oxford")


class TestLeakIndex:
    def test_detects_near_identical_pose_only(self):
        from benchmark.sim.splits import _LeakIndex

        d = {
            k: np.array([v])
            for k, v in dict(E=0.0, N=0.0, U=100.0, yaw=3.1, pitch=-0.3, roll=0.0).items()
        }
        idx = _LeakIndex()
        idx.add("oxford", d)
        assert idx.leaks("oxford", d) and not idx.leaks("london", d)
        moved = dict(d, E=np.array([LEAK_DIST_M + 1.0]))
        turned = dict(d, yaw=np.array([3.1 + math.radians(LEAK_ANGLE_DEG) + 0.01]))
        wrapped = dict(d, yaw=np.array([3.1 - 2 * math.pi + 0.05]))  # same heading across +-pi
        tilted = dict(d, pitch=np.array([-0.3 - math.radians(LEAK_ANGLE_DEG) - 0.01]))
        assert not idx.leaks("oxford", moved) and not idx.leaks("oxford", turned)
        assert idx.leaks("oxford", wrapped) and not idx.leaks("oxford", tilted)


class TestFrameSplit:
    def test_same_frames_and_sizes_as_standard(self, plan):
        p = plan.pairs
        std = set(p.loc[p.split.str.startswith("standard/"), "uav_index"])
        frames = p[p.split.str.startswith("frames/")]
        assert set(frames.uav_index) == std and not frames.uav_index.duplicated().any()
        for part in ("train", "val", "test"):
            assert (p.split == f"frames/{part}").sum() == (p.split == f"standard/{part}").sum()

    def test_naive_split_puts_flights_in_train_and_test(self, plan):
        # the point of the audit: frames of one flight straddle train and test
        assert flights_of(plan, "frames/train") & flights_of(plan, "frames/test")

    def test_labels_equal_the_standard_rows(self, plan):
        p = plan.pairs
        a = p[p.split.str.startswith("standard/")].set_index("uav_index").sort_index()
        b = p[p.split.str.startswith("frames/")].set_index("uav_index").sort_index()
        cols = [*R_COLUMNS, "dE", "dN", "dU", "sat_index", "light", "sat_light"]
        pd.testing.assert_frame_equal(a[cols], b[cols])

    def test_disabled(self):
        plan = make_plan(small_profile(frame_split=False), CITIES, seed=7)
        assert not any(s.startswith("frames/") for s in plan.splits)


class TestTowns:
    def test_roles_match_the_profile_roles(self):
        from benchmark.data.profiles import TOWN_ROLES as DATA_ROLES

        assert DATA_ROLES == TOWN_ROLES

    def test_town_list(self):
        towns = town_list((4, 1, 2, 2), 7)
        assert [t.role for t in towns] == ["train"] * 4 + ["val", "test", "test"] + ["london"] * 2
        assert {t.style for t in towns if t.role != "london"} == {"oxford", "cambridge"}
        assert {t.style for t in towns if t.role == "london"} == {"london"}
        assert len({t.seed for t in towns}) == len(towns) == len({t.name for t in towns})
        assert town_list((4, 1, 2, 2), 7) == towns
        assert {t.seed for t in town_list((4, 1, 2, 2), 8)}.isdisjoint(t.seed for t in towns)
        with pytest.raises(ValueError, match="n_towns"):
            town_list((1, 2), 7)

    def test_splits_use_distinct_towns(self, plan):
        p = plan.pairs
        towns = {r: set(p.loc[p.split == f"towns/{r}", "city"]) for r in TOWN_ROLES}
        assert len(towns["train"]) == 4 and len(towns["test"]) == 2
        for a in TOWN_ROLES:
            for b in TOWN_ROLES:
                assert a == b or not (towns[a] & towns[b]), (a, b)
        assert set(p.loc[p.split == "towns/london", "style"]) == {"london"}
        assert set(p.loc[p.split == "towns/train", "style"]) == {"oxford", "cambridge"}
        counts = p.split.value_counts()
        assert [counts[f"towns/{r}"] for r in TOWN_ROLES] == [20, 5, 10, 10]

    def test_one_satellite_image_per_town(self, plan):
        p = plan.pairs[plan.pairs.split.str.startswith("towns/")]
        assert (p.groupby("city").sat_index.nunique() == 1).all()
        np.testing.assert_allclose(p[["sat_E", "sat_N"]].to_numpy(), 0.0)


class TestIllumination:
    def test_one_state_per_flight_and_independent_satellite_states(self, plan):
        p = plan.pairs
        assert (p.groupby("flight").light.nunique() == 1).all()
        assert (p.groupby("flight").visibility_m.nunique() == 1).all()
        flights = p.drop_duplicates("flight")
        assert flights.light.nunique() == FlatCity.n_lights  # every state is drawn
        # the UAV state and the satellite state of a pair are independent draws
        assert (p.light != p.sat_light).mean() > 0.5
        assert plan.sat.light.nunique() > 1

    def test_angles_are_the_city_states(self, plan):
        p = plan.pairs
        expected = np.array([FlatCity(0.0).light_angles(k) for k in p.light])
        np.testing.assert_allclose(p[["sun_az", "sun_el"]].to_numpy(), expected)
        expected = np.array([FlatCity(0.0).light_angles(k) for k in p.sat_light])
        np.testing.assert_allclose(p[["sat_sun_az", "sat_sun_el"]].to_numpy(), expected)

    def test_visibility_range(self, plan):
        from benchmark.sim.illumination import VISIBILITY_RANGE_M

        assert plan.pairs.visibility_m.between(*VISIBILITY_RANGE_M).all()
        assert plan.pairs.visibility_m.nunique() > 5
