"""``uavbench bench accelerator`` end to end on the CPU at tiny sizes (``--fast``); speeds are not
asserted, only that every figure gets its line and the reproduction's device is reported."""

from __future__ import annotations

import re

import pytest

from benchmark.commands.bench import TARGET_HELP, TARGETS, run_target
from benchmark.data import list_splits
from benchmark.errors import InputError
from benchmark.runner.plan.repro_profiles import get_repro_profile
from benchmark.runner.plan.specs import load_specs
from benchmark.runner.plan.units import plan_units


def main(argv: list[str]) -> int:
    return run_target("accelerator", argv)


FAST = ["--fast", "--device", "cpu", "--precision", "fp32,bf16", "--steps", "1", "--threads", "1"]


def test_registered_as_bench_targets():
    assert TARGETS["accelerator"] == "benchmark.commands.bench_accelerator"
    assert TARGETS["ceiling"] == "benchmark.commands.bench_ceiling"
    assert set(TARGETS) == set(TARGET_HELP)


def test_bench_and_latency_lines_without_reproduction(capsys):
    assert main([*FAST, "--no-reproduce"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("accelerator check: cpu (")
    assert out.splitlines()[1].startswith("bf16 on this CPU: ")  # native or not, the ISA
    assert "smoke reproduction" not in out
    for precision in ("fp32", "bf16"):
        assert re.search(rf"^train 48 px width 0.25 batch 4 {precision}: [\d.]+ pairs/s", out, re.M)
        assert re.search(rf"^conv ceiling {precision}: \d+ GFLOP/s$", out, re.M)
        assert re.search(rf"^inference latency 48 px width 0.25 {precision}: [\d.]+ ms/pair", out,
                         re.M)  # fmt: skip
    assert re.search(r"^train .* bf16: .*, [\d.]+x fp32\)$", out, re.M)
    assert "paper profile estimate" in out and "[--fast" in out


def test_library_returns_its_lines_and_prints_nothing(capsys):
    """``bench_accelerator`` returns the figures' lines and ``ok`` (the command prints them and
    picks the exit code); its opening lines go through ``progress.status``."""
    from benchmark.bench.accelerator import AcceleratorBenchConfig, bench_accelerator
    from benchmark.progress import status_to

    config = AcceleratorBenchConfig(device="cpu", precision="fp32", reproduce=False, steps=1,
                                    threads=1, fast=True)  # fmt: skip
    said: list[str] = []
    with status_to(said.append):
        result = bench_accelerator(config)
    assert capsys.readouterr().out == ""
    assert said[0].startswith("accelerator check: cpu (")
    assert result.ok and result.reproduction == () and result.precisions == ("fp32",)
    lines = result.lines()
    assert lines == [*result.bench, *result.latency, f"end: {result.end_load}"]
    assert lines[0].startswith("train 48 px width 0.25 batch 4 fp32: ")
    assert any(line.startswith("inference latency 48 px width 0.25 fp32: ") for line in lines)


def test_failed_reproduction_exits_1_with_its_log(tmp_path, capsys):
    (tmp_path / "data").mkdir()
    argv = [*FAST, "--precision", "fp32", "--table", "table42", "--data", str(tmp_path / "data")]
    assert main([*argv, "--keep", str(tmp_path / "keep")]) == 1
    out = capsys.readouterr().out
    # reproduce raised in its fresh interpreter: the line names the error, the log holds it
    assert re.search(r"^smoke reproduction \(table42\): FAILED, .*Error: .*table42", out, re.M), out
    assert (tmp_path / "keep" / "reproduce.log").is_file()
    assert "train 48 px" in out  # the other figures still run


@pytest.mark.parametrize("argv", [["--steps", "0"], ["--data", "/nonexistent"], ["--device", "x"]])
def test_bad_arguments(argv):
    with pytest.raises(InputError):
        main(argv)


@pytest.mark.slow
def test_smoke_reproduction_reports_the_runs_device(smoke_dataset, capsys):
    assert main([*FAST, "--precision", "fp32", "--data", str(smoke_dataset)]) == 0
    out = capsys.readouterr().out
    line = re.search(r"^smoke reproduction \(table3\): ok in \d+ s; trained models on (.*);", out,
                     re.M)  # fmt: skip
    assert line is not None, out
    # one model per planned unit of smoke's table3 (its rows x seeds, a shared encoder included)
    profile = get_repro_profile("smoke")
    units = plan_units(load_specs(only=["table3"]), profile, list(range(profile.seeds)),
                       smoke_dataset, list_splits(smoke_dataset), "h")  # fmt: skip
    assert line.group(1).startswith("cpu, fp32 (") and line.group(1).endswith(f" x{len(units)}"), (
        out
    )
