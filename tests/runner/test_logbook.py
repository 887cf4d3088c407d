"""What the reproduce logbook writes for a table row, a sweep row and a Table 6 measurement (local
tracker, no training): descriptions, headline metrics, real times, no empty tags or None params,
one parent per reproduction, cost rows logged once."""

from __future__ import annotations

import json
from pathlib import Path

from benchmark.runner.execute.worker import UnitResult
from benchmark.runner.plan.repro_profiles import PROFILES
from benchmark.runner.plan.specs import load_specs
from benchmark.runner.plan.units import plan_units
from benchmark.runner.report.logbook import HEADLINE, Logbook, experiment_name
from benchmark.tracking import RunStatus, create_tracker

SPLITS = [
    *("standard/train", "standard/val", "standard/test", "generalized/test"),
    *(f"height{h}/{s}" for h in (300, 400, 500, 600, 700) for s in ("train", "test")),
    *("frames/train", "frames/val", "frames/test", "towns/train", "towns/val", "towns/test"),
    "towns/london",
]
PROVENANCE = {"git_commit": "abc", "dataset_manifest": "f" * 64}


def unit_of(table: str, label: str, x: str | None = None):
    specs = load_specs(only=[table])
    units = plan_units(specs, PROFILES["smoke"], [0], Path("/d/ds"), SPLITS, "f" * 64)
    unit = next(u for u in units if any(j.label == label and j.x == x for j in u.jobs))
    return specs, unit, next(j for j in unit.jobs if j.label == label and j.x == x)


def result_for(unit, started_ms: int = 1_000_000, ended_ms: int = 1_090_000) -> UnitResult:
    summary = {m: float(i + 1) for i, m in enumerate(HEADLINE)} | {"n": 20.0, "acc10": 0.5}
    metrics = {key: dict(summary) for split in unit.eval_splits for key in (split, split + "/swap")}
    times = {"started_ms": started_ms, "ended_ms": ended_ms}
    return UnitResult(
        unit.key, True, metrics=metrics, seconds=90.0, run_id="u" * 32, model_uri="models:/m-1",
        **times,
    )  # fmt: skip


def records(root: Path) -> list[dict]:
    return [json.loads(p.read_text()) for p in root.rglob("run.json")]


def test_table_row(tmp_path):
    specs, unit, job = unit_of("table1", "Pd/Re-Net")
    tracker = create_tracker("local", workdir=tmp_path)
    logbook = Logbook(tracker, "smoke", PROVENANCE, specs=specs, data_root=Path("/d/ds"))
    logbook.log_job(job, unit, result_for(unit))
    logbook.close(RunStatus.FINISHED)
    (row,) = [r for r in records(tmp_path) if r["parent_run_id"]]
    assert row["start_time_ms"] == 1_000_000 and row["end_time_ms"] == 1_090_000
    tags, params = row["tags"], row["params"]
    assert "x" not in tags and "x" not in params
    assert all(v != "" for v in tags.values()) and "None" not in params.values()
    assert tags["training_run_id"] == "u" * 32 and tags["model_uri"] == "models:/m-1"
    note = tags["mlflow.note.content"]
    assert "paper Table 1" in note and "**Pd/Re-Net**" in note and "`standard/test`" in note
    assert "`standard/val`" in note and "pd_re_net" in note
    (inp,) = row["inputs"]
    assert inp == {"name": "ds", "digest": "f" * 64, "source": "/d/ds", "context": "standard/test"}
    metrics = tmp_path / "tracking-local" / "uavbench-smoke_table1" / row["run_id"] / "metrics.csv"
    keys = {line.split(",")[0] for line in metrics.read_text().splitlines()[1:]}
    assert {f"test_{m}" for m in HEADLINE} | {f"val_{m}" for m in HEADLINE} <= keys
    assert {"standard/test/dphi_deg", "standard/test/swap/dphi_deg", "unit_seconds"} <= keys
    exp = tracker.experiment_tags(experiment_name("smoke", "table1"))
    assert exp["mlflow.experimentKind"] == "custom_model_development"
    assert "Compared with paper Table 1" in exp["mlflow.note.content"]


def test_sweep_row_has_x_and_parent_is_reused(tmp_path):
    specs, unit, job = unit_of("fig7", "Pd/Re-Net", "10")
    for _ in range(2):  # two invocations
        tracker = create_tracker("local", workdir=tmp_path)
        logbook = Logbook(tracker, "smoke", PROVENANCE, specs=specs, data_root=Path("/d/ds"))
        if logbook.finished(job, unit) is None:
            logbook.log_job(job, unit, result_for(unit))
        logbook.log_table_outputs("fig7", [])
        logbook.close(RunStatus.FINISHED)
    runs = records(tmp_path)
    parents = [r for r in runs if not r["parent_run_id"]]
    rows = [r for r in runs if r["parent_run_id"]]
    assert len(parents) == 1 and len(rows) == 1 and parents[0]["status"] == "FINISHED"
    assert rows[0]["tags"]["x"] == "10" and rows[0]["params"]["x"] == "10"
    assert "= 10" in rows[0]["tags"]["mlflow.note.content"]


def test_cost_rows_are_logged_once(tmp_path):
    info = {"head": "re_net_r", "input_size": 224, "width": 1.0, "parameters": 5, "mflops": 2.5,
            "latency_ms": 3.0, "note": None}  # fmt: skip
    for _ in range(2):
        logbook = Logbook(create_tracker("local", workdir=tmp_path), "smoke", PROVENANCE,
                          specs=load_specs(only=["table6"]))  # fmt: skip
        logbook.log_cost("table6", "Re-Net", info)
        logbook.close(RunStatus.FINISHED)
    rows = [r for r in records(tmp_path) if r["parent_run_id"]]
    assert len(rows) == 1 and "note" not in rows[0]["params"]
    changed = dict(info, latency_ms=4.0)
    logbook = Logbook(create_tracker("local", workdir=tmp_path), "smoke", PROVENANCE)
    logbook.log_cost("table6", "Re-Net", changed)
    logbook.close(RunStatus.FINISHED)
    assert len([r for r in records(tmp_path) if r["parent_run_id"]]) == 2
