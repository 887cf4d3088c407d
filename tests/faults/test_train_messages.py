"""One error style for ``uavbench train`` (issue 14 item 8): a full disk or a refused permission
while the checkpoint is written ends in one line naming the checkpoint and the fix (exit 2, no
``enforce fail at inline_container.cc``), the previous checkpoint stays as it was, and the same
command then finishes with the weights of an uninterrupted run. A damaged dataset is one line too.

Faults are injected, never real: ``open`` in ``benchmark.data.format`` (through which
``atomic_write_bytes`` writes the checkpoint) is replaced by one whose ``write`` fails as a full
disk does (``OSError`` errno 28 without a file name) or whose ``open`` is refused (EACCES).
``evaluate``'s and ``simulate``'s cases live in ``test_error_messages.py``.
"""

from __future__ import annotations

import builtins
import errno
import hashlib
import os

import torch
from test_error_messages import _FullDisk

from benchmark.cli import main
from benchmark.data import format as data_format
from benchmark.training import CHECKPOINT, load_checkpoint

TINY = ["model.width=0.25", "model.variant=/", "optim.batch_size=4", "threads=1",
        "data.limit_train=4", "data.val_split=None", "optim.epochs=2"]  # fmt: skip


def train_cli(root, out, *overrides: str) -> int:
    args = ["train", "--quiet", "--no-track", "--out", str(out), "--eval-split", "standard/test"]
    for item in [f"data.root={root}", *TINY, *overrides]:
        args += ["--set", item]
    return main(args)


def fail_checkpoint_write(monkeypatch, err: int, after: int, at: str = "write") -> list[str]:
    """Let ``after`` checkpoint writes through, then fail every later one with ``err``; returns
    the list of checkpoint paths opened for writing (temporary files)."""
    opened: list[str] = []

    def fake_open(path, mode="r", *args, **kwargs):
        if "w" in mode and f".{CHECKPOINT}.tmp" in str(path):
            opened.append(str(path))
            if len(opened) > after:
                if at == "open":
                    raise PermissionError(err, os.strerror(err), str(path))
                return _FullDisk(builtins.open(path, mode, *args, **kwargs))
        return builtins.open(path, mode, *args, **kwargs)

    monkeypatch.setattr(data_format, "open", fake_open, raising=False)
    return opened


def one_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    return err


def weights_digest(path) -> str:
    state = load_checkpoint(path)["model"]
    h = hashlib.sha256()
    for key in sorted(state):
        h.update(key.encode() + state[key].contiguous().numpy().tobytes())
    return h.hexdigest()


class TestCheckpointWrite:
    def test_disk_full_one_line_previous_checkpoint_kept_then_resumes(
        self, reference, tmp_path, monkeypatch, capsys
    ):
        torch.set_num_threads(1)
        assert train_cli(reference, tmp_path / "whole") == 0  # the uninterrupted run
        capsys.readouterr()
        out = tmp_path / "o"
        ckpt = out / "train" / CHECKPOINT
        opened = fail_checkpoint_write(monkeypatch, errno.ENOSPC, after=1)
        assert train_cli(reference, out) == 2
        err = one_line(capsys)
        assert err.startswith(f"uavbench train: error: {ckpt}: no space left on the device")
        assert "GB free" in err and "rerun the same command: finished work is kept" in err
        assert "inline_container" not in err and len(opened) == 2
        assert load_checkpoint(ckpt)["epoch"] == 1  # epoch 1's checkpoint, whole
        assert sorted(p.name for p in ckpt.parent.iterdir()) == [CHECKPOINT]  # no temp left
        monkeypatch.undo()
        assert train_cli(reference, out) == 0  # space freed: the same command finishes
        assert load_checkpoint(ckpt)["epoch"] == 2
        assert weights_digest(ckpt) == weights_digest(tmp_path / "whole" / "train" / CHECKPOINT)

    def test_permission_denied_names_the_checkpoint(self, reference, tmp_path, monkeypatch,
                                                    capsys):  # fmt: skip
        out = tmp_path / "o"
        fail_checkpoint_write(monkeypatch, errno.EACCES, after=0, at="open")
        assert train_cli(reference, out) == 2
        err = one_line(capsys)
        assert f"{out / 'train' / CHECKPOINT}: permission denied" in err
        assert "fix the permissions or choose a directory you can write" in err


class TestDamagedDataset:
    def test_truncated_shard_one_line_exit_2(self, dataset, capsys):
        shard = dataset / "uav" / "shard_00000.npy"  # standard/train's frames
        shard.write_bytes(shard.read_bytes()[:-100])
        assert train_cli(dataset, dataset.parent / "o") == 2
        err = one_line(capsys)
        assert err.startswith("uavbench train: error: ") and f"truncated file {shard}" in err
