"""``bench train`` runs end to end at a toy size (the measured numbers are not asserted)."""

from __future__ import annotations

import re

import pytest

from benchmark.errors import UsageError
from benchmark.training.bench import main


class TestBenchTrain:
    def test_prints_rates_and_ratio(self, capsys):
        argv = ["--models", "quick", "--size", "32", "--steps", "1", "--warmup", "0"]
        assert main([*argv, "--batch-size", "4", "--distinct-sat", "2", "--threads", "1"]) == 0
        out = capsys.readouterr().out
        row = re.search(r"quick\s+32\s+0\.25\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)x", out)
        assert row is not None, out
        ours, plain, ratio = map(float, row.groups())
        assert ours > 0 and plain > 0 and ratio == pytest.approx(ours / plain, rel=0.01)

    @pytest.mark.parametrize(
        "argv", [["--models", "huge"], ["--distinct-sat", "30"], ["--steps", "0"]]
    )
    def test_bad_arguments(self, argv):
        with pytest.raises(UsageError):
            main(argv)
