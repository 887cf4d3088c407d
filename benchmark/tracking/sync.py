"""``uavbench sync``: copy the runs of a local tracking directory into an MLflow store.

The source is a :class:`~benchmark.tracking.local.LocalTracker` directory (``./tracking-fallback``
where MLflow failed, or ``--tracker local``'s ``./tracking-local``). Every ENDED run (FINISHED,
FAILED, KILLED) is recreated in the store at ``target`` with everything it recorded: experiment
(created with the local experiment's tags if missing), run name, start and end time, status,
params, tags (``run_key`` included), every metric point with its step and timestamp (the full
history, not the latest value), dataset inputs, artifacts, and its parent (a child is copied
after its parent and nested under the parent's copy; a parent that lives in the store already,
as when a run was handed over to the fallback mid-reproduction, is used as it is).

Idempotent: each copy carries the tag ``synced_from_local_run`` = the local run id, and the
store is asked for it before copying, so a second sync copies nothing. The copy is created
RUNNING and set to its real status last, so a copy left RUNNING by an interrupted sync is known
to be partial: the next sync deletes it (MLflow's soft delete) and copies the run again. After a
copy the local run gets ``synced.json`` (see :mod:`benchmark.tracking.pending`): messages stop
counting it and trackers on that store no longer find it locally. The local files stay.

A run still RUNNING locally (a live process, or one killed and not resumed) is not copied, nor
are its children: rerun the command that made it (it resumes or closes it), then sync again.
A run the fallback took over mid-run left a partial husk on the server (its id is the local
tag ``mlflow_run_id``); once the complete copy is in, the husk is deleted (soft) and tagged
``superseded_by`` with the copy's id.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from benchmark.tracking.local import _safe_dirname
from benchmark.tracking.pending import LocalRun, count_runs, read_local_runs, show_path
from benchmark.tracking.records import DatasetRef
from benchmark.tracking.uri import (
    normalize_tracking_uri,
    open_sqlite_store_once,
    server_is_healthy,
    sqlite_path,
)

SYNC_TAG = "synced_from_local_run"  # on a copy: the id of the local run it was copied from
SUPERSEDED_TAG = "superseded_by"  # on a deleted husk: the id of the complete copy
_PARENT_TAG = "mlflow.parentRunId"
# MLflow's per-request limits of log_batch (mlflow.utils.validation).
_MAX_METRICS, _MAX_PARAMS_TAGS = 1000, 100
_TERMINAL = ("FINISHED", "FAILED", "KILLED")


class SyncError(RuntimeError):
    """A sync that cannot start (no runs, target unreachable): one line for the user."""


@dataclass
class SyncReport:
    """What a sync did. ``copied``/``skipped``: (local run, id in the store) pairs."""

    source: Path
    target: str
    copied: list[tuple[LocalRun, str]] = field(default_factory=list)
    skipped: list[tuple[LocalRun, str]] = field(default_factory=list)
    running: list[LocalRun] = field(default_factory=list)
    waiting: list[LocalRun] = field(default_factory=list)  # children of runs not copied
    replaced: int = 0  # partial copies of an interrupted sync, deleted and copied again
    metric_points: int = 0
    artifact_files: int = 0

    def text(self) -> str:
        """The summary ``uavbench sync`` prints last."""
        lines = [
            f"sync {show_path(self.source)} -> {self.target}: copied "
            f"{count_runs(len(self.copied))} ({self.metric_points} metric points, "
            f"{self.artifact_files} artifact files), skipped {len(self.skipped)} already there"
            + (f", replaced {self.replaced} partial copies" if self.replaced else "")
        ]
        if self.running or self.waiting:
            names = ", ".join(_label(r) for r in [*self.running, *self.waiting][:5])
            lines.append(
                f"not copied: {len(self.running)} still RUNNING and {len(self.waiting)} of their "
                f"children ({names}{', ...' if len(self.running) + len(self.waiting) > 5 else ''})"
                "; rerun the command that made them (it resumes or closes them), then sync again"
            )
        return "\n".join(lines)


def _label(run: LocalRun) -> str:
    return f"{run.experiment}/{run.record.get('run_name') or run.run_id}"


def open_target(target: str) -> tuple[str, Any]:
    """``(uri, MlflowClient)`` of the store ``target`` (a URI or a ``.db`` path); raises
    :class:`SyncError` if it cannot be reached or opened (``InputError`` for a bad value)."""
    uri = normalize_tracking_uri(target, "target")
    if uri is None:
        raise SyncError("target is empty: give the MLflow server URL or a sqlite store")
    return uri, _open_client(uri)


def _open_client(uri: str) -> Any:
    if uri.startswith(("http://", "https://")):
        ok, reason = server_is_healthy(uri, timeout=10.0)
        if not ok:
            raise SyncError(f"target {uri} is unreachable ({reason}); start the server, then rerun")
    from mlflow.tracking import MlflowClient

    def open_store() -> Any:
        client = MlflowClient(tracking_uri=uri)  # opens (creates, migrates) a database store
        client.search_experiments(max_results=1)
        return client

    try:
        return open_sqlite_store_once(uri, open_store)
    except Exception as err:
        raise SyncError(f"target {uri} cannot be opened: {err}") from None


def sync_runs(
    source: str | Path, target: str, *, say: Callable[[str], None] = lambda _m: None
) -> SyncReport:
    """Copy every ended run of the local directory ``source`` into the store ``target`` (see the
    module docstring); ``say`` gets one line per copied run. Raises :class:`SyncError` for a
    missing or empty ``source``, an unreachable target or a sync already running on ``source``.
    """
    from benchmark.locks import LockBusyError, work_lock

    # A bad value is refused before anything else. The messages name the arguments (source,
    # target), not the command's flags: this is the library.
    uri = normalize_tracking_uri(target, "target")
    if uri is None:
        raise SyncError("target is empty: give the MLflow server URL or a sqlite store")
    source = Path(source)
    if not source.is_dir():
        raise SyncError(f"source {source}: no such directory (nothing was kept locally there)")
    runs = read_local_runs(source)
    if not runs:
        raise SyncError(f"source {source}: no runs in it (expected <experiment>/<run id>/run.json)")
    client = _open_client(uri)
    try:
        with work_lock(source / ".sync.lock", what="uavbench sync"):
            return _Copier(source.resolve(), uri, client, say).run(runs)
    except LockBusyError as err:
        raise SyncError(str(err)) from None


class _Copier:
    def __init__(self, source: Path, uri: str, client: Any, say: Callable[[str], None]) -> None:
        self.source, self.uri, self.client, self.say = source, uri, client, say
        self.report = SyncReport(source, uri)
        self.exp_ids: dict[str, str] = {}
        db = sqlite_path(uri)
        # A sqlite store's artifacts go beside it (as create_tracker puts them); a server decides.
        self.artifact_root = db.resolve().parent / "mlartifacts" if db is not None else None

    def run(self, runs: list[LocalRun]) -> SyncReport:
        by_id = {r.run_id: r for r in runs}
        done: dict[str, str | None] = {}  # local id -> id in the store (None: not copied)
        for run in sorted(runs, key=lambda r: _depth(r, by_id)):  # stable: oldest first per level
            pid = run.parent_run_id
            if run.status not in _TERMINAL:
                self.report.running.append(run)
                done[run.run_id] = None
                continue
            if pid in by_id and done.get(pid) is None:
                self.report.waiting.append(run)
                done[run.run_id] = None
                continue
            parent = done[pid] if pid in by_id else self._existing_run(pid)
            done[run.run_id] = self._sync_one(run, parent)
        return self.report

    def _sync_one(self, run: LocalRun, parent: str | None) -> str:
        from mlflow.entities import ViewType

        exp_id = self._experiment(run)
        for copy in self.client.search_runs(
            [exp_id], f"tags.{SYNC_TAG} = '{run.run_id}'", ViewType.ACTIVE_ONLY, max_results=10
        ):
            if copy.info.status in _TERMINAL:
                self.report.skipped.append((run, copy.info.run_id))
                run.mark_synced(self.uri, copy.info.run_id)
                return copy.info.run_id
            self.client.delete_run(copy.info.run_id)  # partial: an interrupted sync
            self.report.replaced += 1
        return self._copy(run, exp_id, parent)

    def _copy(self, run: LocalRun, exp_id: str, parent: str | None) -> str:
        from mlflow.entities import Metric, Param

        rec = run.record
        tags = {k: str(v) for k, v in rec.get("tags", {}).items() if k != _PARENT_TAG and v != ""}
        tags[SYNC_TAG] = run.run_id
        if parent:
            tags[_PARENT_TAG] = parent
        elif run.parent_run_id:  # a parent neither here nor in the store: keep its id visible
            tags["local_parent_run_id"] = run.parent_run_id
        created = self.client.create_run(
            exp_id, start_time=rec.get("start_time_ms"), tags=tags, run_name=rec.get("run_name")
        )
        rid = created.info.run_id
        params = [Param(str(k), str(v)) for k, v in rec.get("params", {}).items()]
        for i in range(0, len(params), _MAX_PARAMS_TAGS):
            self.client.log_batch(rid, params=params[i : i + _MAX_PARAMS_TAGS])
        metrics = [Metric(*row) for row in read_metrics(run.run_dir / "metrics.csv")]
        for i in range(0, len(metrics), _MAX_METRICS):
            self.client.log_batch(rid, metrics=metrics[i : i + _MAX_METRICS])
        inputs = [DatasetRef(**d) for d in rec.get("inputs", [])]
        if inputs:
            from benchmark.tracking.mlflow_lineage import dataset_inputs

            self.client.log_inputs(rid, dataset_inputs(inputs))
        art = run.run_dir / "artifacts"
        files = sum(1 for p in art.rglob("*") if p.is_file()) if art.is_dir() else 0
        if files:
            self.client.log_artifacts(rid, str(art))
        self.client.set_terminated(rid, run.status, rec.get("end_time_ms"))
        run.mark_synced(self.uri, rid)
        self._retire_husk(run, rid)
        self.report.copied.append((run, rid))
        self.report.metric_points += len(metrics)
        self.report.artifact_files += files
        self.say(
            f"copied {_label(run)} [{run.status}] (local {run.run_id[:8]} -> {rid[:8]}): "
            f"{len(params)} params, {len(metrics)} metric points, {files} artifact files"
        )
        return rid

    def _retire_husk(self, run: LocalRun, copy_id: str) -> None:
        """Delete (soft) the partial run the store kept of a run handed over to the fallback."""
        husk = self._existing_run(run.record.get("tags", {}).get("mlflow_run_id"))
        if husk is None or husk == copy_id:
            return
        info = self.client.get_run(husk)
        if info.info.run_name != run.record.get("run_name"):
            return  # an id from another store that happens to exist here: not ours to touch
        if info.info.status == "RUNNING":
            self.client.set_terminated(husk, "KILLED")
        self.client.set_tag(husk, SUPERSEDED_TAG, copy_id)
        self.client.delete_run(husk)

    def _existing_run(self, run_id: str | None) -> str | None:
        if not run_id:
            return None
        try:
            found = self.client.get_run(run_id)
        except Exception:  # not in this store
            return None
        return found.info.run_id if found.info.lifecycle_stage == "active" else None

    def _experiment(self, run: LocalRun) -> str:
        name = run.experiment
        if name in self.exp_ids:
            return self.exp_ids[name]
        exp = self.client.get_experiment_by_name(name)
        local_tags = _experiment_tags(run.run_dir.parent)
        if exp is None:
            location = None
            if self.artifact_root is not None:
                location = (self.artifact_root / _safe_dirname(name)).as_uri()
            exp_id = self.client.create_experiment(name, artifact_location=location)
            have: dict[str, str] = {}
        else:
            exp_id, have = exp.experiment_id, dict(exp.tags)
        for key, value in local_tags.items():  # the store's own tags win
            if key not in have and value != "":
                self.client.set_experiment_tag(exp_id, key, value)
        self.exp_ids[name] = exp_id
        return exp_id


def _experiment_tags(exp_dir: Path) -> dict[str, str]:
    path = exp_dir / "experiment.json"
    try:
        return {str(k): str(v) for k, v in json.loads(path.read_text())["tags"].items()}
    except (OSError, ValueError, KeyError, AttributeError):
        return {}


def read_metrics(path: Path) -> list[tuple[str, float, int, int]]:
    """``(key, value, timestamp_ms, step)`` of every row of a local ``metrics.csv``, in the order
    logged (MLflow's ``Metric`` argument order). Values were written with ``repr``, so they read
    back bit-identical (``nan``/``inf`` included); a row cut short by a kill is skipped."""
    rows = []
    with open(path, newline="", encoding="utf-8") as fh:
        for row in csv.DictReader(fh):
            try:
                rows.append(
                    (row["key"], float(row["value"]), int(row["timestamp_ms"]), int(row["step"]))
                )
            except (TypeError, ValueError, KeyError):
                continue
    return rows


def _depth(run: LocalRun, by_id: dict[str, LocalRun]) -> int:
    """Nesting depth within the local directory (parents sort before their children)."""
    depth, seen, pid = 0, {run.run_id}, run.parent_run_id
    while pid in by_id and pid not in seen:
        seen.add(pid)
        depth += 1
        pid = by_id[pid].parent_run_id
    return depth
