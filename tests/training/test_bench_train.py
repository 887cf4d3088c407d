"""``bench train`` runs end to end at a toy size; its FLOP count and ratios are checked against
closed forms and the printed rates (the measured speeds themselves are not asserted)."""

from __future__ import annotations

import re

import pytest
import torch
from torch import nn

from benchmark.errors import UsageError
from benchmark.models.bench_ceiling import conv_step_flops
from benchmark.training import bench
from benchmark.training.bench import count_step_flops, main

TINY = ["--models", "quick", "--size", "32", "--width", "0.1", "--steps", "1", "--warmup", "0"]
TINY += ["--batch-size", "4", "--distinct-sat", "2", "--threads", "1"]
ROW = re.compile(
    r"^quick\s+32\s+0\.10\s+(plain fp32|ours fp32|ours bf16)\s+([\d.]+)\s+([\d.]+x|-)\s+"
    r"([\d.]+x|-)\s+([\d.]+)\s+([\d.]+)\s+(\d+%|-)$",
    re.MULTILINE,
)


def rows(out: str) -> dict[str, tuple[str, ...]]:
    return {m.group(1): m.groups()[1:] for m in ROW.finditer(out)}


class TestBenchTrain:
    def test_rows_per_precision_and_ratios(self, capsys):
        assert main([*TINY, "--precision", "fp32,bf16", "--no-ceiling"]) == 0
        out = capsys.readouterr().out
        got = rows(out)
        assert set(got) == {"plain fp32", "ours fp32", "ours bf16"}, out
        plain, fp32, bf16 = (float(got[k][0]) for k in ("plain fp32", "ours fp32", "ours bf16"))
        assert min(plain, fp32, bf16) > 0
        # x plain and x fp32 are the ratios of the printed rates (rounding of 2 decimals).
        assert float(got["ours fp32"][1][:-1]) == pytest.approx(fp32 / plain, abs=0.02)
        assert float(got["ours bf16"][1][:-1]) == pytest.approx(bf16 / plain, abs=0.02)
        assert float(got["ours bf16"][2][:-1]) == pytest.approx(bf16 / fp32, abs=0.02)
        assert got["plain fp32"][2] == "-" and got["ours fp32"][5] == "-"  # no ceiling asked
        # GFLOP/s = GFLOP per step x steps per second (= pairs/s / pairs per step).
        for rate, _, _, step_gflop, gflops, _ in got.values():
            expected = float(step_gflop) * float(rate) / 4
            assert float(gflops) == pytest.approx(expected, rel=0.05, abs=0.01)
        # Sharing: ours encodes 4 UAV + 2 satellite images, plain 4 + 4: fewer FLOPs per step.
        assert float(got["ours fp32"][3]) < float(got["plain fp32"][3])
        assert "load" in out.splitlines()[0] and out.splitlines()[-1].startswith("end: load")

    def test_ceiling_share(self, capsys):
        argv = [*TINY, "--precision", "fp32", "--no-plain", "--ceiling-batch", "1"]
        assert main(argv) == 0
        out = capsys.readouterr().out
        got = rows(out)
        assert set(got) == {"ours fp32"}, out
        ceiling = re.search(r"conv ceiling fp32: ([\d.]+) GFLOP/s", out)
        assert ceiling is not None, out
        share = float(got["ours fp32"][5][:-1])
        expected = 100 * float(got["ours fp32"][4]) / float(ceiling.group(1))
        assert share == pytest.approx(expected, abs=1.0 + 0.02 * expected)

    def test_default_precisions_follow_support(self, capsys, monkeypatch):
        from benchmark.models import precision_support

        monkeypatch.setattr(precision_support, "bf16_unsupported_reason", lambda d: "no units")
        assert main([*TINY, "--no-ceiling", "--no-plain"]) == 0
        out = capsys.readouterr().out
        assert set(rows(out)) == {"ours fp32"}
        assert "bf16 skipped: no units" in out
        monkeypatch.setattr(precision_support, "bf16_unsupported_reason", lambda d: None)
        assert main([*TINY, "--no-ceiling", "--no-plain"]) == 0
        assert set(rows(capsys.readouterr().out)) == {"ours fp32", "ours bf16"}

    def test_profile_prints_the_top_ops(self, capsys):
        argv = [*TINY, "--precision", "fp32", "--no-plain", "--no-ceiling", "--profile", "3"]
        assert main(argv) == 0
        out = capsys.readouterr().out
        assert "profile of one step, 32 px width 0.1, ours fp32:" in out and "Self CPU" in out

    @pytest.mark.parametrize(
        "argv",
        [
            ["--profile", "-1"],
            ["--models", "huge"],
            ["--distinct-sat", "30"],
            ["--steps", "0"],
            ["--warmup", "-1"],
            ["--ceiling-batch", "0"],
            ["--precision", "fp8"],
            ["--precision", "fp32,fp32"],
            ["--device", "tpu"],
        ],
    )
    def test_bad_arguments(self, argv):
        with pytest.raises(UsageError):
            main(argv)

    @pytest.mark.skipif(torch.cuda.is_available(), reason="checks the message without CUDA")
    def test_cuda_without_cuda_names_the_build(self):
        with pytest.raises(UsageError, match="no CUDA device"):
            main(["--device", "cuda"])


class TestCountStepFlops:
    def test_conv_step_is_three_passes(self):
        """A training step of one 3x3 convolution whose input needs a gradient: forward, grad
        input and grad weight, 3 x 2 N H W C_out C_in 9 FLOPs (the closed form)."""
        conv = nn.Conv2d(8, 16, 3, padding=1, bias=False)
        x = torch.randn(2, 8, 12, 12, requires_grad=True)

        def step() -> float:
            conv(x).sum().backward()
            return 0.0

        assert count_step_flops(step) == conv_step_flops(2, 8, 16, 12) == 3 * 2 * 2 * 144 * 16 * 72

    def test_first_layer_has_no_input_gradient(self):
        conv = nn.Conv2d(3, 4, 3, padding=1, bias=False)
        x = torch.randn(1, 3, 8, 8)  # an image: no gradient wanted

        def step() -> float:
            conv(x).sum().backward()
            return 0.0

        assert count_step_flops(step) == 2 * 2 * 64 * 4 * 27


def test_batch_is_deterministic():
    a, b = bench.batch_of(32, 6, 3), bench.batch_of(32, 6, 3)
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert torch.equal(a["sat"][0], a["sat"][3]) and a["sat_id"].tolist() == [0, 1, 2, 0, 1, 2]
    det = torch.linalg.det(a["R"])
    assert torch.allclose(det, torch.ones(6), atol=1e-5)
