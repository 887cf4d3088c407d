"""The tracker interface: experiments, (nested) runs, params, batched metrics, artifacts, tags.

A :class:`Tracker` is a small backend with five primitives (create a run, log a batch, log an
artifact, end a run, find a finished run). Everything a caller touches is a :class:`Run` handle,
written once here for every backend: it buffers metrics and sends them in batches, keeps a record of
everything logged (so a backend that fails mid-run can hand the whole run over to a local fallback
without losing anything), and, used as a context manager, ends the run FINISHED on success, FAILED
on an exception and KILLED on ``KeyboardInterrupt``.

The runner never imports mlflow: it gets a tracker from :func:`benchmark.tracking.create_tracker`
and talks to this interface only.
"""

from __future__ import annotations

import abc
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from types import TracebackType

# Tag under which the stable hash of a (variant, seed, config) is stored; find_finished_run
# looks it up so a reproduction never redoes a finished run.
RUN_KEY_TAG = "run_key"


class RunStatus(str, Enum):
    """Terminal and live states, spelled as MLflow spells them."""

    RUNNING = "RUNNING"
    FINISHED = "FINISHED"
    FAILED = "FAILED"
    KILLED = "KILLED"


@dataclass(frozen=True)
class RunInfo:
    """What :meth:`Tracker.find_finished_run` returns about a stored run.

    ``metrics`` holds the latest value of each metric; ``backend`` is ``"mlflow"`` or ``"local"``.
    """

    run_id: str
    experiment: str
    run_name: str
    status: str
    tags: Mapping[str, str] = field(default_factory=dict)
    params: Mapping[str, str] = field(default_factory=dict)
    metrics: Mapping[str, float] = field(default_factory=dict)
    artifact_uri: str = ""
    backend: str = ""


@dataclass(frozen=True)
class MetricPoint:
    key: str
    value: float
    step: int
    timestamp_ms: int


def _as_str(value: object) -> str:
    """Params and tags are strings in every backend; ``None`` becomes ``"None"`` like MLflow."""
    return value if isinstance(value, str) else str(value)


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
    ) -> None:
        self.tracker = tracker
        self.run_id = run_id
        self.experiment = experiment
        self.run_name = run_name
        self.parent = parent
        self.status = RunStatus.RUNNING
        self.batch_size = int(batch_size)
        # The full record, kept for a hand-over to the local fallback (see MlflowTracker).
        self.tags: dict[str, str] = dict(tags)
        self.params: dict[str, str] = {}
        self.metrics: list[MetricPoint] = []
        self.artifacts: list[tuple[Path, str | None]] = []
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
        new = {str(k): _as_str(v) for k, v in tags.items()}
        self.tags.update(new)
        self.tracker._log_batch(self, [], {}, new)

    def log_metrics(self, metrics: Mapping[str, float], step: int = 0) -> None:
        """Buffer one value per key at ``step`` (e.g. the epoch). Non-numbers raise ``TypeError``.

        NaN and inf are kept (MLflow stores them); a caller that wants to stop on them checks first.
        """
        now = int(time.time() * 1000)
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

    # ------------------------------------------------------------------ ending
    def end(self, status: RunStatus | str = RunStatus.FINISHED) -> None:
        """Flush and close the run with ``status``; a second call is a no-op."""
        if self.status is not RunStatus.RUNNING:
            return
        status = RunStatus(status)
        if status is RunStatus.RUNNING:
            raise ValueError("a run cannot be ended with status RUNNING")
        try:
            self.flush()
        finally:
            self.status = status
            self.tracker._end_run(self, status)

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
            self.end(RunStatus.FAILED)

    def latest_metrics(self) -> dict[str, float]:
        out: dict[str, float] = {}
        for point in self.metrics:
            out[point.key] = point.value
        return out

    def __repr__(self) -> str:
        return f"Run({self.run_name!r}, id={self.run_id!r}, {self.status.value})"


class Tracker(abc.ABC):
    """A tracking backend. Subclasses implement the underscore primitives and
    :meth:`find_finished_run`; :meth:`start_run` and :class:`Run` are shared."""

    #: Human-readable target, e.g. ``sqlite:///.../mlflow.db`` or a directory.
    uri: str = ""

    def start_run(
        self,
        experiment: str,
        run_name: str,
        *,
        parent: Run | None = None,
        tags: Mapping[str, object] | None = None,
    ) -> Run:
        """Start a run in ``experiment`` (created if missing), nested under ``parent`` if given.

        Use the result as a context manager so it always ends with the right status.
        """
        if not experiment:
            raise ValueError("experiment name must be a non-empty string")
        if parent is not None and parent.experiment != experiment:
            raise ValueError(
                f"nested run {run_name!r} must live in its parent's experiment "
                f"{parent.experiment!r}, not {experiment!r}"
            )
        str_tags = {str(k): _as_str(v) for k, v in (tags or {}).items()}
        run = Run(self, "", experiment, run_name, parent, str_tags)
        run.run_id = self._create_run(run)
        return run

    @abc.abstractmethod
    def find_finished_run(self, experiment: str, run_key: str) -> RunInfo | None:
        """The most recent FINISHED run of ``experiment`` tagged ``run_key``, or ``None``."""

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
