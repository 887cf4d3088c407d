"""The tracker interface: experiments, (nested) runs, params, batched metrics, artifacts, tags.

A :class:`Tracker` is a small backend with a few primitives (create a run, log a batch, log an
artifact, end a run, search runs; plus experiment tags, dataset inputs, a logged model and system
metrics, which a backend may ignore). Everything a caller touches is a :class:`Run` handle,
written once here for every backend: it buffers metrics and sends them in batches, keeps a record of
everything logged (so a backend that fails mid-run can hand the whole run over to a local fallback
without losing anything), and, used as a context manager, ends the run FINISHED on success, FAILED
on an exception (the exception is the run's ``failure_reason`` tag and is added to its note) and
KILLED on ``KeyboardInterrupt``. :meth:`Run.fail` fails a run with a reason explicitly.

The runner never imports mlflow: it gets a tracker from :func:`benchmark.tracking.create_tracker`
and talks to this interface only.
"""

from __future__ import annotations

import abc
import contextlib
import time
from collections.abc import Mapping
from contextlib import AbstractContextManager
from pathlib import Path
from types import TracebackType

from benchmark.tracking.records import (  # noqa: F401 - re-exported: base is the interface
    DESCRIPTION_TAG,
    EXPERIMENT_KIND,
    EXPERIMENT_KIND_TAG,
    FAILURE_REASON_TAG,
    MAX_TAG_VALUE,
    RUN_KEY_TAG,
    DatasetRef,
    MetricPoint,
    RunInfo,
    RunStatus,
    TrackerSpec,
    cut_text,
    failed_note,
)


def _as_str(value: object) -> str:
    """Params and tags are strings in every backend; ``None`` becomes ``"None"`` like MLflow."""
    return value if isinstance(value, str) else str(value)


def _now_ms() -> int:
    return int(time.time() * 1000)


class Run:
    """A live run. Create it with :meth:`Tracker.start_run`, never directly.

    Metrics are buffered and sent every ``batch_size`` points (or on :meth:`flush` / :meth:`end`),
    so per-epoch logging costs one request per batch, not one per number.
    """

    def __init__(
        self,
        tracker: Tracker,
        run_id: str,
        experiment: str,
        run_name: str,
        parent: Run | None,
        tags: Mapping[str, str],
        batch_size: int = 200,
        start_time_ms: int | None = None,
    ) -> None:
        self.tracker = tracker
        self.run_id = run_id
        self.experiment = experiment
        self.run_name = run_name
        self.parent = parent
        self.status = RunStatus.RUNNING
        self.end_time_ms: int | None = None
        self.batch_size = int(batch_size)
        # The full record, kept for a hand-over to the local fallback (see MlflowTracker).
        self.tags: dict[str, str] = dict(tags)
        self.params: dict[str, str] = {}
        self.metrics: list[MetricPoint] = []
        self.artifacts: list[tuple[Path, str | None]] = []
        self.inputs: list[DatasetRef] = []
        self.start_time_ms = start_time_ms if start_time_ms is not None else _now_ms()
        self._unsent = 0  # metrics[-_unsent:] are buffered, not yet sent

    # ------------------------------------------------------------------ logging
    def log_params(self, params: Mapping[str, object]) -> None:
        """Log params (e.g. a flattened config); values are stored as strings.

        Logging the same key twice with a different value raises (as in MLflow): a run has one
        config.
        """
        new = {str(k): _as_str(v) for k, v in params.items()}
        for key, value in new.items():
            if key in self.params and self.params[key] != value:
                raise ValueError(
                    f"param {key!r} already logged as {self.params[key]!r}, cannot change it "
                    f"to {value!r} in run {self.run_name!r}"
                )
        new = {k: v for k, v in new.items() if k not in self.params}
        if new:
            self.params.update(new)
            self.tracker._log_batch(self, [], new, {})

    def set_tags(self, tags: Mapping[str, object]) -> None:
        """Set tags; an empty value is refused (MLflow shows it as a bare, meaningless tag)."""
        new = {str(k): _as_str(v) for k, v in tags.items()}
        _check_tags(new, self.run_name)
        self.tags.update(new)
        self.tracker._log_batch(self, [], {}, new)

    def log_metrics(self, metrics: Mapping[str, float], step: int = 0) -> None:
        """Buffer one value per key at ``step`` (e.g. the epoch). Non-numbers raise ``TypeError``.

        NaN and inf are kept (MLflow stores them); a caller that wants to stop on them checks first.
        """
        now = _now_ms()
        for key, value in metrics.items():
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                try:
                    value = float(value)  # numpy / 0-d torch scalars
                except (TypeError, ValueError):
                    raise TypeError(
                        f"metric {key!r} must be a number, got {type(value).__name__}: {value!r}"
                    ) from None
            self.metrics.append(MetricPoint(str(key), float(value), int(step), now))
            self._unsent += 1
        if self._unsent >= self.batch_size:
            self.flush()

    def flush(self) -> None:
        if self._unsent:
            batch = self.metrics[-self._unsent :]
            self._unsent = 0
            self.tracker._log_batch(self, batch, {}, {})

    def log_artifact(self, path: str | Path, artifact_path: str | None = None) -> None:
        """Log a file or a whole directory (recursively) under ``artifact_path``."""
        path = Path(path)
        if not path.exists():
            raise FileNotFoundError(f"artifact {path} does not exist (run {self.run_name!r})")
        self.artifacts.append((path, artifact_path))
        self.tracker._log_artifact(self, path, artifact_path)

    def log_input(self, dataset: DatasetRef) -> None:
        """Record that this run read ``dataset`` (MLflow: ``log_inputs``; shown as Datasets)."""
        self.inputs.append(dataset)
        self.tracker._log_inputs(self, [dataset])

    def log_model(self, model: object, input_example: object, name: str = "model") -> str:
        """Log a ``torch.nn.Module`` taking ONE float tensor and giving one tensor (what MLflow's
        pytorch flavor serves), with its signature inferred from ``input_example`` (a numpy
        array). Returns the model's URI (``models:/...``, loadable by ``mlflow.pytorch.load_model``)
        or ``""`` if the backend keeps no models."""
        return self.tracker._log_model(self, model, input_example, name)

    def system_metrics(self, interval_s: float = 5.0) -> AbstractContextManager[None]:
        """``with run.system_metrics(): train()``: CPU, memory (GPU where present) sampled every
        ``interval_s`` seconds while the block runs (MLflow only; other backends sample nothing)."""
        return self.tracker._system_metrics(self, interval_s)

    # ------------------------------------------------------------------ ending
    def end(
        self, status: RunStatus | str = RunStatus.FINISHED, end_time_ms: int | None = None
    ) -> None:
        """Flush and close the run with ``status`` at ``end_time_ms`` (default now); a second
        call is a no-op."""
        if self.status is not RunStatus.RUNNING:
            return
        status = RunStatus(status)
        if status is RunStatus.RUNNING:
            raise ValueError("a run cannot be ended with status RUNNING")
        try:
            self.flush()
        finally:
            self.status = status
            self.end_time_ms = end_time_ms if end_time_ms is not None else _now_ms()
            self.tracker._end_run(self, status)

    def fail(self, reason: str, end_time_ms: int | None = None) -> None:
        """End the run FAILED because of ``reason`` (one line, e.g. ``"non-finite val_loss_total
        = inf at epoch 3"``): the tag ``failure_reason`` holds it (cut to MLflow's 8000-character
        limit) and the run's note (``mlflow.note.content``, shown on its page) gets it appended
        below the existing description. A no-op on a run that already ended."""
        if self.status is not RunStatus.RUNNING:
            return
        reason = " ".join(str(reason).split()) or "unknown reason"
        try:
            self.set_tags(
                {
                    FAILURE_REASON_TAG: cut_text(reason, MAX_TAG_VALUE),
                    DESCRIPTION_TAG: failed_note(self.tags.get(DESCRIPTION_TAG, ""), reason),
                }
            )
        finally:  # a backend that cannot take the tags still gets the status
            self.end(RunStatus.FAILED, end_time_ms)

    def __enter__(self) -> Run:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.end(RunStatus.FINISHED)
        elif issubclass(exc_type, KeyboardInterrupt):
            self.end(RunStatus.KILLED)
        else:
            detail = str(exc).strip() if exc is not None else ""
            self.fail(f"{exc_type.__name__}: {detail}" if detail else exc_type.__name__)

    def latest_metrics(self) -> dict[str, float]:
        out: dict[str, float] = {}
        for point in self.metrics:
            out[point.key] = point.value
        return out

    def __repr__(self) -> str:
        return f"Run({self.run_name!r}, id={self.run_id!r}, {self.status.value})"


def _check_tags(tags: Mapping[str, str], where: str) -> None:
    empty = sorted(k for k, v in tags.items() if v == "")
    if empty:
        raise ValueError(f"empty tag value(s) {empty} for {where!r}: leave such tags out")


class Tracker(abc.ABC):
    """A tracking backend. Subclasses implement the underscore primitives and
    :meth:`find_runs`; :meth:`start_run`, :meth:`attach` and :class:`Run` are shared."""

    #: Human-readable target, e.g. ``sqlite:///.../mlflow.db`` or a directory.
    uri: str = ""

    def start_run(
        self,
        experiment: str,
        run_name: str,
        *,
        parent: Run | None = None,
        tags: Mapping[str, object] | None = None,
        description: str = "",
        start_time_ms: int | None = None,
    ) -> Run:
        """Start a run in ``experiment`` (created if missing), nested under ``parent`` if given.

        ``description`` (Markdown) is shown on the run's page; ``start_time_ms`` (epoch ms,
        default now) records when the work began, so a run logged after the fact still shows
        its real duration (end it with ``run.end(end_time_ms=...)``). Use the result as a
        context manager so it always ends with the right status.
        """
        if not experiment:
            raise ValueError("experiment name must be a non-empty string")
        if parent is not None and parent.experiment != experiment:
            raise ValueError(
                f"nested run {run_name!r} must live in its parent's experiment "
                f"{parent.experiment!r}, not {experiment!r}"
            )
        str_tags = {str(k): _as_str(v) for k, v in (tags or {}).items()}
        if description:
            str_tags[DESCRIPTION_TAG] = description
        _check_tags(str_tags, run_name)
        run = Run(self, "", experiment, run_name, parent, str_tags, start_time_ms=start_time_ms)
        run.run_id = self._create_run(run)
        return run

    def attach(self, info: RunInfo, *, reopen: bool = True) -> Run:
        """A :class:`Run` handle on a stored run (from :meth:`find_runs`), to log more to it and
        end it again. ``reopen``: mark it RUNNING in the store (a resumed unit continues its run;
        the start time stays, so its duration spans the interruption)."""
        run = Run(
            self,
            info.run_id,
            info.experiment,
            info.run_name,
            None,
            info.tags,
            start_time_ms=info.start_time_ms,
        )
        run.params.update(info.params)
        if reopen:
            self._reopen_run(run)
        return run

    def describe_experiment(
        self, experiment: str, description: str, tags: Mapping[str, str] | None = None
    ) -> None:
        """Create ``experiment`` if missing and set its description (Markdown, shown on top of
        its runs), its kind (``custom_model_development``: MLflow's classic model-training view,
        not the GenAI one) and ``tags``."""
        all_tags = {EXPERIMENT_KIND_TAG: EXPERIMENT_KIND, **(tags or {})}
        if description:
            all_tags[DESCRIPTION_TAG] = description
        _check_tags(all_tags, experiment)
        self._set_experiment_tags(experiment, all_tags)

    @abc.abstractmethod
    def find_runs(
        self, experiment: str, run_key: str | None = None, statuses: tuple[str, ...] = ()
    ) -> list[RunInfo]:
        """Runs of ``experiment`` (tagged ``run_key`` if given, in one of ``statuses`` if any),
        most recent first."""

    def find_finished_run(self, experiment: str, run_key: str) -> RunInfo | None:
        """The most recent FINISHED run of ``experiment`` tagged ``run_key``, or ``None``."""
        found = self.find_runs(experiment, run_key, (RunStatus.FINISHED.value,))
        return found[0] if found else None

    def spec(self) -> TrackerSpec:
        """How a worker process builds the same tracker (``tracker_from_spec``)."""
        return TrackerSpec("null")

    def summary(self) -> str:
        """One line (two when runs wait to be synced) for the end of a command: where the runs
        went, e.g. ``tracking: sqlite:///.../mlflow.db (12 runs written by this invocation)``."""
        return f"tracking: {self.uri}"

    def pending_sync_notice(self) -> str:
        """A loud multi-line notice when finished runs exist only in a local fallback directory
        that this tracker's store has not received (``uavbench sync`` sends them); ``""`` when
        there are none. Printed by ``create_tracker`` at start and part of :meth:`summary`."""
        return ""

    def close(self) -> None:  # noqa: B027 - optional hook
        """Release resources; runs must have been ended."""

    # Primitives. ``run`` carries experiment, name, parent and the full record.
    @abc.abstractmethod
    def _create_run(self, run: Run) -> str: ...

    @abc.abstractmethod
    def _log_batch(
        self,
        run: Run,
        metrics: list[MetricPoint],
        params: Mapping[str, str],
        tags: Mapping[str, str],
    ) -> None: ...

    @abc.abstractmethod
    def _log_artifact(self, run: Run, path: Path, artifact_path: str | None) -> None: ...

    @abc.abstractmethod
    def _end_run(self, run: Run, status: RunStatus) -> None: ...

    # Optional primitives: a backend without the feature records nothing.
    def _reopen_run(self, run: Run) -> None:  # noqa: B027
        pass

    def _set_experiment_tags(self, experiment: str, tags: Mapping[str, str]) -> None:  # noqa: B027
        pass

    def _log_inputs(self, run: Run, datasets: list[DatasetRef]) -> None:  # noqa: B027
        pass

    def _log_model(self, run: Run, model: object, input_example: object, name: str) -> str:
        return ""

    def _system_metrics(self, run: Run, interval_s: float) -> AbstractContextManager[None]:
        return contextlib.nullcontext()
