"""Log a reproduction to a tracker: one experiment per table or figure, a parent run per
invocation in each, a nested run per (variant, sweep value, seed).

Each nested run carries the flattened train config as params, the per-epoch training history as
metrics (sent in batches), the evaluation summary of each split as ``<split>/<metric>``, the
predictions CSVs and the config as artifacts, and the tags of the trained model
(``benchmark.training.identity.run_tags``, the tags ``uavbench train`` sets: ``model_key`` = the
unit key, heads, head options and versions, encoder, seed, dataset) plus table, label, sweep value,
git commit and ``run_key`` (the job's key). :meth:`Logbook.finished` finds a job's finished run so a
second invocation neither retrains nor logs it again.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from benchmark.config import flatten
from benchmark.runner.execute import eval_keys
from benchmark.runner.plan import Unit, job_key
from benchmark.runner.specs import Job
from benchmark.tracking import RUN_KEY_TAG, Run, RunStatus, Tracker
from benchmark.training.identity import run_tags

SECONDS_METRIC = "unit_seconds"  # wall time of the unit's training + evaluation in its worker


def experiment_name(profile: str, table: str) -> str:
    return f"uavbench-{profile}/{table}"


def run_name(job: Job, seed: int) -> str:
    x = f" [{job.x}]" if job.x is not None else ""
    return f"{job.label}{x} seed {seed}"


class Logbook:
    def __init__(self, tracker: Tracker, profile: str, provenance: dict[str, str]) -> None:
        self.tracker = tracker
        self.profile = profile
        self.provenance = provenance  # git commit, dataset manifest hash, ...
        self.parents: dict[str, Run] = {}

    def parent(self, table: str) -> Run:
        """The invocation's parent run in the table's experiment (started on first use)."""
        if table not in self.parents:
            self.parents[table] = self.tracker.start_run(
                experiment_name(self.profile, table),
                f"reproduce {self.profile}",
                tags={"table": table, "profile": self.profile, **self.provenance},
            )
        return self.parents[table]

    def finished(self, job: Job, unit: Unit) -> tuple[dict[str, dict[str, float]], float] | None:
        """``(per eval-key metrics, unit seconds)`` of this job's FINISHED run in the store, or
        None. Eval keys are the job's splits and the unit's validation split (``Unit.job_splits``)
        with their ``/swap`` probes (``execute.eval_key``); a run that lacks any of them is not
        finished for this code.

        The seconds are the unit's training and evaluation time when it ran (0 for runs logged
        before this was recorded), so re-reporting keeps ``train_seconds``."""
        info = self.tracker.find_finished_run(
            experiment_name(self.profile, job.table), job_key(job, unit.key)
        )
        if info is None:
            return None
        wanted = set(eval_keys(unit.job_splits(job)))
        out: dict[str, dict[str, float]] = {}
        for key, value in info.metrics.items():
            split, sep, metric = key.rpartition("/")
            if sep and split in wanted:
                out.setdefault(split, {})[metric] = float(value)
        if set(out) != wanted:
            return None
        return out, float(info.metrics.get(SECONDS_METRIC, 0.0))

    def log_job(
        self,
        job: Job,
        unit: Unit,
        history: list[dict[str, float]],
        metrics: dict[str, dict[str, float]],
        artifacts: list[Path],
        error: str = "",
        seconds: float = 0.0,
    ) -> None:
        cfg = unit.cfg
        tags: dict[str, Any] = {
            # The trained model's tags, as ``uavbench train`` sets them (one identity for both).
            **run_tags(cfg, self.provenance.get("dataset_manifest", "")),
            "table": job.table,
            "label": job.label,
            "x": job.x if job.x is not None else "",
            "unit": unit.key,
            RUN_KEY_TAG: job_key(job, unit.key),
            **self.provenance,
        }
        if error:
            tags["error"] = error[:5000]
        run = self.tracker.start_run(
            experiment_name(self.profile, job.table),
            run_name(job, cfg.seed),
            parent=self.parent(job.table),
            tags=tags,
        )
        with run:
            params = {k: v for k, v in flatten(cfg).items() if k != "data.root"}
            run.log_params({**params, "table": job.table, "label": job.label, "x": job.x})
            for record in history:
                epoch = int(record.get("epoch", 0))
                values = {f"train/{k}": v for k, v in record.items() if k != "epoch" and _finite(v)}
                run.log_metrics(values, step=epoch)
            for key in eval_keys(unit.job_splits(job)):
                summary = metrics.get(key, {})
                run.log_metrics({f"{key}/{k}": v for k, v in summary.items() if _finite(v)})
            if _finite(seconds):
                run.log_metrics({SECONDS_METRIC: seconds})
            for path in artifacts:
                if path.exists():
                    run.log_artifact(path, "predictions" if path.suffix == ".csv" else None)
            if error:
                run.end(RunStatus.FAILED)

    def log_cost(self, table: str, label: str, info: dict[str, Any]) -> None:
        run = self.tracker.start_run(
            experiment_name(self.profile, table),
            f"{label} {info['input_size']}px w{info['width']:g}",
            parent=self.parent(table),
            tags={"table": table, "label": label, "head": info["head"], **self.provenance},
        )
        with run:
            run.log_params({k: v for k, v in info.items() if not isinstance(v, float)})
            run.log_metrics({k: v for k, v in info.items() if isinstance(v, float) and _finite(v)})

    def log_table_outputs(self, table: str, paths: list[Path]) -> None:
        parent = self.parent(table)
        for path in paths:
            if path.exists():
                parent.log_artifact(path)

    def close(self, status: RunStatus) -> None:
        for run in self.parents.values():
            run.end(status)
        self.parents.clear()


def _finite(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def write_config(unit: Unit, path: Path) -> Path:
    path.write_text(json.dumps(flatten(unit.cfg), indent=2, default=str))
    return path
