"""Log a reproduction to a tracker.

Two kinds of runs, so the heavy data is stored once:

- **training runs** (experiment ``uavbench-<profile>/training``): one per unit (trained model),
  opened by the worker when its training starts and closed when its evaluation ends
  (``benchmark.runner.execute.live``): per-epoch curves, system metrics, the dataset input, every
  split's numbers, the predictions and the logged model;
- **table rows** (experiment ``uavbench-<profile>/<table>``, one per table or figure): one parent
  run per reproduction (reused by the next invocation: tagged ``run_key = reproduce-<hash of
  profile, dataset, table>``) and under it one run per (row, sweep value, seed), with the real
  start and end of its unit's training, the flattened train config as params, the headline
  metrics (``test_*`` on the row's first test split, ``val_*`` on the validation split) beside
  every split's numbers (``<split>/<metric>``), the dataset input of the test split, the model's
  tags (``benchmark.training.identity.model_tags``, as ``uavbench train`` sets them, and the
  ``device``/``precision``/``accelerator`` its worker resolved) and
  ``training_run_id`` / ``model_uri`` pointing at the training run.

Every experiment is tagged ``mlflow.experimentKind = custom_model_development`` and described
(``benchmark.runner.report.descriptions``); every run has a description. :meth:`Logbook.finished`
finds a row's finished run, so a second invocation neither retrains nor logs it again; Table 6 rows
are keyed by a hash of their content and logged once.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from benchmark.config import flatten
from benchmark.runner.execute.live import UnitTracking
from benchmark.runner.execute.worker import UnitResult, eval_keys
from benchmark.runner.plan.invocations import OWNER_TAGS, owner_lives
from benchmark.runner.plan.specs import Job, TableSpec
from benchmark.runner.plan.units import Unit, job_key
from benchmark.runner.report import descriptions
from benchmark.tracking import RUN_KEY_TAG, DatasetRef, Run, RunInfo, RunStatus, Tracker
from benchmark.training.identity import model_tags

END_REASON_TAG = "uavbench.end_reason"  # why a run was ended by another invocation
SECONDS_METRIC = "unit_seconds"  # wall time of the unit's training + evaluation in its worker
# The headline metrics of a row, prefixed test_ / val_ (the paper's columns).
HEADLINE = ("dphi_deg", "dpsi_deg", "dtheta_deg", "dgamma_deg", "dE_m", "dN_m", "dU_m")


def experiment_name(profile: str, table: str) -> str:
    return f"uavbench-{profile}/{table}"


def run_name(job: Job, seed: int) -> str:
    x = f" [{job.x}]" if job.x is not None else ""
    return f"{job.label}{x} seed {seed}"


def headline_metrics(metrics: dict[str, dict[str, float]], test: str, val: str | None) -> dict:
    """``test_dphi_deg``... from split ``test``'s summary, ``val_...`` from ``val``'s."""
    out: dict[str, float] = {}
    for prefix, split in (("test", test), ("val", val)):
        summary = metrics.get(split or "", {})
        out.update({f"{prefix}_{m}": summary[m] for m in HEADLINE if _finite(summary.get(m))})
    return out


class Logbook:
    def __init__(
        self,
        tracker: Tracker,
        profile: str,
        provenance: dict[str, str],
        *,
        specs: Iterable[TableSpec] = (),
        data_root: Path | None = None,
        owner: dict[str, str] | None = None,
    ) -> None:
        """``owner``: the invocation's ``invocations.owner_tags`` (pid, host, work directory),
        set on its parent and training runs so a later invocation tells a dead owner from a live
        one."""
        self.tracker = tracker
        self.owner = dict(owner or {})
        self.profile = profile
        self.provenance = {k: v for k, v in provenance.items() if v}  # git commit, dataset hash
        self.specs = {spec.name: spec for spec in specs}
        self.data_root = Path(data_root).resolve() if data_root is not None else None
        self.parents: dict[str, Run] = {}
        self._described: set[str] = set()
        self.started_ms = int(time.time() * 1000)  # a new parent run starts with the invocation

    # ------------------------------------------------------------------ experiments
    def _describe(self, table: str) -> None:
        if table in self._described:
            return
        self._described.add(table)
        if table == descriptions.UNITS_TABLE:
            text = descriptions.units_experiment(self.profile)
        elif table in self.specs:
            text = descriptions.table_experiment(self.specs[table], self.profile)
        else:
            text = f"Table `{table}` of the `{self.profile}` reproduction."
        self.tracker.describe_experiment(
            experiment_name(self.profile, table), text, {"profile": self.profile}
        )

    def _dataset(self, context: str) -> DatasetRef | None:
        digest = self.provenance.get("dataset_manifest", "")
        if self.data_root is None or not digest:
            return None
        return DatasetRef(self.data_root.name, digest, str(self.data_root), context)

    def parent(self, table: str) -> Run:
        """This reproduction's parent run in the table's experiment: the one an earlier
        invocation of the same profile, dataset and table made (reopened), or a new one."""
        if table not in self.parents:
            self._describe(table)
            experiment = experiment_name(self.profile, table)
            text = json.dumps([self.profile, self.provenance.get("dataset_manifest", ""), table])
            # the parent's key (the tag RUN_KEY_TAG, as the units' runs are found by theirs)
            parent_key = "reproduce-" + hashlib.sha256(text.encode()).hexdigest()[:16]
            # Reuse a parent that an earlier invocation ended (FINISHED or FAILED); a KILLED one
            # records an interrupted invocation and keeps its state, a RUNNING one belongs to a
            # live invocation (see close_stale): this invocation then starts its own.
            ended = (RunStatus.FINISHED.value, RunStatus.FAILED.value)
            found = [r for r in self.tracker.find_runs(experiment, parent_key) if r.status in ended]
            if found:
                run = self.tracker.attach(found[0], reopen=True)
                run.set_tags({**self.provenance, **self.owner})  # the latest invocation's
            else:
                run = self.tracker.start_run(
                    experiment,
                    f"reproduce {self.profile}",
                    tags={
                        "table": table,
                        "profile": self.profile,
                        RUN_KEY_TAG: parent_key,
                        **self.provenance,
                        **self.owner,
                    },
                    description=self._parent_text(table),
                    start_time_ms=self.started_ms,
                )
            self.parents[table] = run
        return self.parents[table]

    def _parent_text(self, table: str) -> str:
        spec = self.specs.get(table)
        what = f"**{spec.title}** ({descriptions.paper_reference(spec)})" if spec else table
        refs = ""
        if spec is not None and spec.references:
            refs = " (its non-learned rows, the constant predictor and the references, are in the "
            refs += "table file only)"
        return f"The `{self.profile}` reproduction of {what}: its rows are the nested runs{refs}."

    # ------------------------------------------------------------------ training runs
    def unit_tracking(self, unit: Unit, *, log_model: bool = True) -> UnitTracking:
        """How the worker training ``unit`` logs its training run
        (``benchmark.runner.execute.live``); ``log_model=False`` logs no model (``--no-models``)."""
        self._describe(descriptions.UNITS_TABLE)
        readers = [
            f"{job.table} ({job.label}{f' [{job.x}]' if job.x is not None else ''})"
            for job in unit.jobs
        ]
        tags = {
            # the model's tags; where it computes (device, precision, accelerator) is tagged by
            # the worker that trains it (benchmark.runner.execute.live.track_unit)
            **model_tags(unit.cfg, self.provenance.get("dataset_manifest", "")),
            "tables": ",".join(dict.fromkeys(job.table for job in unit.jobs)),
            "unit": unit.key,
            **self.provenance,
            **self.owner,
        }
        return UnitTracking(
            spec=self.tracker.spec(),
            experiment=experiment_name(self.profile, descriptions.UNITS_TABLE),
            run_name=(
                f"{unit.jobs[0].label} seed {unit.cfg.seed} ({unit.key[:8]})"
                if unit.jobs
                else f"{unit.title} ({unit.key[:8]})"
            ),  # a shared encoder: no table reads it
            unit_key=unit.key,
            tags={k: v for k, v in tags.items() if v},
            description=descriptions.unit_run(unit, readers),
            dataset=self._dataset(unit.cfg.data.train_split),
            log_model=log_model,
        )

    def kill_unfinished_units(self, keys: Iterable[str]) -> int:
        """Mark KILLED the training runs of ``keys`` still RUNNING (their workers were stopped
        by Ctrl-C); returns how many."""
        experiment = experiment_name(self.profile, descriptions.UNITS_TABLE)
        wanted = set(keys)
        killed = 0
        for info in self.tracker.find_runs(experiment, None, (RunStatus.RUNNING.value,)):
            if info.tags.get(RUN_KEY_TAG) in wanted:
                self.tracker.attach(info, reopen=False).end(RunStatus.KILLED)
                killed += 1
        return killed

    def close_stale(self, tables: Iterable[str]) -> list[RunInfo]:
        """End KILLED every RUNNING parent run of ``tables`` and training run of this profile
        whose owning invocation is gone (killed: ``kill -9``, power loss), tagging the reason;
        runs of a live invocation (another work directory on the same store) are left alone.
        A run without owner tags (logged before they existed) counts as gone. Returns the runs
        ended."""
        closed = []
        for table in dict.fromkeys([*tables, descriptions.UNITS_TABLE]):
            experiment = experiment_name(self.profile, table)
            for info in self.tracker.find_runs(experiment, None, (RunStatus.RUNNING.value,)):
                if owner_lives(info.tags):
                    continue
                owner = info.tags.get(OWNER_TAGS[0], "?"), info.tags.get(OWNER_TAGS[1], "?")
                run = self.tracker.attach(info, reopen=False)
                run.set_tags(
                    {
                        END_REASON_TAG: f"its invocation (pid {owner[0]} on {owner[1]}) ended "
                        "without closing it (killed); closed by a later invocation"
                    }
                )
                run.end(RunStatus.KILLED)
                closed.append(info)
        return closed

    # ------------------------------------------------------------------ table rows
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

    def log_job(self, job: Job, unit: Unit, result: UnitResult) -> None:
        """The table row ``job`` of ``unit``, from its worker's ``result`` (see module doc)."""
        cfg = unit.cfg
        tags: dict[str, Any] = {
            # The trained model's tags, as ``uavbench train`` sets them (one identity for both),
            # and where its worker computed, as that worker resolved it (none if it never ran).
            **model_tags(cfg, self.provenance.get("dataset_manifest", "")),
            **result.placement_tags,
            "table": job.table,
            "label": job.label,
            "unit": unit.key,
            RUN_KEY_TAG: job_key(job, unit.key),
            "training_run_id": result.run_id,
            "model_uri": result.model_uri,
            "error": result.error[:5000],
            **self.provenance,
        }
        if job.x is not None:
            tags["x"] = job.x
        text = descriptions.job_run(
            self.specs.get(job.table), job, unit, result.run_id, self.profile
        )
        run = self.tracker.start_run(
            experiment_name(self.profile, job.table),
            run_name(job, cfg.seed),
            parent=self.parent(job.table),
            tags={k: v for k, v in tags.items() if v != ""},
            description=text,
            start_time_ms=result.started_ms,
        )
        status = RunStatus.FINISHED if result.ok else RunStatus.FAILED
        try:
            params = {k: v for k, v in flatten(cfg, drop_none=True).items() if k != "data.root"}
            extra = {"table": job.table, "label": job.label}
            if job.x is not None:
                extra["x"] = job.x
            run.log_params({**params, **extra})
            dataset = self._dataset(job.eval_splits[0])
            if dataset is not None:
                run.log_input(dataset)
            run.log_metrics(headline_metrics(result.metrics, job.eval_splits[0], unit.val_split))
            for key in eval_keys(unit.job_splits(job)):
                summary = result.metrics.get(key, {})
                run.log_metrics({f"{key}/{k}": v for k, v in summary.items() if _finite(v)})
            if _finite(result.seconds):
                run.log_metrics({SECONDS_METRIC: result.seconds})
        except BaseException:
            run.end(RunStatus.FAILED)
            raise
        run.end(status, end_time_ms=result.ended_ms)

    def log_cost(self, table: str, label: str, info: dict[str, Any]) -> None:
        """One Table 6 measurement; skipped if the same content is already logged FINISHED."""
        experiment = experiment_name(self.profile, table)
        text = json.dumps([label, info], sort_keys=True, default=str)
        key = "cost-" + hashlib.sha256(text.encode()).hexdigest()[:16]
        if self.tracker.find_finished_run(experiment, key) is not None:
            return
        name = f"{label} {info['input_size']}px w{info['width']:g}"
        run = self.tracker.start_run(
            experiment,
            name,
            parent=self.parent(table),
            tags={
                "table": table,
                "label": label,
                "head": info["head"],
                RUN_KEY_TAG: key,
                **self.provenance,
            },
            description=f"Cost of **{label}** at {info['input_size']} px, encoder width "
            f"{info['width']:g}: parameters, size, MFLOPs, CPU latency per pair.",
        )
        with run:
            params = {k: v for k, v in info.items() if not isinstance(v, float) and v is not None}
            run.log_params(params)
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
