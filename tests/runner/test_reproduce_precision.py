"""``uavbench reproduce --device/--precision`` (issue 20): every unit trains in the precision
asked for, its runs say so, and a precision the machine cannot run is refused before any work.

The bf16 reproduction runs on every machine: where the CPU has no native bf16 (``avx512_bf16`` /
``amx_bf16``) it sets ``UAVBENCH_ALLOW_SLOW_BF16=1``, the documented way to run bf16 anyway.
"""

from __future__ import annotations

import json

import pytest
import torch

from benchmark.cli import main
from benchmark.models.precision_support import onednn_bf16_level
from benchmark.runner.execute import audit as audit_module
from tests.cpu_kinds import AVX2_ONLY, fake_cpu


def reproduce(tmp_path, dataset, *extra: str) -> int:
    return main([
        "reproduce", "--profile", "smoke", "--data", str(dataset), "--out",
        str(tmp_path / "reports"), "--workdir", str(tmp_path / "runs"), "--tracker", "local",
        "--quiet", "--workers", "1", "--seeds", "1", "--no-models", "--only", "fig7", *extra,
    ])  # fmt: skip


def unit_runs(tmp_path) -> list[dict]:
    """The run records of the trained units (those with a device tag)."""
    runs = [json.loads(p.read_text()) for p in (tmp_path / "tracking-local").rglob("run.json")]
    return [r for r in runs if "device" in r["tags"]]


class TestRefusedBeforeAnyWork:
    def test_unknown_precision_is_one_line(self, tmp_path, smoke_dataset, capsys):
        assert reproduce(tmp_path, smoke_dataset, "--precision", "fp8") == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1
        assert "precision must be one of auto, fp32, bf16, fp16, got 'fp8'" in err
        assert not (tmp_path / "runs").exists()

    def test_bf16_without_native_units_names_the_instruction_set(
        self, tmp_path, smoke_dataset, capsys, monkeypatch
    ):
        monkeypatch.delenv("UAVBENCH_ALLOW_SLOW_BF16", raising=False)
        fake_cpu(monkeypatch, AVX2_ONLY)
        assert reproduce(tmp_path, smoke_dataset, "--device", "cpu", "--precision", "bf16") == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "avx512_bf16" in err and "avx2" in err
        assert "UAVBENCH_ALLOW_SLOW_BF16" in err
        assert not (tmp_path / "runs").exists()

    @pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has CUDA")
    def test_missing_device_is_one_line(self, tmp_path, smoke_dataset, capsys):
        assert reproduce(tmp_path, smoke_dataset, "--device", "cuda:1") == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "cuda:1" in err


@pytest.mark.slow
class TestBf16SmokeReproduction:
    def test_units_train_in_bf16_and_are_tagged(self, tmp_path, smoke_dataset, monkeypatch):
        if onednn_bf16_level() != "native":
            monkeypatch.setenv("UAVBENCH_ALLOW_SLOW_BF16", "1")
        monkeypatch.setattr(audit_module, "heading_cue_rows", lambda root, **kwargs: [])
        monkeypatch.chdir(tmp_path)  # the local tracking store lives in the working directory
        assert reproduce(tmp_path, smoke_dataset, "--device", "cpu", "--precision", "bf16") == 0
        bf16 = unit_runs(tmp_path)
        assert bf16 and {r["tags"]["precision"] for r in bf16} == {"bf16"}
        assert {r["status"] for r in bf16} == {"FINISHED"}
        assert "fig7.md" in {p.name for p in (tmp_path / "reports").iterdir()}
        # the report says which precision produced it (issue 40)
        readme = (tmp_path / "reports" / "README.md").read_text()
        assert "Precision: every unit trained and evaluated in bf16." in readme
        # fp32 units are other models: a second reproduction trains them instead of reusing bf16
        assert reproduce(tmp_path, smoke_dataset, "--device", "cpu", "--precision", "fp32") == 0
        runs = unit_runs(tmp_path)
        fp32_keys = {r["tags"]["run_key"] for r in runs if r["tags"]["precision"] == "fp32"}
        assert fp32_keys and not fp32_keys & {r["tags"]["run_key"] for r in bf16}
        readme = (tmp_path / "reports" / "README.md").read_text()
        assert "Precision: every unit trained and evaluated in fp32." in readme


class TestPrecisionText:
    @staticmethod
    def units(*precisions: str) -> list:
        from types import SimpleNamespace

        return [SimpleNamespace(cfg=SimpleNamespace(precision=p)) for p in precisions]

    def test_one_precision(self):
        from benchmark.runner.report.outputs import precision_text

        assert precision_text(self.units("fp32", "fp32")) == (
            "Precision: every unit trained and evaluated in fp32."
        )

    def test_mixed_precisions_are_counted(self):
        from benchmark.runner.report.outputs import precision_text

        assert precision_text(self.units("bf16", "fp32", "fp32")) == (
            "Precision: mixed, 1 in bf16, 2 in fp32 (units)."
        )

    def test_no_units_no_sentence(self):
        from benchmark.runner.report.outputs import precision_text

        assert precision_text([]) == ""
