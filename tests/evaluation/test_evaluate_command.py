"""``uavbench evaluate`` argument errors (the full path: tests/training/test_command.py)."""

from __future__ import annotations

from benchmark.cli import main


class TestEvaluateCommandErrors:
    def test_missing_checkpoint(self, tmp_path, capsys):
        assert main(["evaluate", "--checkpoint", str(tmp_path / "none.pt")]) == 2
        assert "none.pt: no such file" in capsys.readouterr().err

    def test_not_a_checkpoint(self, tmp_path, capsys):
        (tmp_path / "x.pt").write_bytes(b"not a checkpoint")
        assert main(["evaluate", "--checkpoint", str(tmp_path / "x.pt")]) == 2
        assert "x.pt" in capsys.readouterr().err
