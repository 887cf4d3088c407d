"""The convolution ceiling and the precision plan of the benchmarks (rates are not asserted)."""

from __future__ import annotations

import re

import pytest
import torch
from torch.utils.flop_counter import FlopCounterMode

from benchmark.models import precision_support
from benchmark.models.bench_ceiling import SHAPES, conv_job, conv_step_flops, main, measure_ceiling
from benchmark.models.precision_support import precision_plan

CPU = torch.device("cpu")


class TestConvStepFlops:
    @pytest.mark.parametrize("kernel", [1, 3, 5])
    def test_matches_torch_flop_counter(self, kernel):
        """Closed form against torch's own counter on forward + both gradients."""
        conv = torch.nn.Conv2d(6, 10, kernel, padding=kernel // 2, bias=False)
        x = torch.randn(3, 6, 9, 9, requires_grad=True)
        with FlopCounterMode(display=False) as counter:
            conv(x).sum().backward()
        assert counter.get_total_flops() == conv_step_flops(3, 6, 10, 9, kernel)

    def test_job_counts_its_own_shape(self):
        run, flops = conv_job(SHAPES["4e-3x3"], CPU, "fp32", batch=1)
        assert flops == conv_step_flops(1, 160, 320, 14)
        assert run() > 0


class TestMeasureCeiling:
    def test_best_shape_is_the_maximum(self):
        r = measure_ceiling(CPU, "fp32", repeats=1, batch=1)
        assert set(r.per_shape) == set(SHAPES)
        assert r.gflops == max(r.per_shape.values()) == r.per_shape[r.best_shape] > 0

    def test_command_prints_one_line_per_precision(self, capsys):
        assert main(["--device", "cpu", "--precision", "fp32,bf16", "--repeats", "1",
                     "--batch", "1", "--threads", "1"]) == 0  # fmt: skip
        out = capsys.readouterr().out
        found = re.findall(r"^conv ceiling (fp32|bf16): ([\d.]+) GFLOP/s \(", out, re.MULTILINE)
        assert [p for p, _ in found] == ["fp32", "bf16"], out
        assert all(float(g) > 0 for _, g in found)


class TestPrecisionPlan:
    def test_default_without_bf16_support_says_why(self, monkeypatch):
        monkeypatch.setattr(precision_support, "bf16_unsupported_reason", lambda d: "no units")
        precisions, notes = precision_plan(CPU, None)
        assert precisions == ["fp32"] and notes == [
            "bf16 skipped: no units (--precision fp32,bf16 measures it anyway)"
        ]
        precisions, notes = precision_plan(CPU, "bf16,fp32")
        assert precisions == ["bf16", "fp32"] and "unsupported: no units" in notes[0]

    def test_default_with_bf16_support(self, monkeypatch):
        monkeypatch.setattr(precision_support, "bf16_unsupported_reason", lambda d: None)
        assert precision_plan(CPU, None) == (["fp32", "bf16"], [])
        assert precision_plan(CPU, " fp32 ") == (["fp32"], [])

    @pytest.mark.parametrize("spec", ["", "fp16", "fp32,fp32", "fp32;bf16"])
    def test_bad_spec(self, spec):
        with pytest.raises(ValueError, match="--precision"):
            precision_plan(CPU, spec)

    def test_cpu_reason_matches_torch(self):
        """The CPU's answer is PyTorch's oneDNN check; a reason names the CPU's vector units."""
        reason = precision_support.bf16_unsupported_reason(CPU)
        assert (reason is None) == bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
        if reason is not None:
            assert "AVX-512" in reason
