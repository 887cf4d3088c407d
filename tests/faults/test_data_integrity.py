"""Same-size corruption is refused by default, named by ``uavbench verify``, and repaired by
``uavbench simulate`` from re-rendered bytes (issue 14, items 1 and 2)."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess

import numpy as np
import pandas as pd
import pytest
from fault_tools import CLI, all_files, flip_byte

from benchmark.cli import main
from benchmark.data import DatasetError, PairDataset
from benchmark.data import integrity as integ
from benchmark.data.journal import JOURNAL
from benchmark.data.profiles import DATA_PROFILES
from benchmark.data.verify import verify_and_report
from benchmark.data.writer import simulate_dataset

SMOKE = DATA_PROFILES["smoke"]
SHARDS = ["uav/shard_00000.npy", "sat/shard_00000.npy"]  # both read by standard/train


def swap_two_labels_same_size(root) -> tuple[float, float]:
    """Swap the yaw labels of the first two standard/train pairs inside pairs.parquet's bytes (the
    column is dictionary-encoded: its distinct values are stored once, as raw float64, in a snappy
    literal), so the file keeps its size and stays a valid parquet file whose labels differ."""
    path = root / "pairs.parquet"
    data = bytearray(path.read_bytes())
    pairs = pd.read_parquet(path)
    a, b = pairs.yaw[pairs.split == "standard/train"][:2]
    ka, kb = (data.find(np.float64(v).tobytes()) for v in (a, b))
    assert a != b and ka > 0 and kb > 0 and data.count(np.float64(a).tobytes()) == 1
    data[ka : ka + 8], data[kb : kb + 8] = data[kb : kb + 8], data[ka : ka + 8]
    path.write_bytes(bytes(data))
    edited = pd.read_parquet(path).yaw[pairs.split == "standard/train"][:2].tolist()
    assert edited == [b, a]  # a readable file with the two labels swapped
    return a, b


class TestRefusedByDefault:
    @pytest.mark.parametrize("shard", SHARDS)
    def test_flipped_byte_refused_and_named(self, dataset, shard):
        PairDataset(dataset, "standard/train")  # good: hashed once and cached
        flip_byte(dataset / shard)
        with pytest.raises(DatasetError, match=rf"corrupted file .*{shard}: sha256 differs"):
            PairDataset(dataset, "standard/train")

    def test_flip_caught_even_with_mtime_restored(self, dataset):
        PairDataset(dataset, "standard/train")
        path = dataset / SHARDS[0]
        st = path.stat()
        flip_byte(path)
        os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))  # `touch -r`: same size and mtime
        assert path.stat().st_mtime_ns == st.st_mtime_ns and path.stat().st_size == st.st_size
        with pytest.raises(DatasetError, match="corrupted file"):
            PairDataset(dataset, "standard/train")  # the ctime (inode change time) moved

    def test_two_labels_swapped_at_the_same_size(self, dataset):
        size = (dataset / "pairs.parquet").stat().st_size
        PairDataset(dataset, "standard/train")
        swap_two_labels_same_size(dataset)
        assert (dataset / "pairs.parquet").stat().st_size == size
        with pytest.raises(DatasetError, match=r"corrupted file .*pairs\.parquet"):
            PairDataset(dataset, "standard/test")  # any split: the labels table is shared
        ds = PairDataset(dataset, "standard/train", verify="size")  # the opt-out does not see it
        assert len(ds) > 0

    def test_evaluate_refuses_a_flipped_byte_in_one_line(self, dataset, checkpoint, capsys):
        flip_byte(dataset / "uav/shard_00001.npy")  # standard/test's frames
        out = str(dataset.parent / "e")
        code = main(["evaluate", "--quiet", "--checkpoint", str(checkpoint), "--data-root",
                     str(dataset), "--split", "standard/test", "--out", out])  # fmt: skip
        err = capsys.readouterr().err.strip()
        assert code == 2 and len(err.splitlines()) == 1, err
        assert "corrupted file" in err and "uav/shard_00001.npy" in err and "uavbench verify" in err


class TestTrainingOpen:
    """What ``uavbench train`` and every reproduce unit open (``open_datasets(cfg)``)."""

    def test_checksum_mode_refuses_a_flipped_byte(self, dataset):
        from benchmark.config import apply_overrides
        from benchmark.training import TrainConfig
        from benchmark.training.build import open_datasets

        cfg = apply_overrides(TrainConfig(), [f"data.root={dataset}", "data.verify=sha256"])
        open_datasets(cfg)
        flip_byte(dataset / SHARDS[1])
        with pytest.raises(DatasetError, match=r"corrupted file .*sat/shard_00000\.npy"):
            open_datasets(cfg)

    def test_default_config_refuses_a_flipped_byte(self, dataset):
        from benchmark.training import TrainConfig
        from benchmark.training.build import open_datasets

        cfg = dataclasses.replace(
            TrainConfig(), data=dataclasses.replace(TrainConfig().data, root=str(dataset))
        )
        flip_byte(dataset / SHARDS[0])
        with pytest.raises(DatasetError, match="corrupted file"):
            open_datasets(cfg)


class TestCachedVerification:
    def test_each_file_hashed_once_then_stat_only(self, dataset, monkeypatch):
        hashed = []
        real = integ.sha256_file
        monkeypatch.setattr(integ, "sha256_file", lambda p: hashed.append(p.name) or real(p))
        monkeypatch.setattr(integ, "RACY_NS", 0)  # files copied a moment ago count as settled
        PairDataset(dataset, "standard/train")
        first = len(hashed)
        assert first >= 5  # three tables, satellite and UAV shards
        PairDataset(dataset, "standard/train")
        integ._MEMO.clear()  # a new process: the cache file is read
        PairDataset(dataset, "standard/train")
        assert len(hashed) == first
        flip_byte(dataset / SHARDS[1])
        with pytest.raises(DatasetError):
            PairDataset(dataset, "standard/train")
        assert hashed[first:] == ["shard_00000.npy"]  # only the changed file is hashed again

    def test_recently_changed_file_is_not_cached(self, dataset, monkeypatch):
        """A file written within RACY_NS of its hash could change again within one timestamp
        tick unseen, so its verdict is not kept ('racy git')."""
        hashed = []
        real = integ.sha256_file
        monkeypatch.setattr(integ, "sha256_file", lambda p: hashed.append(p.name) or real(p))
        os.utime(dataset / "pairs.parquet")  # just touched
        PairDataset(dataset, "standard/train")
        n = hashed.count("pairs.parquet")
        PairDataset(dataset, "standard/train")
        assert hashed.count("pairs.parquet") == n + 1

    def test_unwritable_cache_dir_still_verifies(self, dataset, tmp_path, monkeypatch):
        blocker = tmp_path / "not-a-dir"
        blocker.write_text("a file where the cache directory should be")
        monkeypatch.setenv("UAVBENCH_VERIFY_CACHE", str(blocker / "verified"))
        before = all_files(dataset)
        PairDataset(dataset, "standard/train")
        flip_byte(dataset / SHARDS[0])
        with pytest.raises(DatasetError, match="corrupted file"):
            PairDataset(dataset, "standard/train")
        assert set(all_files(dataset)) == set(before)  # nothing written into the dataset

    def test_read_only_dataset(self, dataset, monkeypatch):
        monkeypatch.setattr(integ, "RACY_NS", 0)  # chmod just changed every ctime
        before = all_files(dataset)
        for p in [dataset, *dataset.rglob("*")]:
            p.chmod(0o555 if p.is_dir() else 0o444)
        try:
            PairDataset(dataset, "standard/train")
            assert integ.cache_file(dataset).is_file()  # the cache lives outside the dataset
            assert all_files(dataset) == before
        finally:
            for p in [dataset, *dataset.rglob("*")]:
                p.chmod(0o755 if p.is_dir() else 0o644)


class TestVerifyCommand:
    def test_good_dataset(self, dataset, capsys):
        assert main(["verify", "--quiet", str(dataset)]) == 0
        assert "OK" in capsys.readouterr().out

    def test_names_each_bad_file_and_the_fix_which_works(self, dataset, city_cache, capsys):
        for shard in SHARDS:
            flip_byte(dataset / shard)
        swap_two_labels_same_size(dataset)
        assert main(["verify", "--quiet", str(dataset)]) == 1
        err = capsys.readouterr().err
        for rel in [*SHARDS, "pairs.parquet"]:
            assert f"corrupted file {dataset / rel}: sha256 differs" in err
        fix = f"`uavbench simulate --profile smoke --out {dataset}`"
        assert fix in err
        # the fix, as printed (plus this test's city cache)
        code = main(["simulate", "--profile", "smoke", "--out", str(dataset), "--workers", "1",
                     "--city-cache", str(city_cache), "--quiet"])  # fmt: skip
        assert code == 0
        assert main(["verify", "--quiet", str(dataset)]) == 0

    def test_truncated_and_missing_files(self, dataset, capsys):
        shard = dataset / "uav/shard_00002.npy"
        shard.write_bytes(shard.read_bytes()[:-100])
        (dataset / "sat/shard_00001.npy").unlink()
        assert main(["verify", "--quiet", str(dataset)]) == 1
        err = capsys.readouterr().err
        assert f"truncated file {shard}" in err and "missing file" in err

    def test_edited_manifest_named_and_the_fix_works(self, dataset, reference, city_cache,
                                                     capsys):  # fmt: skip
        manifest = json.loads((dataset / "manifest.json").read_text())
        manifest["splits"]["standard/test"] += 1
        (dataset / "manifest.json").write_text(json.dumps(manifest))
        assert main(["verify", "--quiet", str(dataset)]) == 1
        err = capsys.readouterr().err
        assert "split 'standard/test'" in err
        assert f"delete {dataset / 'manifest.json'} and rerun `uavbench simulate" in err
        (dataset / "manifest.json").unlink()
        stats = simulate_dataset(dataset, SMOKE, 0, cache_dir=city_cache, progress=False)
        assert stats["state"] == "written" and stats["replaced"] == []
        assert all_files(dataset) == all_files(reference)

    def test_not_a_dataset_exits_2(self, tmp_path, capsys):
        assert main(["verify", str(tmp_path / "nothing")]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "does not exist" in err

    def test_progress_shows_rate_and_eta(self, dataset):
        proc = subprocess.run([*CLI, "verify", str(dataset)], capture_output=True, text=True)
        assert proc.returncode == 0
        assert "MB/s" in proc.stderr and "ETA" in proc.stderr


class TestLibraryResults:
    """Issue 41: the library functions behind ``uavbench verify`` and ``simulate`` return what
    they found or did and print nothing; simulate's notices go through
    ``benchmark.progress.status``; the commands print (and map to exit codes)."""

    def test_verify_returns_the_verdict(self, dataset, capsys):
        report = verify_and_report(dataset, progress=False)
        n = len(json.loads((dataset / "manifest.json").read_text())["files"])
        assert report.ok and report.n_files == n and report.problems == ()
        assert report.lines() == [
            f"{dataset}: OK, {n} files match manifest.json (sha256, sizes, shapes, split counts)"
        ]
        flip_byte(dataset / SHARDS[0])
        report = verify_and_report(dataset, progress=False)
        assert not report.ok and [p.file for p in report.problems] == [SHARDS[0]]
        assert f"`uavbench simulate --profile smoke --out {dataset}`" in report.fixes[0]
        assert report.lines()[0].startswith(f"corrupted file {dataset / SHARDS[0]}: ")
        assert report.lines()[-1].startswith(f"{dataset}: 1 problem(s) in 1 file(s); fix: rerun")
        assert capsys.readouterr() == ("", "")

    def test_simulate_returns_what_it_did(self, dataset, reference, city_cache, capsys):
        from benchmark.data.simulate import SimulateConfig, simulate
        from benchmark.progress import status_to

        flip_byte(dataset / SHARDS[1])
        config = SimulateConfig(SMOKE, 0, dataset, 1, city_cache=city_cache, progress=False)
        said: list[str] = []
        with status_to(said.append):
            result = simulate(config)
        assert capsys.readouterr() == ("", "")
        assert result.state == "written" and result.replaced == (SHARDS[1],)
        assert result.rendered_sat == SMOKE.sat_shard_size and result.rendered_uav == 0
        assert result.warnings() == [f"{dataset}: replaced 1 corrupted shard(s): {SHARDS[1]}"]
        assert result.lines()[0].startswith(f"{dataset}: written; cities ")
        assert said[0].startswith(f"simulate: corrupted file {dataset / SHARDS[1]}")
        assert said[-1] == f"simulate: {dataset / SHARDS[1]} differed from its render " + (
            "(corrupted): replaced"
        )
        assert all_files(dataset) == all_files(reference)
        with status_to(said.append):
            again = simulate(config)
        assert again.state == "complete" and again.warnings() == []
        assert again.lines() == [
            f"{dataset}: already complete (profile smoke, seed 0); nothing to do"
        ]

    def test_simulate_command_summary_on_stdout_notices_on_stderr(self, dataset, city_cache,
                                                                  capsys):  # fmt: skip
        # As before issue 41: stdout holds the summary alone, stderr what simulate noticed on the
        # way (status lines routed there by the command) and the corrupted shards it replaced.
        flip_byte(dataset / SHARDS[1])
        assert main(["simulate", "--profile", "smoke", "--out", str(dataset), "--workers", "1",
                     "--city-cache", str(city_cache), "--quiet"]) == 0  # fmt: skip
        out, err = capsys.readouterr()
        (summary,) = out.splitlines()
        assert summary.startswith(f"{dataset}: written; cities ")
        notices = err.splitlines()
        assert notices[0].startswith(f"simulate: corrupted file {dataset / SHARDS[1]}")
        assert notices[-1] == f"{dataset}: replaced 1 corrupted shard(s): {SHARDS[1]}"


class TestSimulateTrustsOnlyRenderedBytes:
    def test_manifest_deleted_and_shard_corrupted_rerendered(self, dataset, reference, city_cache):
        (dataset / "manifest.json").unlink()
        flip_byte(dataset / SHARDS[0])
        stats = simulate_dataset(dataset, SMOKE, 0, cache_dir=city_cache, progress=False)
        assert stats["state"] == "written" and stats["replaced"] == [SHARDS[0]]
        assert all_files(dataset) == all_files(reference)  # manifest rebuilt from rendered bytes

    def test_finished_dataset_with_corrupted_shard_repaired(self, dataset, reference, city_cache):
        flip_byte(dataset / SHARDS[1])
        stats = simulate_dataset(dataset, SMOKE, 0, cache_dir=city_cache, progress=False)
        assert stats["state"] == "written" and stats["replaced"] == [SHARDS[1]]
        assert stats["rendered_sat"] == SMOKE.sat_shard_size and stats["rendered_uav"] == 0
        assert all_files(dataset) == all_files(reference)

    def test_resume_rerenders_a_shard_changed_since_its_render(self, tmp_path, reference,
                                                               city_cache):  # fmt: skip
        out = tmp_path / "ds"
        stats = simulate_dataset(out, SMOKE, 0, cache_dir=city_cache, progress=False, max_tasks=3)
        assert stats["state"] == "interrupted" and (out / JOURNAL).is_file()
        flip_byte(out / "sat/shard_00001.npy")  # rendered, journalled, then damaged
        stats = simulate_dataset(out, SMOKE, 0, cache_dir=city_cache, progress=False)
        assert stats["replaced"] == ["sat/shard_00001.npy"]
        assert all_files(out) == all_files(reference)  # and the journal is gone

    def test_unjournalled_good_shard_is_confirmed_by_rerendering(self, dataset, reference,
                                                                 city_cache):  # fmt: skip
        (dataset / "manifest.json").unlink()  # no manifest, no journal: nothing vouches
        n_uav = json.loads((reference / "manifest.json").read_text())["counts"]["uav_images"]
        stats = simulate_dataset(dataset, SMOKE, 0, cache_dir=city_cache, progress=False)
        assert stats["replaced"] == [] and stats["rendered_uav"] == n_uav
        assert all_files(dataset) == all_files(reference)
