"""Trackers that need no server: :class:`NullTracker` (tests) and :class:`LocalTracker` (files).

:class:`LocalTracker` is the fallback when MLflow is unreachable, so its format is plain and
complete: one directory per run::

    <root>/<experiment>/experiment.json        the experiment's tags (kind, description)
    <root>/<experiment>/<run_id>/run.json      name, parent, status, times, params, tags, inputs
    <root>/<experiment>/<run_id>/metrics.csv   key,value,step,timestamp_ms (appended per batch)
    <root>/<experiment>/<run_id>/artifacts/    copies of logged files and directories

``run.json`` is rewritten atomically (temp file + rename) after every change, so a killed process
leaves a readable record of everything logged up to then.
"""

from __future__ import annotations

import csv
import io
import json
import os
import re
import shutil
import tempfile
import uuid
from collections.abc import Mapping
from pathlib import Path

from benchmark.tracking.base import (
    RUN_KEY_TAG,
    DatasetRef,
    MetricPoint,
    Run,
    RunInfo,
    RunStatus,
    Tracker,
    TrackerSpec,
)


class NullTracker(Tracker):
    """Logs nothing anywhere; runs still keep their in-memory record (``run.params`` etc.).

    ``find_finished_run`` never finds anything, so everything runs. For tests and ``--no-track``.
    """

    uri = "null"

    def find_runs(
        self, experiment: str, run_key: str | None = None, statuses: tuple[str, ...] = ()
    ) -> list[RunInfo]:
        return []

    def summary(self) -> str:
        return "tracking: off (nothing was logged)"

    def _create_run(self, run: Run) -> str:
        return uuid.uuid4().hex

    def _log_batch(self, run, metrics, params, tags) -> None:
        pass

    def _log_artifact(self, run: Run, path: Path, artifact_path: str | None) -> None:
        pass

    def _end_run(self, run: Run, status: RunStatus) -> None:
        pass


def _safe_dirname(name: str) -> str:
    """Experiment names may hold ``/`` or spaces; the directory name must not."""
    cleaned = re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._") or "experiment"
    return cleaned


def _write_json_atomic(path: Path, data: Mapping) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".run.", suffix=".json")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            json.dump(data, fh, indent=2, sort_keys=True)
            fh.write("\n")
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


class LocalTracker(Tracker):
    """Writes every run under ``root`` (see the module docstring for the layout)."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root).resolve()
        self.uri = str(self.root)

    def spec(self) -> TrackerSpec:
        return TrackerSpec("local", str(self.root))

    def summary(self) -> str:
        n = sum(1 for _ in self.root.glob("*/*/run.json")) if self.root.is_dir() else 0
        return f"tracking: {n} run(s) as files under {self.root} (run.json, metrics.csv per run)"

    def _run_dir(self, run: Run) -> Path:
        return self.root / _safe_dirname(run.experiment) / run.run_id

    def _record(self, run: Run) -> dict:
        return {
            "run_id": run.run_id,
            "experiment": run.experiment,
            "run_name": run.run_name,
            "parent_run_id": (
                run.parent.run_id if run.parent is not None else getattr(run, "_local_parent", None)
            ),
            "status": run.status.value,
            "start_time_ms": run.start_time_ms,
            "end_time_ms": run.end_time_ms,
            "params": dict(run.params),
            "tags": dict(run.tags),
            "inputs": [vars(d) for d in run.inputs],
        }

    def _save(self, run: Run) -> None:
        _write_json_atomic(self._run_dir(run) / "run.json", self._record(run))

    def _create_run(self, run: Run) -> str:
        run.run_id = uuid.uuid4().hex
        run_dir = self._run_dir(run)
        run_dir.mkdir(parents=True, exist_ok=False)
        with open(run_dir / "metrics.csv", "w", newline="", encoding="utf-8") as fh:
            csv.writer(fh).writerow(["key", "value", "step", "timestamp_ms"])
        self._save(run)
        return run.run_id

    def _log_batch(
        self,
        run: Run,
        metrics: list[MetricPoint],
        params: Mapping[str, str],
        tags: Mapping[str, str],
    ) -> None:
        if metrics:
            with open(self._run_dir(run) / "metrics.csv", "a", newline="", encoding="utf-8") as fh:
                writer = csv.writer(fh)
                for m in metrics:
                    writer.writerow([m.key, repr(m.value), m.step, m.timestamp_ms])
        if params or tags:
            self._save(run)  # run.params / run.tags already hold the new values

    def _log_artifact(self, run: Run, path: Path, artifact_path: str | None) -> None:
        dest = self._run_dir(run) / "artifacts"
        if artifact_path:
            dest = dest / artifact_path
        dest.mkdir(parents=True, exist_ok=True)
        if path.is_dir():
            shutil.copytree(path, dest / path.name, dirs_exist_ok=True)
        else:
            shutil.copy2(path, dest / path.name)

    def _end_run(self, run: Run, status: RunStatus) -> None:
        self._save(run)

    def attach(self, info: RunInfo, *, reopen: bool = True) -> Run:
        run_dir = self.root / _safe_dirname(info.experiment) / info.run_id
        with open(run_dir / "run.json", encoding="utf-8") as fh:
            rec = json.load(fh)
        run = super().attach(info, reopen=False)
        run._local_parent = rec.get("parent_run_id")
        run.inputs.extend(DatasetRef(**d) for d in rec.get("inputs", []))
        run.end_time_ms = rec.get("end_time_ms")
        if reopen:
            self._reopen_run(run)
        return run

    def _reopen_run(self, run: Run) -> None:
        run.status = RunStatus.RUNNING
        self._save(run)

    def _set_experiment_tags(self, experiment: str, tags: Mapping[str, str]) -> None:
        exp_dir = self.root / _safe_dirname(experiment)
        exp_dir.mkdir(parents=True, exist_ok=True)
        path = exp_dir / "experiment.json"
        old = json.loads(path.read_text(encoding="utf-8")) if path.is_file() else {}
        _write_json_atomic(path, {"name": experiment, "tags": {**old.get("tags", {}), **tags}})

    def experiment_tags(self, experiment: str) -> dict[str, str]:
        path = self.root / _safe_dirname(experiment) / "experiment.json"
        return json.loads(path.read_text(encoding="utf-8"))["tags"] if path.is_file() else {}

    def _log_inputs(self, run: Run, datasets: list[DatasetRef]) -> None:
        self._save(run)  # run.inputs already holds them

    def _log_model(self, run: Run, model: object, input_example: object, name: str) -> str:
        """The MLflow pytorch flavor's directory under ``artifacts/<name>`` (no server needed):
        ``mlflow.pytorch.load_model(<that directory>)`` loads it."""
        from benchmark.tracking.models import save_pytorch_model

        dest = self._run_dir(run) / "artifacts" / name
        save_pytorch_model(model, input_example, dest)
        return dest.as_uri()

    # ------------------------------------------------------------------ reading
    def list_runs(self, experiment: str) -> list[RunInfo]:
        """Every run of ``experiment`` stored here, oldest first."""
        exp_dir = self.root / _safe_dirname(experiment)
        records = []
        for path in exp_dir.glob("*/run.json"):
            with open(path, encoding="utf-8") as fh:
                rec = json.load(fh)
            if rec.get("experiment") == experiment:
                records.append((rec, path.parent))
        records.sort(key=lambda r: (r[0].get("start_time_ms") or 0, r[0]["run_id"]))
        return [self._info(rec, run_dir) for rec, run_dir in records]

    def _info(self, rec: Mapping, run_dir: Path) -> RunInfo:
        latest: dict[str, float] = {}
        text = (run_dir / "metrics.csv").read_text(encoding="utf-8")
        # Another process may be appending to this run's file right now (two workers, one store):
        # a last line without its newline is still being written, and is not read.
        complete = text[: text.rfind("\n") + 1]
        for row in csv.DictReader(io.StringIO(complete, newline="")):
            latest[row["key"]] = float(row["value"])
        return RunInfo(
            run_id=rec["run_id"],
            experiment=rec["experiment"],
            run_name=rec["run_name"],
            status=rec["status"],
            tags=dict(rec["tags"]),
            params=dict(rec["params"]),
            metrics=latest,
            artifact_uri=(run_dir / "artifacts").as_uri(),
            backend="local",
            start_time_ms=rec.get("start_time_ms"),
            end_time_ms=rec.get("end_time_ms"),
        )

    def find_runs(
        self, experiment: str, run_key: str | None = None, statuses: tuple[str, ...] = ()
    ) -> list[RunInfo]:
        found = [
            info
            for info in self.list_runs(experiment)
            if (run_key is None or info.tags.get(RUN_KEY_TAG) == run_key)
            and (not statuses or info.status in statuses)
        ]
        return found[::-1]
