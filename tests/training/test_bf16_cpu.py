"""``precision: bf16`` on a CPU (issue 20): native bf16 only, or an explicit allowance to emulate.

"Native" is defined once in ``benchmark/models/precision_support.py``: the CPU has ``avx512_bf16``
or ``amx_bf16`` (Arm: ``bf16``). PyTorch's ``torch.ops.mkldnn._is_mkldnn_bf16_supported()`` is
True on plain AVX-512 too (``avx512bw``/``vl``/``dq``: oneDNN widens bf16 to fp32 in registers),
so it is not the test of "native". Every test here runs on every machine: where this CPU lacks
native bf16, the end-to-end run sets ``UAVBENCH_ALLOW_SLOW_BF16=1`` explicitly; the error tests
replace the CPU's flags with a known AVX2-only / AVX-512-without-bf16 set.
"""

from __future__ import annotations

import json
import math

import pandas as pd
import pytest
import torch

from benchmark.cli import main
from benchmark.models.device import (
    PrecisionUnsupportedError,
    check_precision_supported,
    resolve_precision,
)
from benchmark.models.precision_support import (
    ALLOW_SLOW_BF16_ENV,
    bf16_support_label,
    bf16_unsupported_reason,
    cpu_bf16_level,
    onednn_bf16_level,
)
from tests.cpu_kinds import AVX2_ONLY, AVX512_NO_BF16, SAPPHIRE_RAPIDS, ZEN4, fake_cpu

CPU = torch.device("cpu")
NATIVE_HERE = onednn_bf16_level() == "native"


class TestWhatNativeMeans:
    @pytest.mark.parametrize(
        ("flags", "level"),
        [
            (AVX2_ONLY, "reference"),
            (AVX512_NO_BF16, "converted"),  # _is_mkldnn_bf16_supported() is True here
            (AVX512_NO_BF16 - {"avx512dq"}, "reference"),  # oneDNN wants bw, vl and dq
            (ZEN4, "native"),
            (SAPPHIRE_RAPIDS, "native"),
            ({"fp", "asimd", "bf16"}, "native"),  # Armv8.6 BF16 (Graviton 3, Neoverse V1)
        ],
    )
    def test_levels_from_cpu_flags(self, flags, level):
        assert cpu_bf16_level(flags) == level

    @pytest.mark.usefixtures("real_cpu_flags")
    def test_this_cpu_against_torch(self):
        """This machine's level agrees with torch's own cpuinfo (an independent flag reader) and
        with PyTorch's oneDNN check: the hardware is native exactly when cpuinfo has
        avx512_bf16/amx_bf16; oneDNN's level (after any ``ONEDNN_MAX_CPU_ISA`` cap) is converted
        or native exactly when oneDNN has bf16 kernels (x86)."""
        caps = torch.cpu.get_capabilities()
        if caps.get("architecture") == "x86_64":
            assert (cpu_bf16_level() == "native") == bool(caps["avx512_bf16"] or caps["amx_bf16"])
            oneDNN = bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
            assert (onednn_bf16_level() != "reference") == oneDNN

    @pytest.mark.parametrize(
        ("cap", "flags", "level"),
        [
            ("AVX2", SAPPHIRE_RAPIDS, "reference"),
            ("avx2", ZEN4, "reference"),  # oneDNN reads the name in any case
            ("AVX512_CORE", ZEN4, "converted"),
            ("AVX512_CORE_VNNI", SAPPHIRE_RAPIDS, "converted"),
            ("AVX512_CORE_BF16", ZEN4, "native"),
            ("AVX512_CORE_AMX", SAPPHIRE_RAPIDS, "native"),
            ("ALL", ZEN4, "native"),
            ("AVX512_CORE", AVX2_ONLY, "reference"),  # a cap never raises the hardware's level
        ],
    )
    def test_a_onednn_cap_lowers_the_level(self, monkeypatch, cap, flags, level):
        fake_cpu(monkeypatch, flags)
        monkeypatch.setenv("ONEDNN_MAX_CPU_ISA", cap)
        assert onednn_bf16_level() == level
        assert cpu_bf16_level() == cpu_bf16_level(set(flags))  # the hardware's, uncapped

    def test_the_old_variable_name_caps_too_and_the_label_says_why(self, monkeypatch):
        fake_cpu(monkeypatch, ZEN4)
        monkeypatch.setenv("DNNL_MAX_CPU_ISA", "AVX2")
        assert onednn_bf16_level() == "reference"
        assert bf16_support_label(CPU) == (
            "reference code (oneDNN capped at AVX2 by $ONEDNN_MAX_CPU_ISA)"
        )
        reason = bf16_unsupported_reason(CPU, native=True)
        assert reason is not None and reason.startswith("oneDNN is capped at AVX2 by ")

    def test_the_cap_refuses_native_training(self, monkeypatch):
        """Training in bf16 is refused where oneDNN may not use the bf16 instructions, even on
        a CPU that has them."""
        monkeypatch.delenv(ALLOW_SLOW_BF16_ENV, raising=False)
        fake_cpu(monkeypatch, SAPPHIRE_RAPIDS)
        monkeypatch.setenv("ONEDNN_MAX_CPU_ISA", "AVX512_CORE")
        with pytest.raises(PrecisionUnsupportedError, match="capped at AVX512_CORE"):
            check_precision_supported("bf16", CPU)

    def test_labels_for_the_benchmarks(self, monkeypatch):
        fake_cpu(monkeypatch, SAPPHIRE_RAPIDS)
        assert bf16_support_label(CPU) == "native (avx512_bf16, amx_bf16)"
        fake_cpu(monkeypatch, AVX512_NO_BF16)
        assert bf16_support_label(CPU) == "converted to fp32 in AVX-512 registers (not native)"
        fake_cpu(monkeypatch, AVX2_ONLY)
        assert bf16_support_label(CPU) == "reference code (no AVX-512)"

    def test_auto_stays_fp32_on_a_cpu_with_native_bf16(self, monkeypatch):
        """The default numbers never depend on the CPU's bf16 units."""
        for flags in (AVX2_ONLY, ZEN4, SAPPHIRE_RAPIDS):
            fake_cpu(monkeypatch, flags)
            assert resolve_precision("auto", CPU) == "fp32"
            check_precision_supported("fp32", CPU)  # fp32 runs anywhere

    def test_native_cpu_needs_no_allowance(self, monkeypatch):
        monkeypatch.delenv(ALLOW_SLOW_BF16_ENV, raising=False)
        fake_cpu(monkeypatch, ZEN4)
        assert bf16_unsupported_reason(CPU, native=True) is None
        check_precision_supported("bf16", CPU)


class TestRefusedWithoutNativeBf16:
    @pytest.mark.parametrize(
        ("flags", "has", "why"),
        [
            (AVX2_ONLY, "it has avx, avx2 (", "oneDNN has no bf16 kernels"),
            (AVX512_NO_BF16, "avx512_vnni, avx512bw, avx512dq, avx512f, avx512vl (",
             "widens bf16 to fp32"),
        ],
    )  # fmt: skip
    def test_message_names_the_missing_and_present_instruction_sets(
        self, monkeypatch, flags, has, why
    ):
        monkeypatch.delenv(ALLOW_SLOW_BF16_ENV, raising=False)
        fake_cpu(monkeypatch, flags)
        with pytest.raises(PrecisionUnsupportedError) as info:
            check_precision_supported("bf16", CPU)
        message = str(info.value)
        assert "\n" not in message
        assert "needs avx512_bf16 or amx_bf16" in message and has in message and why in message
        assert f"set {ALLOW_SLOW_BF16_ENV}=1" in message and "precision=fp32" in message

    @pytest.mark.parametrize("value", ["1", "yes", "true"])
    def test_explicit_allowance_runs_it(self, monkeypatch, value):
        fake_cpu(monkeypatch, AVX2_ONLY)
        monkeypatch.setenv(ALLOW_SLOW_BF16_ENV, value)
        check_precision_supported("bf16", CPU)
        monkeypatch.setenv(ALLOW_SLOW_BF16_ENV, "0")
        with pytest.raises(PrecisionUnsupportedError):
            check_precision_supported("bf16", CPU)

    def test_train_and_evaluate_commands_exit_2_in_one_line(self, monkeypatch, tmp_path, capsys):
        monkeypatch.delenv(ALLOW_SLOW_BF16_ENV, raising=False)
        fake_cpu(monkeypatch, AVX2_ONLY)
        args = ["train", "--no-track", "--set", f"data.root={tmp_path}", "--set", "device=cpu",
                "--set", "precision=bf16"]  # fmt: skip
        assert main(args) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1, err
        assert "precision=bf16" in err and "needs avx512_bf16 or amx_bf16" in err
        assert "it has avx, avx2" in err and ALLOW_SLOW_BF16_ENV in err
        assert "data.root" not in err  # refused before the (empty) dataset is looked at
        (tmp_path / "c.pt").write_bytes(b"")  # the check comes before the checkpoint is read
        args = ["evaluate", "--checkpoint", str(tmp_path / "c.pt"), "--device", "cpu",
                "--precision", "bf16"]  # fmt: skip
        assert main(args) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "needs avx512_bf16 or amx_bf16" in err, err


class TestSmokeUnitInBf16:
    def test_trains_evaluates_and_is_tracked_as_bf16(self, smoke_dataset, tmp_path, monkeypatch):
        """``uavbench train --set precision=bf16`` on the smoke dataset: trains, evaluates with
        the true and the swapped satellite image and logs an MLflow run tagged precision=bf16;
        ``uavbench evaluate --precision bf16`` on its checkpoint gives the same predictions.
        (Re-Net-R keeps it fast; Pd/Re-Net's logits in bf16: test_devices.py::TestBf16OnCpu.)"""
        from mlflow.tracking import MlflowClient

        if NATIVE_HERE:
            monkeypatch.delenv(ALLOW_SLOW_BF16_ENV, raising=False)
        else:  # the explicit allowance: bf16 emulated, but exercised on every machine
            monkeypatch.setenv(ALLOW_SLOW_BF16_ENV, "1")
        monkeypatch.chdir(tmp_path)
        monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
        out = tmp_path / "out"
        sets = [f"data.root={smoke_dataset}", "data.limit_train=8", "data.limit_val=4",
                "model.width=0.25", "model.variant=/", "model.attitude=re_net_r",
                "optim.epochs=1", "optim.batch_size=4", "threads=1", "device=cpu",
                "precision=bf16"]  # fmt: skip
        args = ["train", "--quiet", "--out", str(out)]
        for item in sets:
            args += ["--set", item]
        assert main(args) == 0

        client = MlflowClient(f"sqlite:///{tmp_path / 'mlflow.db'}")
        (run,) = client.search_runs([client.get_experiment_by_name("train").experiment_id])
        assert run.info.status == "FINISHED"
        tags = run.data.tags
        assert (tags["precision"], tags["device"]) == ("bf16", "cpu")
        assert run.data.params["precision"] == "bf16"
        for key in ("standard/test/dphi_deg", "standard/test/swap/dphi_deg", "train_loss_total"):
            assert math.isfinite(run.data.metrics[key]), key

        weights = torch.load(out / "train" / "checkpoint.pt", weights_only=False)["model"]
        assert all(v.dtype != torch.bfloat16 for v in weights.values())  # fp32 master weights
        ckpt = str(out / "train" / "checkpoint.pt")
        ev = ["evaluate", "--quiet", "--checkpoint", ckpt, "--out", str(tmp_path / "ev"),
              "--device", "cpu", "--precision", "bf16"]  # fmt: skip
        assert main(ev) == 0
        ours = pd.read_csv(tmp_path / "ev" / "standard_test.csv")
        pipeline = pd.read_csv(out / "eval" / "standard__test.csv")
        pd.testing.assert_frame_equal(ours, pipeline)  # same precision, same machine: same bytes
        summary = json.loads((tmp_path / "ev" / "metrics.json").read_text())["standard/test"]
        assert summary["dphi_deg"] == pytest.approx(run.data.metrics["standard/test/dphi_deg"])
