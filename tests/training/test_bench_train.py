"""``bench train`` runs end to end at a toy size; its FLOP count and ratios are checked against
closed forms and the printed rates (the measured speeds themselves are not asserted), for the
GoogLeNet and the matching encoder."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import torch
from torch import nn

from benchmark.bench import train as bench
from benchmark.bench.ceiling import conv_step_flops
from benchmark.bench.train import count_step_flops, step_flops
from benchmark.bench.train_breakdown import KINDS
from benchmark.commands import bench_train as command
from benchmark.commands.bench import run_target
from benchmark.data.dataset import CONTEXT_KEYS
from benchmark.errors import InputError
from benchmark.models import precision_support
from benchmark.models.flop_count import KINDS as KINDS_OF_FLOPS
from benchmark.models.matching_ops import fft_size
from tests.cpu_kinds import AVX2_ONLY, fake_cpu

TINY = ["--models", "quick", "--size", "32", "--width", "0.1", "--steps", "1", "--warmup", "0"]
TINY += ["--batch-size", "4", "--distinct-sat", "2", "--threads", "1"]
BOTH = [*TINY, "--encoders", "googlenet,matching"]
TINY += ["--encoders", "googlenet"]
ROW = re.compile(
    r"^quick\s+(googlenet|matching|matching_alt3)\s+32\s+(?:0\.10|-)\s+"
    r"(plain fp32|base fp32|ours fp32|ours bf16)"
    r"\s+([\d.]+)\s+([\d.]+x|-)\s+([\d.]+x|-)\s+([\d.]+)\s+([\d.]+)\s+(\d+%|-)$",
    re.MULTILINE,
)


def main(argv: list[str]) -> int:
    return run_target("train", argv)


def rows(out: str, encoder: str = "googlenet") -> dict[str, tuple[str, ...]]:
    """Loop name -> (pairs/s, x plain, x fp32, GFLOP/step, GFLOP/s, %ceiling) of ``encoder``."""
    return {m.group(2): m.groups()[2:] for m in ROW.finditer(out) if m.group(1) == encoder}


class TestBenchTrain:
    def test_rows_per_precision_and_ratios(self, capsys):
        argv = [*TINY, "--precision", "fp32,bf16", "--no-ceiling", "--optimizer", "adam"]
        assert main(argv) == 0
        out = capsys.readouterr().out
        got = rows(out)
        assert set(got) == {"plain fp32", "base fp32", "ours fp32", "ours bf16"}, out
        names = ("plain fp32", "base fp32", "ours fp32", "ours bf16")
        plain, base, fp32, bf16 = (float(got[k][0]) for k in names)
        assert min(plain, base, fp32, bf16) > 0
        # x plain and x fp32 are the ratios of the printed rates (rounding of 2 decimals).
        assert float(got["ours fp32"][1][:-1]) == pytest.approx(fp32 / plain, abs=0.02)
        assert float(got["ours bf16"][1][:-1]) == pytest.approx(bf16 / plain, abs=0.02)
        assert float(got["ours bf16"][2][:-1]) == pytest.approx(bf16 / fp32, abs=0.02)
        assert float(got["base fp32"][2][:-1]) == pytest.approx(base / fp32, abs=0.02)
        assert got["plain fp32"][2] == "-" and got["ours fp32"][5] == "-"  # no ceiling asked
        # Before/after of the optimiser change and the bf16 table repeat those rates.
        change = re.search(
            r"base fp32 -> ours fp32.*: ([\d.]+) -> ([\d.]+) pairs/s \(([\d.]+)x", out
        )
        assert change is not None, out
        assert [float(change.group(i)) for i in (1, 2)] == pytest.approx([base, fp32], abs=0.01)
        assert float(change.group(3)) == pytest.approx(fp32 / base, abs=0.02)
        table = re.search(r"^quick\s+googlenet\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)x\s+([\d.]+)x$",
                          out, re.M)  # fmt: skip
        assert table is not None and "bf16 beside fp32" in out, out
        t_fp32, t_bf16, t_ratio, t_plain = (float(x) for x in table.groups())
        assert (t_fp32, t_bf16) == pytest.approx((fp32, bf16), abs=0.01)
        assert t_ratio == pytest.approx(bf16 / fp32, abs=0.02)
        assert t_plain == pytest.approx(bf16 / plain, abs=0.02)
        # GFLOP/s = GFLOP per step x steps per second (= pairs/s / pairs per step).
        for rate, _, _, step_gflop, gflops, _ in got.values():
            expected = float(step_gflop) * float(rate) / 4
            assert float(gflops) == pytest.approx(expected, rel=0.05, abs=0.01)
        # Sharing: ours encodes 4 UAV + 2 satellite images, plain 4 + 4: fewer FLOPs per step.
        assert float(got["ours fp32"][3]) < float(got["plain fp32"][3])
        assert "load" in out.splitlines()[0] and out.splitlines()[-1].startswith("end: load")
        assert out.splitlines()[2].startswith("allocator: ")  # after the set-up and CPU lines

    @pytest.mark.usefixtures("real_cpu_flags")
    def test_cpu_line_names_the_bf16_flags_and_isa(self, capsys):
        """The line's present/missing flags are /proc/cpuinfo's (read here independently) and
        its ATen ISA is torch's; bf16 is native exactly when a native-bf16 flag is present."""
        from benchmark.bench.ceiling import native_bf16_flags

        assert main([*TINY, "--precision", "fp32", "--no-plain", "--no-base", "--no-ceiling"]) == 0
        line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("bf16 on "))
        try:
            text = Path("/proc/cpuinfo").read_text()
            flags = set(re.search(r"^(?:flags|Features)\s*:(.*)$", text, re.M).group(1).split())
        except (OSError, AttributeError):
            pytest.skip("no /proc/cpuinfo flags on this machine")
        for flag in native_bf16_flags():
            assert f"{flag} {'present' if flag in flags else 'missing'}" in line, line
        native = any(f in flags for f in native_bf16_flags())
        if precision_support.onednn_isa_cap() is not None:  # e.g. an AVX2 machine emulated
            native = native and precision_support.onednn_bf16_level() == "native"
        assert line.startswith(f"bf16 on this CPU: {'native' if native else 'not native'} (")
        assert f"ATen ISA {torch.backends.cpu.get_cpu_capability()}," in line
        assert "fp32 conv ran " in line and "bf16 conv ran " in line

    def test_library_returns_the_table_and_says_what_runs_through_status(self, capsys):
        """``bench_train`` prints nothing: its opening lines go to ``progress.status`` and the
        table is its result, whose lines hold the rows of the loops it returns."""
        from benchmark.progress import status_to

        argv = [*TINY, "--precision", "fp32", "--no-plain", "--no-base", "--no-ceiling"]
        said: list[str] = []
        with status_to(said.append):
            result = bench.bench_train(command.parse(argv))
        assert capsys.readouterr().out == ""
        assert said[0].startswith("bench train: pd_re_net on googlenet") and "load" in said[0]
        assert said[1].startswith("bf16 on this CPU: ")
        lines = result.lines()
        assert lines[0] == bench.HEADER and lines[-1] == f"end: {result.end_load}"
        [model] = result.models
        assert (model.name, model.size, model.width) == ("quick", 32, 0.1)
        [loop] = model.loops
        printed = rows("\n".join(lines))
        assert set(printed) == {"ours fp32"} and loop.loop == "ours fp32"
        assert float(printed["ours fp32"][0]) == pytest.approx(loop.pairs_per_s, abs=0.006)

    def test_base_row_only_where_the_optimiser_changed(self):
        cpu = torch.device("cpu")
        for optimizer, base in (("sgd", False), ("adam", True)):  # loop.CPU_FOREACH
            names = [s.name for s in bench.loop_specs(["fp32"], cpu, True, True, optimizer)]
            assert names == ["plain fp32", *(["base fp32"] if base else []), "ours fp32"]

    def test_base_and_ours_train_the_same_weights(self):
        """The base row (torch's per-tensor optimiser loop) and ours (foreach for Adam) differ
        in speed only: three steps from the same weights end in bit-identical weights."""
        args = command.parse([*TINY, "--optimizer", "adam"])
        cpu = torch.device("cpu")
        batch = bench.batch_of(32, 4, 2)
        clip = bench.optim_config(args).grad_clip
        weights = []
        for spec in bench.loop_specs(["fp32"], cpu, plain=False, base=True, optimizer="adam"):
            model, opt = bench.build(32, 0.1, args, spec, cpu)
            assert opt.defaults["foreach"] is (spec.name == "ours fp32")
            step = bench.make_step(model, opt, batch, spec.share, cpu, "fp32", clip)
            for _ in range(3):
                step()
            weights.append([p.detach().clone() for p in model.parameters()])
        assert len(weights) == 2
        assert all(torch.equal(a, b) for a, b in zip(*weights, strict=True))
        start = bench.build(32, 0.1, args, spec, cpu)[0].parameters()
        assert not all(torch.equal(a, b) for a, b in zip(start, weights[0], strict=True))

    def test_profile_breaks_the_step_down(self, capsys):
        argv = [*TINY, "--precision", "fp32", "--no-plain", "--no-base", "--ceiling-batch", "1"]
        assert main([*argv, "--profile", "2", "--optimizer", "adam"]) == 0
        out = capsys.readouterr().out
        line = next(x for x in out.splitlines() if x.startswith("time by kind"))
        shares = dict(re.findall(r"(\w+) (\d+)%", line.split(": ", 1)[1]))
        assert set(shares) >= {"convolution", "matmul", "optimizer", "other"}, line
        assert sum(int(shares[k]) for k in KINDS) == pytest.approx(100, abs=len(KINDS))
        assert int(shares["optimizer"]) > 0  # Adam's step and the clipping are found

    def test_ceiling_share(self, capsys):
        argv = [*TINY, "--precision", "fp32", "--no-plain", "--ceiling-batch", "1"]
        assert main([*argv, "--optimizer", "adam"]) == 0
        out = capsys.readouterr().out
        got = rows(out)
        assert set(got) == {"base fp32", "ours fp32"}, out
        ceiling = re.search(r"conv ceiling fp32: ([\d.]+) GFLOP/s", out)
        assert ceiling is not None, out
        share = float(got["ours fp32"][5][:-1])
        expected = 100 * float(got["ours fp32"][4]) / float(ceiling.group(1))
        assert share == pytest.approx(expected, abs=1.0 + 0.02 * expected)

    def test_default_precisions_follow_support(self, capsys, monkeypatch):
        from benchmark.models import precision_support

        monkeypatch.setattr(
            precision_support, "bf16_unsupported_reason", lambda d, native=False: "no units"
        )
        assert main([*TINY, "--no-ceiling", "--no-plain", "--no-base"]) == 0
        out = capsys.readouterr().out
        assert set(rows(out)) == {"ours fp32"}
        assert "bf16 skipped: no units" in out and "bf16 beside fp32" not in out
        monkeypatch.setattr(
            precision_support, "bf16_unsupported_reason", lambda d, native=False: None
        )
        assert main([*TINY, "--no-ceiling", "--no-plain", "--no-base"]) == 0
        assert set(rows(capsys.readouterr().out)) == {"ours fp32", "ours bf16"}

    def test_bf16_without_native_units_is_noted_as_training_refuses_it(self, monkeypatch):
        """On an AVX2-only CPU an explicit bf16 is measured, with training's refusal and its way
        out as a note; with the allowance set, or fp32 only, no such note."""
        fake_cpu(monkeypatch, AVX2_ONLY)
        monkeypatch.delenv(precision_support.ALLOW_SLOW_BF16_ENV, raising=False)
        args = command.parse([*TINY, "--precision", "fp32,bf16"])
        _, precisions, notes = bench.resolve(args.device, args.precision)
        assert precisions == ["fp32", "bf16"]
        note = next(n for n in notes if "for comparison only" in n)
        assert "UAVBENCH_ALLOW_SLOW_BF16=1" in note and "needs avx512_bf16 or amx_bf16" in note
        monkeypatch.setenv(precision_support.ALLOW_SLOW_BF16_ENV, "1")
        assert not any(
            "for comparison only" in n for n in bench.resolve(args.device, args.precision)[2]
        )
        monkeypatch.delenv(precision_support.ALLOW_SLOW_BF16_ENV)
        fp32 = command.parse([*TINY, "--precision", "fp32"])
        assert not any(
            "for comparison only" in n for n in bench.resolve(fp32.device, fp32.precision)[2]
        )

    def test_profile_prints_the_top_ops(self, capsys):
        argv = [*TINY, "--precision", "fp32", "--no-plain", "--no-base", "--no-ceiling"]
        argv += ["--profile", "3"]
        assert main(argv) == 0
        out = capsys.readouterr().out
        assert "profile of one step, 32 px width 0.1, googlenet ours fp32:" in out
        assert "Self CPU" in out

    @pytest.mark.parametrize(
        "argv",
        [
            ["--profile", "-1"],
            ["--models", "huge"],
            ["--encoders", "resnet"],
            ["--encoders", "matching_alt4"],
            ["--encoders", "matching,matching"],
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
        with pytest.raises(InputError):
            main(argv)

    @pytest.mark.skipif(torch.cuda.is_available(), reason="checks the message without CUDA")
    def test_cuda_without_cuda_names_the_build(self):
        with pytest.raises(InputError, match="no CUDA device"):
            main(["--device", "cuda"])


class TestMatchingEncoder:
    def test_side_by_side_with_googlenet(self, capsys):
        """Both encoders' rows in one run; the matching/googlenet line and the bf16 table repeat
        the printed rates; the FLOPs by kind add up to the step's GFLOP."""
        argv = [*BOTH, "--precision", "fp32,bf16", "--no-ceiling", "--no-base"]
        assert main(argv) == 0
        out = capsys.readouterr().out
        goog, match = rows(out, "googlenet"), rows(out, "matching")
        assert set(goog) == set(match) == {"plain fp32", "ours fp32", "ours bf16"}, out
        assert re.search(r"^quick\s+matching\s+32\s+-\s+ours fp32", out, re.M)  # no width
        line = next(x for x in out.splitlines() if "matching / googlenet" in x)
        for loop in goog:
            got = re.search(rf"{loop} ([\d.]+)x pairs/s, ([\d.]+)x GFLOP/step", line)
            assert got is not None, line
            rate = float(match[loop][0]) / float(goog[loop][0])
            assert float(got.group(1)) == pytest.approx(rate, rel=0.02, abs=0.01)
            step = float(match[loop][3]) / float(goog[loop][3])
            assert float(got.group(2)) == pytest.approx(step, rel=0.01)
        kinds = next(x for x in out.splitlines() if "matching ours fp32: GFLOP/step by kind" in x)
        parts = dict(re.findall(r"(\w+) ([\d.]+)", kinds.split("by kind: ")[1]))
        # the default correlation's real GEMMs count as matmul (no complex products left)
        assert set(parts) == {"convolution", "matmul", "sampling"}, kinds
        assert sum(map(float, parts.values())) == pytest.approx(float(match["ours fp32"][3]),
                                                                abs=0.003)  # fmt: skip
        bf16_row = r"^quick\s+(googlenet|matching)\s+([\d.]+)\s+([\d.]+)\s+[\d.]+x\s+[\d.]+x$"
        table = re.findall(bf16_row, out, re.M)
        assert [t[0] for t in table] == ["googlenet", "matching"], out
        assert float(table[1][1]) == pytest.approx(float(match["ours fp32"][0]), abs=0.01)

    def test_step_flops_are_the_closed_forms(self):
        """One training step of the matching encoder (32 px, 4 pairs over 2 satellite images,
        default options: 36 yaws, 8 channels, 25 x 25 templates on a 63 x 63 grid), kind by
        kind against the shapes: both CNN trunks and the gravity convolution (forward, input and
        weight gradients; no input gradient for the images), the DFT correlation's complex
        GEMMs (forward, and the same GEMMs again for the gradients of their left operands), the
        spectra's products and sums, and the bilinear sampling (forward and input gradient: the
        sampling positions come from the context's priors in training, no gradient)."""
        args = command.parse([*TINY, "--optimizer", "adam"])
        cpu = torch.device("cpu")
        specs = bench.loop_specs(["fp32"], cpu, False, True, "adam", "matching")
        assert [s.name for s in specs] == ["base fp32", "ours fp32"]
        assert dict(specs[0].encoder_options) == {"correlation": "dft"}  # before issue 40
        counted = {}
        for spec in specs:
            model, opt = bench.build(32, 0.1, args, spec, cpu, "matching")
            batch = bench.batch_of(32, 4, 2)
            step = bench.make_step(model, opt, batch, spec.share, cpu, "fp32", 10.0)
            step()  # builds the cached DFT matrices
            counted[spec.name] = step_flops(step)
        got, ours = counted["base fp32"], counted["ours fp32"]
        b, k, c = 4, 36, 8
        t, g = 25, 63
        L = fft_size(g)
        v, m = L // 2 + 1, g - t + 1

        def conv(n, h, w, c_out, c_in, kernel):  # forward FLOPs of one convolution
            return 2 * n * h * w * c_out * c_in * kernel * kernel

        uav = 2 * conv(b, 32, 32, 16, 3, 3) + 3 * 3 * conv(b, 16, 16, 16, 16, 3)
        uav += 3 * conv(b, 16, 16, 8, 16, 1) + 3 * conv(b, 8, 8, 16, 16, 3)  # out, gravity
        sat = 2 * conv(2, 32, 32, 16, 3, 3) + 3 * 3 * conv(2, 16, 32, 16, 16, 3)
        sat += 3 * conv(2, 16, 32, 8, 16, 1)  # 2 distinct images, pooled along rows only
        assert got["convolution"] == uav + sat
        gemms = (b * k * c) * (t * t * v + v * t * L) + (b * c) * (g * g * v + v * g * L)
        gemms += (b * k) * (v * L * m + m * v * m)
        assert got["dft"] == 2 * 8 * gemms
        cells = b * k * v * L
        forward = cells * (6 * c + 2 * (c - 1))
        backward = c * (6 * cells + 6 * cells + 2 * (cells - b * v * L))  # both factors
        assert got["spectrum"] == forward + backward
        assert got["sampling"] == 16 * b * c * (k * t * t + g * g)
        assert got["total"] == sum(got[kind] for kind in KINDS_OF_FLOPS)
        # Ours (correlate_xdft): the same convolutions and sampling, no complex work, and real
        # GEMMs counted as matmul: the template rows' DFT (forward, again in the backward pass,
        # which recomputes it, and the gradient of its input), the grid rows' DFT (forward and
        # its input's gradient: the backward keeps the forward's spectra), the batched GEMM
        # along the rows (forward and both gradients) and the inverse (forward and its input's
        # gradient).
        for kind in ("convolution", "sampling"):
            assert ours[kind] == got[kind]
        assert ours["dft"] == ours["spectrum"] == 0
        template_rows = b * 2 * v * t * (k * c * t)
        grid_rows = (b * c * g) * g * 2 * v
        inverse = (b * k * m) * 4 * v * m
        batched = (b * v) * (2 * k) * (c * t) * (2 * m)
        assert ours["matmul"] - got["matmul"] == 2 * (
            3 * template_rows + 2 * grid_rows + 3 * batched + 2 * inverse
        )

    def test_altitude_hypotheses_beside_the_matching_encoder(self, capsys):
        """``matching_alt3`` (three altitudes) in the same rounds as ``matching``: its own
        rows, a matching_alt3/matching line repeating the printed rates, and FLOPs by kind
        against the closed forms: the same convolutions (no new weights), three banks of
        templates sampled and correlated, and the satellite grid sampled once but transformed
        once per bank (``correlate`` takes the grid, not its spectrum)."""
        argv = [*TINY[:-2], "--encoders", "matching,matching_alt3", "--precision", "fp32",
                "--no-ceiling", "--no-base", "--no-plain"]  # fmt: skip
        assert main(argv) == 0
        out = capsys.readouterr().out
        one, three = rows(out, "matching"), rows(out, "matching_alt3")
        assert set(one) == set(three) == {"ours fp32"}, out
        line = next(x for x in out.splitlines() if "matching_alt3 / matching" in x)
        got = re.search(r"ours fp32 ([\d.]+)x pairs/s, ([\d.]+)x GFLOP/step", line)
        assert got is not None, line
        rate = float(three["ours fp32"][0]) / float(one["ours fp32"][0])
        assert float(got.group(1)) == pytest.approx(rate, rel=0.02, abs=0.01)

        args = command.parse([*TINY, "--optimizer", "adam"])
        cpu = torch.device("cpu")
        # the base row's correlation (the 2-D DFT): its complex GEMMs have the closed forms below
        spec = bench.loop_specs(["fp32"], cpu, False, True, "adam", "matching")[0]
        flops = {}
        for name in ("matching", "matching_alt3"):
            model, opt = bench.build(32, 0.1, args, spec, cpu, name)
            step = bench.make_step(model, opt, bench.batch_of(32, 4, 2), True, cpu, "fp32", 10.0)
            step()
            flops[name] = step_flops(step)
        b, k, c, t, g, s = 4, 36, 8, 25, 63, 3
        L = fft_size(g)
        v, m = L // 2 + 1, g - t + 1
        gemms = s * (b * k * c) * (t * t * v + v * t * L) + s * (b * c) * (g * g * v + v * g * L)
        gemms += s * (b * k) * (v * L * m + m * v * m)
        one, three = flops["matching"], flops["matching_alt3"]
        assert three["dft"] == 2 * 8 * gemms == s * one["dft"]
        assert three["convolution"] == one["convolution"]
        assert three["sampling"] == 16 * b * c * (s * k * t * t + g * g)
        assert three["spectrum"] == s * one["spectrum"]


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

    def test_split_by_kind(self):
        """A convolution and a dense layer: each kind's FLOPs are its closed form (dense layer:
        forward, grad input, grad weight, 3 x 2 B in out), and they add up to the total."""
        conv = nn.Conv2d(4, 6, 3, padding=1, bias=False)
        dense = nn.Linear(6 * 8 * 8, 5, bias=False)
        x = torch.randn(2, 4, 8, 8, requires_grad=True)

        def step() -> float:
            dense(conv(x).flatten(1)).sum().backward()
            return 0.0

        got = step_flops(step)
        assert got["convolution"] == conv_step_flops(2, 4, 6, 8)
        assert got["matmul"] == 3 * 2 * 2 * 384 * 5
        assert got["total"] == got["convolution"] + got["matmul"]

    def test_first_layer_has_no_input_gradient(self):
        conv = nn.Conv2d(3, 4, 3, padding=1, bias=False)
        x = torch.randn(1, 3, 8, 8)  # an image: no gradient wanted

        def step() -> float:
            conv(x).sum().backward()
            return 0.0

        assert count_step_flops(step) == 2 * 2 * 64 * 4 * 27


def test_optimizers_are_the_profiles():
    """--optimizer adam is the quick profile's optimiser, sgd the paper profile's (the bench
    keeps its own copy: training may not import the runner)."""
    from benchmark.runner.plan.repro_profiles import PROFILES

    for name, profile in (("adam", "quick"), ("sgd", "paper")):
        args = command.parse(["--optimizer", name])
        got, want = bench.optim_config(args), PROFILES[profile].optim
        assert (got.name, got.lr, got.grad_clip) == (want.name, want.lr, want.grad_clip)
        assert got.momentum == want.momentum and got.weight_decay == want.weight_decay


def test_batch_is_deterministic():
    a, b = bench.batch_of(32, 6, 3), bench.batch_of(32, 6, 3)
    assert all(torch.equal(a[k], b[k]) for k in a if k != "context")
    assert set(a["context"]) == set(CONTEXT_KEYS)
    assert all(torch.equal(a["context"][k], b["context"][k]) for k in CONTEXT_KEYS)
    assert torch.equal(a["sat"][0], a["sat"][3]) and a["sat_id"].tolist() == [0, 1, 2, 0, 1, 2]
    det = torch.linalg.det(a["R"])
    assert torch.allclose(det, torch.ones(6), atol=1e-5)
