"""``uavbench reproduce`` with a shared encoder (quick's protocol, on the smoke dataset): the
encoder unit trains first, every row on it trains heads only on its cached features, a second
invocation trains nothing, and a failed encoder fails its rows without running them."""

from __future__ import annotations

import dataclasses
import os

import pytest
import torch

from benchmark.cli import main
from benchmark.runner.plan import repro_profiles as profiles_module
from benchmark.runner.plan.repro_profiles import SharedEncoder
from benchmark.training.config import OptimConfig

ONE_EPOCH = OptimConfig(name="adam", lr=1e-3, lr_schedule="constant", batch_size=8, epochs=1)


@pytest.fixture
def shared_smoke(monkeypatch):
    profile = dataclasses.replace(
        profiles_module.PROFILES["smoke"],
        encoder="matching",
        shared_encoder=SharedEncoder(optim=ONE_EPOCH),
    )
    monkeypatch.setitem(profiles_module.PROFILES, "smoke", profile)
    return profile


def _reproduce(tmp_path, dataset) -> int:
    previous = os.getcwd()
    os.chdir(tmp_path)
    try:
        return main([
            "reproduce", "--profile", "smoke", "--data", str(dataset), "--only", "table1",
            "--out", str(tmp_path / "reports"), "--workdir", str(tmp_path / "runs"),
            "--tracker", "null", "--quiet", "--workers", "1",
        ])  # fmt: skip
    finally:
        os.chdir(previous)


def _units(tmp_path) -> dict[str, dict]:
    units = {}
    for path in (tmp_path / "runs" / "units").glob("*/config.yaml"):
        import yaml

        units[path.parent.name] = yaml.safe_load(path.read_text())
    return units


@pytest.mark.slow
def test_encoder_first_then_heads_on_its_features(tmp_path, smoke_dataset, shared_smoke):
    assert _reproduce(tmp_path, smoke_dataset) == 0
    units = _units(tmp_path)
    encoders = [k for k, c in units.items() if not c["pretrained"]["checkpoint"]]
    assert len(encoders) == 1
    (enc,) = encoders
    heads = {k: c for k, c in units.items() if k != enc}
    assert len(heads) == 9  # table1's 8 heads and the UAV-only control
    for cfg in heads.values():
        assert cfg["pretrained"]["key"] == enc
        assert cfg["model"]["encoder"] == "matching"
    cache = tmp_path / "runs" / "units" / enc / "train" / "encodings"
    names = {p.stem for p in cache.glob("*/*.pt")}
    assert {"standard__train", "standard__test", "standard__test__swap", "standard__val",
            "standard__train__blank"} <= names  # fmt: skip
    # every head unit's checkpoint holds the encoder's weights unchanged
    ref = torch.load(tmp_path / "runs" / "units" / enc / "train" / "checkpoint.pt",
                     weights_only=False)["model"]  # fmt: skip
    for key in heads:
        state = torch.load(tmp_path / "runs" / "units" / key / "train" / "checkpoint.pt",
                           weights_only=False)["model"]  # fmt: skip
        for name, value in ref.items():
            if name.startswith("encoder."):
                assert torch.equal(state[name], value), (key, name)
    table = (tmp_path / "reports" / "table1.md").read_text()
    assert "| Pd/Re-Net |" in table and "not run" not in table
    # a second invocation finds every file: nothing is trained or encoded again
    stamps = {p: p.stat().st_mtime_ns for p in (tmp_path / "runs").rglob("*.pt")}
    assert _reproduce(tmp_path, smoke_dataset) == 0
    assert {p: p.stat().st_mtime_ns for p in stamps} == stamps


@pytest.mark.slow
def test_a_failed_encoder_fails_its_rows_without_running_them(
    tmp_path, smoke_dataset, shared_smoke, monkeypatch, capsys
):
    from benchmark.runner.execute import pool
    from benchmark.runner.execute.worker import UnitResult

    real = pool.run_unit

    def failing(task):
        if not task.cfg.pretrained.enabled:
            return UnitResult(task.key, False, error="RuntimeError: encoder training broke")
        return real(task)

    monkeypatch.setattr(pool, "run_unit", failing)
    assert _reproduce(tmp_path, smoke_dataset) == 1
    out = capsys.readouterr().out
    failed = [line for line in out.splitlines() if line.startswith("FAILED ")]
    assert len(failed) == 10  # the encoder, then its 9 rows, each named once as it ends
    assert sum("its shared encoder failed" in line for line in failed) == 9
    assert _units(tmp_path) == {}  # no row ran
