"""Device and precision are resolved where a unit computes, once, and its record tells the truth
(issue 41 item 4).

A unit's key names its precision and is computed on the driver; with a remote Ray cluster the
driver (say a CPU machine) is not where the units train (GPU workers), and ``"auto"`` would
resolve to fp32 there and bf16 here. So the plan resolves the precision into every unit's config,
a remote cluster needs it explicit, and each worker resolves its own device once, checks it can
run that precision, and writes the device/precision/accelerator tags itself. The fake GPU below
is torch's CUDA queries patched on this CPU machine: enough to make ``"auto"`` resolve as on a
bf16-capable GPU, without computing anything on it (training is replaced by a recorder).
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest
import torch

from benchmark.errors import InputError
from benchmark.models.device import Placement
from benchmark.runner import ReproduceConfig, reproduce
from benchmark.runner.execute.pool import ExecutorConfig
from benchmark.runner.execute.worker import UnitResult, UnitTask, run_unit, unit_placement
from benchmark.runner.plan.repro_profiles import PROFILES
from benchmark.runner.plan.specs import load_specs
from benchmark.runner.plan.units import plan_units
from benchmark.runner.report.logbook import Logbook
from benchmark.tracking import RunStatus, create_tracker
from benchmark.training import run_key
from tests.runner.test_logbook import PROVENANCE, SPLITS, records

REMOTE = "10.0.0.5:6379"


def planned_here():
    """table1's units planned by a driver on this (CPU) machine with the smoke profile, whose
    device and precision are both ``"auto"``."""
    assert (PROFILES["smoke"].device, PROFILES["smoke"].precision) == ("auto", "auto")
    return plan_units(load_specs(only=["table1"]), PROFILES["smoke"], [0], Path("/d/ds"),
                      SPLITS, PROVENANCE["dataset_manifest"])  # fmt: skip


def fake_gpu(monkeypatch) -> None:
    """From now on this process sees one bf16-capable CUDA device named "Fake GPU" (queries
    only): the worker's machine."""
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)
    monkeypatch.setattr(torch.cuda, "current_device", lambda: 0)
    monkeypatch.setattr(torch.cuda, "is_bf16_supported", lambda *a, **k: True)
    monkeypatch.setattr(torch.cuda, "get_device_name", lambda *a, **k: "Fake GPU")


def fake_done() -> SimpleNamespace:
    """What ``train_and_evaluate`` returns, with nothing trained or evaluated."""
    return SimpleNamespace(history=[], metrics={}, predictions={}, sequences={},
                           volume_sequences={}, joint_sequences={})  # fmt: skip


class TestPlanResolvesThePrecision:
    @pytest.mark.skipif(torch.cuda.is_available(), reason="the driver must be a CPU machine")
    def test_units_carry_the_drivers_precision_not_auto(self):
        for unit in planned_here():
            assert unit.cfg.precision == "fp32"
            # the key names that precision (fp32 keys are the keys from before devices)
            assert unit.key == run_key(unit.cfg, PROVENANCE["dataset_manifest"], "fp32")

    def test_explicit_precision_is_kept(self):
        profile = PROFILES["smoke"].__class__(**{**PROFILES["smoke"].__dict__, "precision": "bf16"})
        units = plan_units(load_specs(only=["table1"]), profile, [0], Path("/d/ds"), SPLITS,
                           PROVENANCE["dataset_manifest"])  # fmt: skip
        assert {u.cfg.precision for u in units} == {"bf16"}


class TestRemoteCluster:
    def test_auto_precision_is_refused(self, tmp_path):
        config = ReproduceConfig(
            profile="smoke", tracker="null", out=tmp_path / "r", workdir=tmp_path / "w",
            executor=ExecutorConfig(kind="ray", ray_address=REMOTE),
        )  # fmt: skip
        with pytest.raises(InputError, match=r"precision 'auto' with the remote Ray cluster"):
            reproduce(config)
        assert not (tmp_path / "r").exists() and not (tmp_path / "w").exists()

    def test_a_device_the_driver_lacks_is_checked_by_name_only(self):
        from benchmark.runner.reproduction import _with_device

        remote = ExecutorConfig(kind="ray", ray_address=REMOTE)
        profile = _with_device(PROFILES["smoke"], "cuda:1", "bf16", remote)
        assert (profile.device, profile.precision) == ("cuda:1", "bf16")
        with pytest.raises(InputError, match="device"):
            _with_device(PROFILES["smoke"], "tpu", "bf16", remote)
        if not torch.cuda.is_available():  # a local run needs the device here
            with pytest.raises(InputError, match="no CUDA device"):
                _with_device(PROFILES["smoke"], "cuda:1", "fp32", ExecutorConfig())


@pytest.mark.skipif(torch.cuda.is_available(), reason="the driver must be a CPU machine")
class TestFakeGpuWorkerCpuDriver:
    def test_worker_trains_in_the_precision_the_key_names(self, monkeypatch, tmp_path):
        unit = planned_here()[0]  # planned on the CPU driver
        fake_gpu(monkeypatch)  # trained on the GPU worker
        seen: list[Placement] = []

        def record(cfg, out_dir, eval_splits, **kwargs):
            seen.append(kwargs["placement"])
            return fake_done()

        monkeypatch.setattr("benchmark.runner.execute.worker.train_and_evaluate", record)
        result = run_unit(UnitTask(unit.key, unit.cfg, [], tmp_path / unit.key))
        assert result.ok, result.error
        (placement,) = seen  # resolved once, on the worker, and handed down
        assert placement == Placement(torch.device("cuda", 0), "fp32")
        assert run_key(unit.cfg, PROVENANCE["dataset_manifest"], placement.precision) == unit.key
        assert result.placement_tags == {
            "device": "cuda:0", "precision": "fp32", "accelerator": "Fake GPU",
        }  # fmt: skip

    def test_the_table_run_is_tagged_with_the_workers_placement(self, tmp_path):
        specs = load_specs(only=["table1"])
        unit = planned_here()[0]
        where = {"device": "cuda:0", "precision": "fp32", "accelerator": "Fake GPU"}
        logbook = Logbook(create_tracker("local", workdir=tmp_path), "smoke", PROVENANCE,
                          specs=specs, data_root=Path("/d/ds"))  # fmt: skip
        logbook.log_job(unit.jobs[0], unit, UnitResult(unit.key, True, placement_tags=where))
        logbook.close(RunStatus.FINISHED)
        (row,) = [r for r in records(tmp_path) if r["parent_run_id"]]
        assert {k: row["tags"][k] for k in where} == where
        assert row["tags"]["model_key"] == unit.key

    def test_auto_reaching_a_worker_is_an_error(self, monkeypatch):
        unit = planned_here()[0]
        fake_gpu(monkeypatch)
        cfg = unit.cfg.__class__(**{**unit.cfg.__dict__, "precision": "auto"})
        with pytest.raises(ValueError, match="resolved by the plan"):
            unit_placement(cfg)
