"""The bench commands print what the library benches return and map their verdicts to exit codes
(the library neither prints its table nor returns an exit code; issue 41). The measurements are
replaced by fixed results, so these run in no time; the end-to-end runs are in the benches' own
tests (``test_bench_train``, ``test_bench_accelerator``, ``test_bench_ceiling``, ...)."""

from __future__ import annotations

from pathlib import Path

import pytest

from benchmark.bench import isa, ray_cluster, simulate, verify
from benchmark.commands.bench import run_target
from benchmark.errors import InputError, UsageError


def rates(rate_96: float) -> simulate.SimulateBenchResult:
    size_96 = simulate.SizeRate(96, rate_96, 800, 1, 0.0123, 1.5, 150.0)
    size_64 = simulate.SizeRate(64, 10.0, 800, 1, 0.002, 1.0, None)  # no target at 64 px
    return simulate.SimulateBenchResult("oxford", 4, 2.5, 0.25, 42.0, (size_96, size_64))


class TestSimulate:
    def test_lines_are_the_old_print(self):
        lines = rates(165.0).lines()
        assert lines == [
            "city build (oxford, from scratch, 4 illumination states): 2.50 s; load from cache: "
            "0.25 s; cache 42 MB",
            "  96 px:   165.0 pairs/s over 800 pairs, supersample 1 (target >= 150: OK, ratio "
            "1.10); satellite image 12 ms; worker start-up 1.5 s (not counted)",
            "  64 px:    10.0 pairs/s over 800 pairs, supersample 1; satellite image 2 ms; "
            "worker start-up 1.0 s (not counted)",
        ]
        assert "BELOW TARGET, ratio 0.67" in rates(100.0).lines()[1]

    @pytest.mark.parametrize(
        ("rate", "strict", "code"), [(165.0, True, 0), (100.0, False, 0), (100.0, True, 1)]
    )
    def test_strict_exits_1_only_for_a_missed_target(self, monkeypatch, capsys, rate, strict,
                                                     code):  # fmt: skip
        monkeypatch.setattr(simulate, "bench_simulate", lambda config: rates(rate))
        assert run_target("simulate", ["--sizes", "96", *(["--strict"] if strict else [])]) == code
        assert capsys.readouterr().out.splitlines() == rates(rate).lines()

    def test_bad_counts(self):
        with pytest.raises(UsageError, match="--workers >= 1"):
            run_target("simulate", ["--pairs", "0"])
        with pytest.raises(InputError, match=r"SimulateBenchConfig\.workers") as error:
            simulate.bench_simulate(simulate.SimulateBenchConfig(sizes=(4,)))
        assert "--" not in str(error.value)


class TestRay:
    RESULT = ray_cluster.BenchRayResult((30.0, 20.0, 25.0), (31.0, 24.0, 26.5), same=True)

    def test_lines_are_the_old_print(self):
        assert self.RESULT.lines() == [
            "process pool      25.0 s (median wall of reproduce)",
            "local Ray         26.5 s",
            "Ray / pool        1.06x (within the 1.3x target)",
            "results.csv    identical numbers",
        ]
        slow = ray_cluster.BenchRayResult((10.0,), (20.0,), same=False)
        assert slow.lines()[2:] == [
            "Ray / pool        2.00x (OVER the 1.3x target)",
            "results.csv    NUMBERS DIFFER",
        ]

    @pytest.mark.parametrize("same", [True, False])
    def test_exit_1_when_the_numbers_differ(self, monkeypatch, capsys, same):
        result = ray_cluster.BenchRayResult((10.0,), (11.0,), same)
        monkeypatch.setattr(ray_cluster, "bench_ray", lambda config: result)
        assert run_target("ray", ["--workers", "1"]) == (0 if same else 1)
        assert capsys.readouterr().out.splitlines() == result.lines()

    def test_library_names_its_fields(self):
        with pytest.raises(InputError, match=r"BenchRayConfig\.workers") as error:
            ray_cluster.bench_ray(ray_cluster.BenchRayConfig(workers=0))
        assert "--" not in str(error.value)


class TestIsa:
    @pytest.mark.parametrize(("differs", "strict", "code"),
                             [(False, True, 0), (True, False, 0), (True, True, 1)])  # fmt: skip
    def test_strict_exits_1_when_a_digest_differs(self, monkeypatch, capsys, differs, strict,
                                                  code):  # fmt: skip
        default = isa.IsaRow("default", "a" * 64, True, 1.0, {}, {"aten": "AVX2"}, ())
        files = ("uav/000.npy",) if differs else ()
        forced, effect = {"ATEN_CPU_CAPABILITY": "default"}, {"aten": "DEFAULT"}
        torch_row = isa.IsaRow("torch", "b" * 64, not differs, 1.0, forced, effect, files)
        result = isa.IsaBenchResult((default, torch_row))
        monkeypatch.setattr(isa, "bench_isa", lambda config: result)
        argv = ["--only", "torch", *(["--strict"] if strict else [])]
        assert run_target("isa", argv) == code
        assert capsys.readouterr().out.splitlines() == result.lines()


class TestVerify:
    def test_prints_the_table(self, monkeypatch, capsys, tmp_path):
        rows = (
            verify.OpenTimes("open standard/train", 0.001, 0.5, 0.002, 0.004, 0.5),
            verify.OpenTimes("all files", 0.002, 1.0, 0.003, 0.005, 1.0),
        )
        result = verify.VerifyBenchResult(tmp_path, 12, 250.0, 5, rows)
        assert result.hashing_mb_per_s == 250.0
        lines = result.lines()
        assert lines[0] == f"uavbench bench verify: {tmp_path} (12 files, 250 MB), median of 5 " \
                           "later opens"  # fmt: skip
        assert lines[2].split() == ["open", "standard/train", "1.0", "ms", "500.0", "ms", "2.0",
                                    "ms", "4.0", "ms", "500.0", "ms", "125x", "4.00x"]  # fmt: skip
        assert lines[-1] == "hashing rate (full check of all files): 250 MB/s"
        monkeypatch.setattr(verify, "bench_verify", lambda dataset, split, repeats: result)
        assert run_target("verify", [str(tmp_path)]) == 0
        assert capsys.readouterr().out.splitlines() == lines

    def test_repeats_below_1(self, tmp_path: Path):
        with pytest.raises(SystemExit):
            run_target("verify", [str(tmp_path), "--repeats", "0"])
        with pytest.raises(InputError, match="repeats must be >= 1") as error:
            verify.bench_verify(tmp_path, repeats=0)
        assert "--" not in str(error.value)
