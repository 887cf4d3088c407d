"""The allocator policy set at start-up (benchmark.allocator) and its bench
(benchmark.bench.allocator), checked in fresh processes against what the kernel reports: where a
4 MiB block lives (/proc/self/maps)."""

from __future__ import annotations

import platform

import pytest

from benchmark.allocator import ALLOCATOR_ENV, ENV_SWITCH, allocator_probe
from benchmark.bench.allocator import (
    AllocatorBenchConfig,
    AllocatorBenchResult,
    AllocatorRow,
    side_environment,
)
from benchmark.bench.fresh_process import FreshProcessError, run_fresh

glibc_only = pytest.mark.skipif(
    platform.system() != "Linux" or platform.libc_ver()[0] != "glibc", reason="glibc's policy"
)


@glibc_only
class TestTuneAllocator:
    def test_default_serves_a_large_block_from_its_own_mapping(self):
        env, unset = side_environment("default")
        got = run_fresh(allocator_probe, env=env, unset=unset)
        assert got["tuned"] is False and "default" in got["detail"]
        assert got["env"] == {name: None for name in ALLOCATOR_ENV}
        assert got["in_heap"] is False  # glibc mmaps a fresh 4 MiB block

    def test_tuned_serves_it_from_the_heap_and_exports_the_figures(self):
        got = run_fresh(allocator_probe, env={}, unset=(ENV_SWITCH, *ALLOCATOR_ENV))
        assert got["tuned"] is True and "256 MiB" in got["detail"]
        assert got["env"] == ALLOCATOR_ENV  # for the processes it starts
        assert got["in_heap"] is True

    def test_a_users_own_figures_win_in_the_children(self):
        got = run_fresh(allocator_probe, env={"MALLOC_TRIM_THRESHOLD_": "12345"},
                        unset=(ENV_SWITCH,))  # fmt: skip
        assert got["env"]["MALLOC_TRIM_THRESHOLD_"] == "12345"

    def test_a_bad_switch_is_named(self):
        with pytest.raises(FreshProcessError, match=ENV_SWITCH):
            run_fresh(allocator_probe, env={ENV_SWITCH: "fast"})

    def test_the_cli_exits_2_on_a_bad_switch(self, monkeypatch, capsys):
        import benchmark.allocator as allocator
        from benchmark.commands.main import main

        monkeypatch.setattr(allocator, "_STATUS", None)
        monkeypatch.setenv(ENV_SWITCH, "fast")
        assert main(["verify", "/nonexistent"]) == 2
        assert ENV_SWITCH in capsys.readouterr().err


class TestSideEnvironment:
    def test_default_unsets_the_figures(self):
        env, unset = side_environment("default")
        assert env == {ENV_SWITCH: "default"} and set(unset) == set(ALLOCATOR_ENV)

    def test_tuned_sets_them(self):
        env, unset = side_environment("tuned")
        assert env == {ENV_SWITCH: "tuned", **ALLOCATOR_ENV} and unset == ()

    def test_unknown_side(self):
        with pytest.raises(ValueError, match="side must be"):
            side_environment("fast")


class TestAllocatorBenchConfig:
    @pytest.mark.parametrize(
        "kwargs, match",
        [
            ({"workloads": ("matcher", "gemm")}, "workloads"),
            ({"precisions": ("fp16",)}, "precisions"),
            ({"rounds": 0}, "rounds"),
            ({"warmup": -1}, "warmup"),
        ],
    )
    def test_refused(self, kwargs, match):
        with pytest.raises(ValueError, match=match):
            AllocatorBenchConfig(**kwargs)


class TestAllocatorBenchResult:
    def test_ratios_from_the_medians_of_the_rounds(self):
        base = AllocatorRow("matcher", "base fp32", {"default": [1.0, 1.2, 0.9], "tuned": [0.8]})
        ours = AllocatorRow("matcher", "ours fp32", {"default": [0.5, 0.4, 0.6], "tuned": [0.4]})
        joint = AllocatorRow("joint", "fp64", {"default": [6.0, 5.0], "tuned": [4.0, 4.0]})
        assert ours.ratio == pytest.approx(0.5 / 0.4)
        assert joint.ratio == pytest.approx(5.5 / 4.0)
        lines = AllocatorBenchResult([base, ours, joint]).lines()
        total = next(line for line in lines if "same run" in line)
        assert "2.50x" in total  # base default 1.0 over ours tuned 0.4
        assert "code alone, both default: 2.00x" in total


class TestAllocatorStatus:
    def test_untouched_until_tuned_then_the_tuning_status(self, monkeypatch):
        import benchmark.allocator as allocator

        monkeypatch.setattr(allocator, "_STATUS", None)
        assert allocator.allocator_status().tuned is False
        assert "not tuned" in allocator.allocator_status().detail
        monkeypatch.setenv(ENV_SWITCH, "default")
        status = allocator.tune_allocator()
        assert allocator.allocator_status() == status and "default" in status.detail
