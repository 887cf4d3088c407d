"""One error style (issue 14 item 8): disk full, permission and damaged-dataset errors of
``simulate``, ``evaluate`` and ``verify`` end in one line naming the path and the fix, exit 2.

Disk full is injected by replacing the ``open`` that ``benchmark.data.format.atomic_write_bytes``
writes through with one whose ``write`` fails as a full disk does (``OSError`` errno 28 without a
file name), never by filling the disk.
"""

from __future__ import annotations

import builtins
import errno
import os

import pytest
from fault_tools import all_files

from benchmark.cli import main
from benchmark.data import format as data_format
from benchmark.data import integrity as integ


class _FullDisk:
    """A file opened for writing whose writes fail with ENOSPC (the real file is created)."""

    def __init__(self, fh):
        self._fh = fh

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._fh.close()

    def write(self, data):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def __getattr__(self, name):
        return getattr(self._fh, name)


def inject(monkeypatch, match: str, err: int, at: str = "write") -> None:
    """Make ``atomic_write_bytes`` fail with ``err`` for paths containing ``match``: at ``open``
    (EACCES, EROFS: the directory refuses the file) or at ``write`` (ENOSPC, EDQUOT)."""

    def fake_open(path, mode="r", *args, **kwargs):
        if "w" in mode and match in str(path):
            if at == "open":
                raise PermissionError(err, os.strerror(err), str(path))
            return _FullDisk(builtins.open(path, mode, *args, **kwargs))
        return builtins.open(path, mode, *args, **kwargs)

    monkeypatch.setattr(data_format, "open", fake_open, raising=False)


def one_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    return err


def simulate(out, city_cache) -> int:
    return main(["simulate", "--profile", "smoke", "--out", str(out), "--workers", "1",
                 "--city-cache", str(city_cache), "--quiet"])  # fmt: skip


class TestSimulate:
    def test_disk_full_names_the_shard_then_resumes(self, tmp_path, reference, city_cache,
                                                    monkeypatch, capsys):  # fmt: skip
        out = tmp_path / "ds"
        inject(monkeypatch, "uav/.shard_00002.npy", errno.ENOSPC)
        assert simulate(out, city_cache) == 2
        err = one_line(capsys)
        assert err.startswith(f"uavbench simulate: error: {out / 'uav' / 'shard_00002.npy'}: ")
        assert "no space left on the device" in err and "GB free" in err
        assert "rerun the same command" in err
        assert not list(out.rglob(".*.tmp*"))  # no partial file left behind
        monkeypatch.undo()
        assert simulate(out, city_cache) == 0  # space freed: the same command finishes
        assert all_files(out) == all_files(reference)

    def test_permission_denied_names_the_file(self, tmp_path, city_cache, monkeypatch, capsys):
        out = tmp_path / "ds"
        inject(monkeypatch, "config.json", errno.EACCES, at="open")
        assert simulate(out, city_cache) == 2
        err = one_line(capsys)
        assert f"{out / 'config.json'}: permission denied" in err
        assert "fix the permissions or choose a directory you can write" in err

    def test_read_only_file_system(self, tmp_path, city_cache, monkeypatch, capsys):
        inject(monkeypatch, "config.json", errno.EROFS, at="open")
        assert simulate(tmp_path / "ds", city_cache) == 2
        assert "read-only file system; choose a writable directory" in one_line(capsys)


class TestEvaluate:
    def run(self, checkpoint, data, out):
        return main(["evaluate", "--quiet", "--checkpoint", str(checkpoint), "--data-root",
                     str(data), "--split", "standard/test", "--out", str(out)])  # fmt: skip

    @pytest.mark.parametrize("verify", ["sha256", "size"])
    def test_truncated_shard_one_line(self, dataset, checkpoint, verify, tmp_path, capsys):
        shard = dataset / "uav" / "shard_00001.npy"  # standard/test's frames
        shard.write_bytes(shard.read_bytes()[:-100])
        code = main(["evaluate", "--quiet", "--checkpoint", str(checkpoint), "--data-root",
                     str(dataset), "--split", "standard/test", "--verify", verify,
                     "--out", str(tmp_path / "e")])  # fmt: skip
        err = one_line(capsys)
        assert code == 2 and f"truncated file {shard}" in err and "uavbench verify" in err

    def test_disk_full_names_the_output(self, reference, checkpoint, tmp_path, monkeypatch,
                                        capsys):  # fmt: skip
        import benchmark.evaluation.evaluate as ev

        def full(*args, **kwargs):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))  # as a CSV writer raises it

        monkeypatch.setattr(ev, "write_predictions_csv", full)
        assert self.run(checkpoint, reference, tmp_path / "e") == 2
        err = one_line(capsys)
        assert f"{tmp_path / 'e'}: no space left on the device" in err

    def test_metrics_file_permission_denied(self, reference, checkpoint, tmp_path, monkeypatch,
                                            capsys):  # fmt: skip
        inject(monkeypatch, "metrics.json", errno.EACCES, at="open")
        assert self.run(checkpoint, reference, tmp_path / "e") == 2
        assert f"{tmp_path / 'e' / 'metrics.json'}: permission denied" in one_line(capsys)


class TestVerify:
    def test_unreadable_file_one_line(self, dataset, monkeypatch, capsys):
        def denied(path, chunk=1 << 22):
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(path))

        monkeypatch.setattr(integ, "sha256_file", denied)
        assert main(["verify", "--quiet", str(dataset)]) == 2
        assert "permission denied" in one_line(capsys)

    def test_damaged_manifest_exit_1_with_the_fix(self, dataset, reference, city_cache, capsys):
        (dataset / "manifest.json").write_text('{"format_version": 2, "fil')
        assert main(["verify", "--quiet", str(dataset)]) == 1
        err = capsys.readouterr().err
        assert "not valid JSON" in err and "uavbench simulate --profile smoke" in err
        assert simulate(dataset, city_cache) == 0
        assert all_files(dataset) == all_files(reference)
