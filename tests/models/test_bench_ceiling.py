"""The convolution ceiling and the precision plan of the benchmarks (rates are not asserted)."""

from __future__ import annotations

import os
import re

import pytest
import torch
from torch.utils.flop_counter import FlopCounterMode

from benchmark.bench import ceiling as bench_ceiling
from benchmark.bench.ceiling import SHAPES, conv_job, conv_step_flops, measure_ceiling
from benchmark.commands.bench import run_target
from benchmark.errors import InputError
from benchmark.models import precision_support
from benchmark.models.precision_support import precision_plan
from tests.cpu_kinds import fake_cpu

CPU = torch.device("cpu")


def main(argv: list[str]) -> int:
    return run_target("ceiling", argv)


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

    def test_library_returns_the_ceilings_and_prints_nothing(self, capsys):
        """``bench_ceiling`` returns its measurements (the command prints ``lines()``); a bad
        precision is the library's typed error."""
        from benchmark.errors import InputError

        result = bench_ceiling.bench_ceiling("cpu", "fp32", repeats=1, batch=1, threads=1)
        assert capsys.readouterr().out == ""
        [fp32] = result.ceilings
        assert fp32.precision == "fp32" and fp32.gflops > 0 and result.device == CPU
        lines = result.lines()
        assert lines[0] == result.cpu_line and lines[0].startswith("bf16 on this CPU: ")
        head = f"conv ceiling fp32: {fp32.gflops:.1f} GFLOP/s ({fp32.best_shape}; "
        assert lines[-1].startswith(head) and lines[-1].endswith("on cpu, 1 thread(s)")
        with pytest.raises(InputError, match="fp8"):
            bench_ceiling.bench_ceiling("cpu", "fp8")


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
        # a typed InputError naming the argument (not the command line's flag)
        with pytest.raises(InputError, match=r"^precision .*: expected a comma list of distinct"):
            precision_plan(CPU, spec)

    def test_cpu_reason_matches_torch(self):
        """The CPU's answer is PyTorch's oneDNN check; a reason names the CPU's vector units."""
        reason = precision_support.bf16_unsupported_reason(CPU)
        assert (reason is None) == bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
        if reason is not None:
            assert "AVX-512" in reason


# Verbose lines as oneDNN 3.x prints them (an AVX2 machine's, and an AVX-512 BF16 one's forward).
AVX2_LINES = [
    "onednn_verbose,v1,info,oneDNN v3.12.0 (commit 80afa71049cd69a3df32adcccb623b12cd7baa22)",
    "onednn_verbose,v1,info,cpu,isa:Intel AVX2",
    "onednn_verbose,v1,primitive,exec,cpu,reorder,jit:uni,undef,src:f32::blocked:acdb::f0 ...",
    "onednn_verbose,v1,primitive,exec,cpu,convolution,brg_conv_fwd:avx2,forward_training,src:f32",
    "onednn_verbose,v1,primitive,create_nested:cache_miss,cpu,convolution,brg_conv_fwd:avx2,x",
    "onednn_verbose,v1,primitive,exec,cpu,convolution,brg_conv_bwd:avx2+brg_conv_fwd:avx2,bwd",
    "onednn_verbose,v1,primitive,exec,cpu,convolution,jit:avx2,backward_weights,src:f32::blocked",
    "onednn_verbose,v1,primitive,exec,cpu,convolution,brg_conv_fwd:avx2,forward_training,again",
]
BF16_LINE = "onednn_verbose,v1,primitive,exec,cpu,convolution,brg_conv_fwd:avx512_core_bf16,fwd"


class TestKernelReport:
    def test_implementations_parsed_in_order_once(self):
        assert bench_ceiling._conv_implementations(AVX2_LINES) == [
            "brg_conv_fwd:avx2",
            "brg_conv_bwd:avx2+brg_conv_fwd:avx2",
            "jit:avx2",
        ]
        assert bench_ceiling._conv_implementations([BF16_LINE]) == ["brg_conv_fwd:avx512_core_bf16"]
        assert bench_ceiling._conv_implementations(["hello", "a,exec,b"]) == []

    def test_report_matches_torch(self):
        """fp32 channels_last training convolutions run in oneDNN wherever PyTorch has it; bf16
        runs in oneDNN exactly where PyTorch's own check says oneDNN has bf16 kernels, else in
        ATen's reference convolution. The ATen ISA is torch's."""
        report = bench_ceiling.cpu_kernel_report(("fp32", "bf16"))
        assert report.aten_isa == torch.backends.cpu.get_cpu_capability()
        if torch.backends.mkldnn.is_available():
            assert report.conv["fp32"].startswith("oneDNN "), report
        bf16_in_onednn = bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
        assert report.conv["bf16"].startswith("oneDNN ") == bf16_in_onednn, report
        if not bf16_in_onednn:
            assert report.conv["bf16"].endswith("(no oneDNN kernel)")
            assert "_slow_conv2d_forward" in report.conv["bf16"]

    def test_captured_output_restores_the_descriptors(self, capfd):
        """What C code writes to file descriptors 1 and 2 is captured, and only inside."""
        with bench_ceiling._captured_output() as lines:
            os.write(1, b"inside 1\n")
            os.write(2, b"inside 2\n")
        os.write(1, b"outside\n")
        assert lines == ["inside 1", "inside 2"]
        assert capfd.readouterr().out == "outside\n"

    def test_line_names_flags(self, monkeypatch):
        """Native exactly when a native-bf16 flag is present (oneDNN uncapped); each flag named
        present/missing."""
        fake_cpu(monkeypatch, {"avx2", "avx512_bf16"})
        monkeypatch.setattr(bench_ceiling.platform, "machine", lambda: "x86_64")
        line = bench_ceiling.cpu_bf16_line(("fp32",))
        assert line.startswith("bf16 on this CPU: native (avx512_bf16 present, amx_bf16 missing)")
        fake_cpu(monkeypatch, {"avx", "avx2"})
        line = bench_ceiling.cpu_bf16_line(("fp32",))
        assert line.startswith(
            "bf16 on this CPU: not native (avx512_bf16 missing, amx_bf16 missing: reference code"
        )
        assert f"ATen ISA {torch.backends.cpu.get_cpu_capability()}, oneDNN ISA " in line

    def test_line_says_when_onednn_is_capped(self, monkeypatch):
        """A CPU with bf16 instructions whose oneDNN is capped below them is not native."""
        fake_cpu(monkeypatch, {"avx2", "avx512_bf16"})
        monkeypatch.setattr(bench_ceiling.platform, "machine", lambda: "x86_64")
        monkeypatch.setenv("ONEDNN_MAX_CPU_ISA", "AVX2")
        line = bench_ceiling.cpu_bf16_line(("fp32",))
        assert line.startswith(
            "bf16 on this CPU: not native (avx512_bf16 present, amx_bf16 missing: reference code "
            "(oneDNN capped at AVX2 by $ONEDNN_MAX_CPU_ISA)"
        ), line

    def test_ceiling_command_prints_the_line(self, capsys):
        assert main(["--device", "cpu", "--precision", "fp32", "--repeats", "1",
                     "--batch", "1", "--threads", "1"]) == 0  # fmt: skip
        assert capsys.readouterr().out.startswith("bf16 on this CPU: ")
