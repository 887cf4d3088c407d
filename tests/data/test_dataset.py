"""The dataset on disk: writer, manifest, resume, PairDataset round trip, corruption reports."""

from __future__ import annotations

import hashlib
import json
import math
import pickle
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from scipy.spatial.transform import Rotation
from torch.utils.data import DataLoader

from benchmark.data import (
    ODOMETRY_COLUMNS,
    DatasetError,
    PairDataset,
    list_splits,
    odometry_noise,
    require_odometry,
)
from benchmark.data.profiles import DATA_PROFILES
from benchmark.data.swap import swap_targets
from benchmark.data.writer import ConfigMismatchError, simulate_dataset

SMOKE = DATA_PROFILES["smoke"]


def all_files(root: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()
    }


def copy_dataset(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


class TestSimulateDataset:
    def test_layout_counts_and_checksums(self, smoke_root):
        manifest = json.loads((smoke_root / "manifest.json").read_text())
        assert manifest["seed"] == 0 and manifest["profile"]["name"] == "smoke"
        for rel, entry in manifest["files"].items():
            data = (smoke_root / rel).read_bytes()
            assert len(data) == entry["bytes"]
            assert hashlib.sha256(data).hexdigest() == entry["sha256"], rel
        uav = pd.read_parquet(smoke_root / "uav.parquet")
        sat = pd.read_parquet(smoke_root / "sat.parquet")
        assert manifest["counts"]["uav_images"] == len(uav)
        assert manifest["counts"]["sat_images"] == len(sat)
        shards = sorted(smoke_root.glob("uav/shard_*.npy"))
        images = np.concatenate([np.load(p) for p in shards])
        assert images.shape == (len(uav), SMOKE.image_size, SMOKE.image_size, 3)
        assert images.dtype == np.uint8
        assert images.std() > 5.0  # rendered content, not a blank
        # satellite images are stored once per (city, variant, centre, height), not per pair
        pairs = pd.read_parquet(smoke_root / "pairs.parquet")
        assert len(sat) < len(pairs)
        assert not sat.duplicated(["city", "variant", "centre", "height_m"]).any()

    def test_workers_give_identical_bytes(self, smoke_root, tmp_path, city_cache):
        out = tmp_path / "ds2"
        simulate_dataset(out, SMOKE, 0, workers=2, cache_dir=city_cache, progress=False)
        assert all_files(out) == all_files(smoke_root)

    def test_resume_after_interruption_is_identical(self, smoke_root, tmp_path, city_cache):
        out = tmp_path / "ds"
        stats = simulate_dataset(
            out, SMOKE, 0, workers=1, cache_dir=city_cache, progress=False, max_tasks=2
        )
        assert stats["state"] == "interrupted"
        assert not (out / "manifest.json").exists()
        with pytest.raises(DatasetError, match=r"manifest\.json"):
            PairDataset(out, "standard/train")
        (out / "uav").mkdir(exist_ok=True)
        (out / "uav" / ".shard_00002.npy.tmp999999999").write_bytes(b"partial")  # a killed write
        stats = simulate_dataset(out, SMOKE, 0, workers=2, cache_dir=city_cache, progress=False)
        assert stats["state"] == "written"
        assert stats["rendered_uav"] + stats["rendered_sat"] < sum(
            json.loads((smoke_root / "manifest.json").read_text())["counts"][k]
            for k in ("uav_images", "sat_images")
        )
        assert all_files(out) == all_files(smoke_root)

    def test_finished_dataset_is_confirmed_not_rewritten(self, smoke_root, city_cache):
        before = {p: p.stat().st_mtime_ns for p in smoke_root.rglob("*") if p.is_file()}
        stats = simulate_dataset(smoke_root, SMOKE, 0, cache_dir=city_cache, progress=False)
        assert stats["state"] == "complete"
        assert before == {p: p.stat().st_mtime_ns for p in smoke_root.rglob("*") if p.is_file()}

    def test_other_config_refused_untouched(self, smoke_root, city_cache):
        before = all_files(smoke_root)
        with pytest.raises(ConfigMismatchError, match="seed"):
            simulate_dataset(smoke_root, SMOKE, 1, cache_dir=city_cache, progress=False)
        with pytest.raises(ConfigMismatchError, match="n_standard: existing 24 != requested 30"):
            simulate_dataset(smoke_root, SMOKE.with_size(30), 0, cache_dir=city_cache)
        assert all_files(smoke_root) == before

    def test_foreign_directory_refused(self, tmp_path, city_cache):
        (tmp_path / "notes.txt").write_text("mine")
        with pytest.raises(ConfigMismatchError, match="non-empty"):
            simulate_dataset(tmp_path, SMOKE, 0, cache_dir=city_cache)
        assert [p.name for p in tmp_path.iterdir()] == ["notes.txt"]

    def test_other_seed_other_images(self, smoke_root, tmp_path, city_cache):
        out = tmp_path / "s1"
        simulate_dataset(out, SMOKE, 1, workers=2, cache_dir=city_cache, progress=False)
        a = np.load(smoke_root / "uav" / "shard_00000.npy")
        b = np.load(out / "uav" / "shard_00000.npy")
        assert a.shape == b.shape and np.mean(a != b) > 0.5


class TestPairDataset:
    def test_item_contract(self, smoke_root):
        ds = PairDataset(smoke_root, "standard/train")
        n = SMOKE.image_size
        item = ds[3]
        assert item["uav"].shape == (3, n, n) and item["uav"].dtype == torch.float32
        assert item["sat"].shape == (3, n, n) and item["sat"].dtype == torch.float32
        assert 0.0 <= float(item["uav"].min()) and float(item["uav"].max()) <= 1.0
        assert item["sat_id"].dtype == torch.int64 and item["index"].dtype == torch.int64
        assert item["R"].shape == (3, 3) and item["R"].dtype == torch.float32
        assert item["T"].shape == (3,) and item["uav_euler"].shape == (3,)
        assert int(item["index"]) == 3

    def test_round_trip_matches_files(self, smoke_root):
        ds = PairDataset(smoke_root, "standard/test")
        uav = np.concatenate([np.load(p) for p in sorted(smoke_root.glob("uav/shard_*.npy"))])
        sat = np.concatenate([np.load(p) for p in sorted(smoke_root.glob("sat/shard_*.npy"))])
        for i in range(len(ds)):
            item, row = ds[i], ds.poses.iloc[i]
            expected = torch.from_numpy(uav[row.uav_index]).permute(2, 0, 1).float() / 255
            torch.testing.assert_close(item["uav"], expected, rtol=0, atol=1e-7)
            torch.testing.assert_close(
                item["sat"], torch.from_numpy(sat[row.sat_index]).permute(2, 0, 1).float() / 255
            )
            assert int(item["sat_id"]) == row.sat_index
            np.testing.assert_allclose(item["T"].numpy(), [row.dE, row.dN, row.dU], rtol=1e-6)
            np.testing.assert_allclose(item["uav_euler"].numpy(), [row.yaw, row.pitch, row.roll])

    def test_convention_labels_against_scipy(self, smoke_root):
        ds = PairDataset(smoke_root, "generalized/test")
        for i in range(len(ds)):
            item = ds[i]
            yaw, pitch, roll = item["uav_euler"].double().numpy()
            R_uav = Rotation.from_euler("ZXY", [yaw, pitch, roll]).as_matrix()
            R_sat = Rotation.from_euler("ZXY", [0.0, -math.pi / 2, 0.0]).as_matrix()
            np.testing.assert_allclose(item["R"].numpy(), R_uav @ R_sat.T, atol=1e-6)
            row = ds.poses.iloc[i]
            sat = ds.sat_table.loc[row.sat_index]
            # T = UAV position minus the satellite capture point above the flight centre
            np.testing.assert_allclose(
                item["T"].numpy(), [row.E - sat.E, row.N - sat.N, row.U - sat.U], atol=1e-3
            )
            assert sat.U - row.U > 800.0  # 1000 m above the centre's ground, UAV at 80-120 m

    def test_splits_listed_and_unknown_split(self, smoke_root):
        names = list_splits(smoke_root)
        for s in ("standard/train", "standard/val", "standard/test", "generalized/test",
                  "flight/pitch0", "flight/pitch-10", "flight/pitch-50", "height600/train",
                  "height1400/test", "pitch-40to-50/test"):  # fmt: skip
            assert s in names
        ds = PairDataset(smoke_root, "flight/pitch-50")
        assert ds.splits == names and ds.manifest["splits"]["flight/pitch-50"] == len(ds)
        with pytest.raises(ValueError, match="available"):
            PairDataset(smoke_root, "nope")

    def test_odometry_columns_and_long_splits(self, smoke_root):
        """Issue 39: every UAV row and pair row carries its odometry (NaN on a flight's first
        sample), and the smoke dataset holds the long test splits."""
        names = list_splits(smoke_root)
        assert {"long/standard", "long/towns", "long/london"} <= set(names)
        uav = pd.read_parquet(smoke_root / "uav.parquet")
        odo = require_odometry(uav, smoke_root / "uav.parquet")
        first = (uav.frame == uav.groupby("flight").frame.transform("min")).to_numpy()
        assert np.isnan(odo[first]).all() and np.isfinite(odo[~first]).all()
        ds = PairDataset(smoke_root, "long/london")
        assert len(ds) == SMOKE.n_long_flights * SMOKE.long_samples_per_flight
        odo = require_odometry(ds.poses, smoke_root / "pairs.parquet")
        by_uav = uav.set_index("uav_index").loc[ds.poses.uav_index, list(ODOMETRY_COLUMNS)]
        np.testing.assert_array_equal(odo, by_uav.to_numpy())
        manifest_noise = odometry_noise(ds.manifest["profile"])
        assert manifest_noise == odometry_noise(SMOKE)

    def test_dataloader_workers_and_pickling(self, smoke_root):
        ds = PairDataset(smoke_root, "standard/train")
        ds[0]  # opens a memory map in this process
        assert len(pickle.dumps(ds)) < 2_000_000  # maps are dropped, not copied
        loader = DataLoader(ds, batch_size=5, num_workers=2, shuffle=False)
        batches = list(loader)
        assert sum(len(b["index"]) for b in batches) == len(ds)
        torch.testing.assert_close(batches[1]["uav"][0], ds[5]["uav"])

    def test_truncated_shard_named(self, smoke_root, tmp_path):
        root = copy_dataset(smoke_root, tmp_path / "ds")
        shard = root / "uav" / "shard_00001.npy"
        shard.write_bytes(shard.read_bytes()[:-100])
        with pytest.raises(DatasetError, match=r"truncated file .*uav/shard_00001\.npy"):
            PairDataset(root, "standard/train", verify="size")

    def test_corrupted_shard_named(self, smoke_root, tmp_path):
        root = copy_dataset(smoke_root, tmp_path / "ds")
        shard = root / "uav" / "shard_00000.npy"
        data = bytearray(shard.read_bytes())
        data[-7] ^= 0xFF  # same size, one pixel changed
        shard.write_bytes(bytes(data))
        with pytest.raises(DatasetError, match=r"corrupted file .*uav/shard_00000\.npy"):
            PairDataset(root, "standard/train")

    def test_missing_shard_named(self, smoke_root, tmp_path):
        root = copy_dataset(smoke_root, tmp_path / "ds")
        (root / "sat" / "shard_00000.npy").unlink()
        with pytest.raises(DatasetError, match=r"missing file .*sat/shard_00000\.npy"):
            PairDataset(root, "standard/val", verify="size")

    def test_missing_manifest_named(self, tmp_path):
        with pytest.raises(DatasetError, match="does not exist"):
            PairDataset(tmp_path / "nothing", "standard/train")
        (tmp_path / "ds").mkdir()
        with pytest.raises(DatasetError, match=r"manifest\.json is missing"):
            PairDataset(tmp_path / "ds", "standard/train")


@pytest.mark.slow
class TestInterruptedCommand:
    def test_ctrl_c_then_rerun_gives_identical_bytes(self, tmp_path, city_cache):
        """A real interruption: SIGINT to ``uavbench simulate`` after its first shard, rerun."""
        import os
        import signal
        import subprocess
        import sys
        import time

        def command(out):
            # not ``-m benchmark.cli``: that imports cli twice and its UsageError handler misses
            entry = "import sys; from benchmark.cli import main; sys.exit(main(sys.argv[1:]))"
            return [sys.executable, "-c", entry, "simulate", "--profile", "smoke",
                    "--size", "240", "--workers", "2", "--out", str(out),
                    "--city-cache", str(city_cache), "--quiet"]  # fmt: skip

        env = {**os.environ, "NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
        ref, out = tmp_path / "ref", tmp_path / "out"
        subprocess.run(command(ref), check=True, env=env, capture_output=True)
        proc = subprocess.Popen(command(out), env=env, stderr=subprocess.PIPE)
        deadline = time.monotonic() + 120
        while not list(out.glob("uav/shard_*.npy")) and time.monotonic() < deadline:
            time.sleep(0.05)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=60) == 130
        assert "interrupted" in proc.stderr.read().decode()
        assert not (out / "manifest.json").exists()
        subprocess.run(command(out), check=True, env=env, capture_output=True)
        assert all_files(out) == all_files(ref)


def sat_rows(rows: list[tuple[str, str, int, str]]) -> pd.DataFrame:
    """A synthetic sat table: (city, style, centre, variant) rows at 1000 m, 2 km x 1 km."""
    return pd.DataFrame(
        [
            dict(sat_index=i, city=c, style=s, centre=k, variant=v, height_m=1000.0,
                 footprint_E_m=2000.0, footprint_N_m=1000.0)
            for i, (c, s, k, v) in enumerate(rows)
        ]
    )  # fmt: skip


class TestSwapTargets:
    """The mapping rules of ``benchmark.data.swap`` on synthetic tables (no rendering)."""

    TABLE = sat_rows(
        [("oxford", "oxford", k, "now") for k in range(3)]
        + [("cambridge", "cambridge", k, "now") for k in range(2)]
        + [("london", "london", k, "now") for k in range(2)]
        + [(f"town-test{k:02d}-oxford", "oxford", 0, "now") for k in range(3)]
        + [
            ("town-london00-london", "london", 0, "now"),
            ("town-train00-oxford", "oxford", 0, "now"),
        ]
    )

    def test_standard_takes_the_other_city_of_the_split(self):
        # a city's centres overlap (400-900 m apart, 2 km x 1 km images): never the same city
        got = swap_targets(self.TABLE, "standard/test", [0, 1, 2, 3, 4])
        cities = self.TABLE.set_index("sat_index")["city"]
        assert {k: cities[v] for k, v in got.items()} == {
            0: "cambridge",
            1: "cambridge",
            2: "cambridge",
            3: "oxford",
            4: "oxford",
        }
        assert len({got[0], got[1], got[2]}) == 2 and got[3] != got[4]  # spread by rank

    def test_one_city_takes_a_centre_whose_footprint_does_not_overlap(self):
        # an oxford-only split: centres 0 and 1 overlap (1 km apart east, footprints 2 km wide),
        # centre 2 lies 1.2 km north of both (footprints 1 km tall): only 2 <-> {0, 1} qualify
        table = self.TABLE.assign(E=0.0, N=0.0)
        table.loc[1, "E"] = 1000.0
        table.loc[2, ["E", "N"]] = (500.0, 1200.0)
        got = swap_targets(table, "standard/test", [0, 1, 2])
        assert got[0] == 2 and got[1] == 2 and got[2] in (0, 1)

    def test_one_city_without_a_disjoint_centre_takes_another_paper_city(self):
        table = self.TABLE.assign(E=0.0, N=0.0)  # every oxford centre on the same ground
        got = swap_targets(table.iloc[:3].pipe(lambda t: pd.concat([t, table.iloc[3:5]])),
                           "pitch-0to-10/test", [0])  # fmt: skip
        assert got[0] in (3, 4)

    def test_generalized_takes_a_paper_city_outside_the_split(self):
        got = swap_targets(self.TABLE, "generalized/test", [5, 6])
        cities = self.TABLE.set_index("sat_index")["city"]
        assert {cities[v] for v in got.values()} <= {"oxford", "cambridge"}
        assert got[5] != got[6]

    def test_towns_take_another_town_of_the_split(self):
        got = swap_targets(self.TABLE, "towns/test", [7, 8, 9])
        assert got == {7: 8, 8: 9, 9: 7}

    def test_single_town_falls_back_to_another_town(self):
        got = swap_targets(self.TABLE, "towns/london", [10])
        assert got[10] in {7, 8, 9, 11}

    def test_no_other_place_is_an_error(self):
        with pytest.raises(DatasetError, match="no satellite image of another place"):
            swap_targets(self.TABLE.iloc[:1], "standard/test", [0])

    def test_unknown_index_is_an_error(self):
        with pytest.raises(DatasetError, match=r"\[99\]"):
            swap_targets(self.TABLE, "standard/test", [99])


class TestSatelliteSwap:
    """``PairDataset(..., satellite="swap")`` on every split of the smoke dataset."""

    def test_every_pair_gets_another_place_labels_unchanged(self, smoke_root):
        for split in list_splits(smoke_root):
            true = PairDataset(smoke_root, split, verify="size")
            swap = PairDataset(smoke_root, split, verify="size", satellite="swap")
            assert swap.satellite == "swap" and true.swap_map == {}
            pd.testing.assert_frame_equal(true.poses, swap.poses)
            sat = true.sat_table.set_index("sat_index")
            for i in range(len(true)):
                a, b = true[i], swap[i]
                for key in ("uav", "R", "T", "uav_euler", "index"):
                    assert torch.equal(a[key], b[key]), (split, i, key)
                s_true, s_swap = int(a["sat_id"]), int(b["sat_id"])
                assert s_true == int(true.poses["sat_index"][i])
                assert s_swap == swap.swap_map[s_true] == int(swap.served_sat_index[i])
                assert not torch.equal(a["sat"], b["sat"]), (split, i)  # other pixels
                place = (sat.city[s_true], sat.centre[s_true])
                assert (sat.city[s_swap], sat.centre[s_swap]) != place, split
                same_height = sat[sat.height_m == sat.height_m[s_true]]
                if (same_height.city != sat.city[s_true]).any():  # smoke's height splits: none
                    assert sat.height_m[s_swap] == sat.height_m[s_true], split
                if split == "generalized/test":
                    assert sat.city[s_swap] != sat.city[s_true]
                    assert sat.city[s_swap] in ("oxford", "cambridge")
                if sat.city[s_swap] == sat.city[s_true]:  # same world: footprints disjoint
                    d_e = abs(sat.E[s_swap] - sat.E[s_true])
                    d_n = abs(sat.N[s_swap] - sat.N[s_true])
                    assert d_e >= sat.footprint_E_m[s_true] or d_n >= sat.footprint_N_m[s_true]

    def test_deterministic(self, smoke_root):
        for split in ("standard/test", "generalized/test"):
            a = PairDataset(smoke_root, split, verify="size", satellite="swap")
            b = PairDataset(smoke_root, split, verify="size", satellite="swap")
            assert a.swap_map == b.swap_map
            assert np.array_equal(a.served_sat_index, b.served_sat_index)

    def test_bad_mode_named(self, smoke_root):
        with pytest.raises(ValueError, match=r"satellite must be one of.*'grey'"):
            PairDataset(smoke_root, "standard/test", satellite="grey")
