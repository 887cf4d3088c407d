"""MLflow backend with a local fallback that loses nothing.

Embedded default: the sqlite store ``sqlite:///<cwd>/mlflow.db`` (MLflow 3.x no longer accepts the
plain file store) with artifacts under ``<cwd>/mlartifacts/<experiment>``; nothing to start.
``tracking_uri`` (``--tracking-uri`` or ``MLFLOW_TRACKING_URI``) points at a server instead.

The URI goes through :func:`~benchmark.tracking.uri.normalize_tracking_uri` (a plain ``x.db``
becomes ``sqlite:///<abs>``, anything unusable is refused), and the first open of a sqlite store
runs under its schema lock (:func:`~benchmark.tracking.uri.open_sqlite_store_once`), so processes
starting together on a fresh store do not race in MLflow's migration.

Failure policy: if the server does not answer ``/health`` within ``health_timeout`` seconds at
start, or any MLflow call fails later, the tracker switches for the rest of the process to a
:class:`~benchmark.tracking.local.LocalTracker` under ``fallback_dir``, says ONE loud block
(:func:`~benchmark.progress.status` lines: what failed, where the runs go, the exact
``uavbench sync --from DIR --to URI`` that sends them) and emits one
:class:`TrackingFallbackWarning` (for programs; not displayed by default, the block is the
message for people). Every run still open is handed over with its complete record
(params, tags, all metrics logged so far, artifacts), tagged ``mlflow_run_id`` with its id on the
server, so the local copy is self-contained. Runs that ended before the failure are on the server.
:meth:`MlflowTracker.summary` says at the end where the runs really are.

Runs found in the fallback directory by a later invocation are reused (a finished unit is not
trained again), but they stay local: with the store reachable again, ``create_tracker`` says
:meth:`MlflowTracker.pending_sync_notice` (N runs exist only locally, and the sync command) and
the summary repeats it. ``uavbench sync`` copies them; once copied (``synced.json`` beside each
run) they are found in the store only, never twice.

mlflow is imported lazily (in the constructor), so importing this module costs nothing.
"""

from __future__ import annotations

import os
import re
import time
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from benchmark.progress import status
from benchmark.tracking.base import (
    RUN_KEY_TAG,
    MetricPoint,
    Run,
    RunInfo,
    RunStatus,
    Tracker,
    TrackerSpec,
)
from benchmark.tracking.local import LocalTracker, _safe_dirname
from benchmark.tracking.mlflow_lineage import LineageMixin
from benchmark.tracking.mlflow_summary import SummaryMixin
from benchmark.tracking.pending import fallback_message, is_synced
from benchmark.tracking.uri import (
    default_tracking_uri,
    normalize_tracking_uri,
    open_sqlite_store_once,
    server_is_healthy,
)

__all__ = ["MlflowTracker", "TrackingFallbackWarning", "default_tracking_uri", "server_is_healthy"]

# Retries of a failed MLflow call before falling back (see MlflowTracker._guard).
_RETRIES, _RETRY_PAUSE_S = 3, 0.3
# MLflow's REST limits per log_batch request (mlflow.utils.validation).
_MAX_METRICS, _MAX_PARAMS_TAGS, _MAX_ENTITIES = 1000, 100, 1000
# A run_key goes into a search filter string: keep it to characters that need no quoting.
_RUN_KEY_RE = re.compile(r"^[A-Za-z0-9_.:-]{1,128}$")
# Shorter retries than MLflow's defaults (7 retries, 120 s timeout: minutes before giving up) so a
# dead server is noticed quickly; a user's own setting of these variables wins.
_HTTP_ENV_DEFAULTS = {
    "MLFLOW_HTTP_REQUEST_MAX_RETRIES": "2",
    "MLFLOW_HTTP_REQUEST_BACKOFF_FACTOR": "1",
    "MLFLOW_HTTP_REQUEST_TIMEOUT": "30",
}


def _is_connection_error(err: Exception) -> bool:
    """A dead server (its client already retried): no point in retrying again."""
    text = repr(err)
    return any(s in text for s in ("Connection refused", "Max retries", "timed out", "Timeout"))


def _client(uri: str) -> Any:
    """An MlflowClient on ``uri``; a database store is opened (schema created) here."""
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri=uri)
    if not uri.startswith(("http://", "https://")):
        client.search_experiments(max_results=1)
    return client


class TrackingFallbackWarning(UserWarning):
    """MLflow could not be used; results go to a local directory instead. Its message is the
    block said as status lines; catch it with ``pytest.warns`` / ``warnings.catch_warnings``."""


# The status block is what people read; the warning is for programs, so by default it is not
# displayed a second time (appended: a user's own -W / PYTHONWARNINGS filter still wins).
warnings.filterwarnings("ignore", category=TrackingFallbackWarning, append=True)


class MlflowTracker(SummaryMixin, LineageMixin, Tracker):
    """One MLflow experiment per table/figure, a parent run per invocation, nested runs per
    (variant, seed). See the module docstring for the store defaults and the fallback."""

    def __init__(
        self,
        tracking_uri: str | None = None,
        *,
        artifact_root: str | Path | None = None,
        fallback_dir: str | Path | None = None,
        health_timeout: float = 5.0,
    ) -> None:
        self.uri = normalize_tracking_uri(tracking_uri) or default_tracking_uri()
        self._is_http = self.uri.startswith(("http://", "https://"))
        cwd = Path.cwd()
        # Artifacts of a local store go next to the db; a server decides for itself.
        self.artifact_root = (
            None if self._is_http else Path(artifact_root or cwd / "mlartifacts").resolve()
        )
        self.fallback_dir = Path(fallback_dir or cwd / "tracking-fallback").resolve()
        self._fallback: LocalTracker | None = None
        self._open: list[Run] = []  # creation order: a parent is handed over before its children
        self._experiment_ids: dict[str, str] = {}
        self._client: Any = None
        self._started_ms = int(time.time() * 1000)
        self._failure = ""  # why the fallback is used, for the summary
        if self._is_http:
            for key, value in _HTTP_ENV_DEFAULTS.items():
                os.environ.setdefault(key, value)
            ok, reason = server_is_healthy(self.uri, timeout=health_timeout)
            if not ok:
                self._failure = "was unreachable"
                self._switch_to_fallback(f"tracking server {self.uri} is unreachable ({reason})")
                return
        try:
            # MlflowClient() opens the store, which creates/migrates a sqlite db: under its lock.
            self._client = open_sqlite_store_once(self.uri, lambda: _client(self.uri))
        except Exception as err:  # any store error: fall back, never abort the work
            self._failure = "could not be opened"
            self._switch_to_fallback(f"MLflow store {self.uri} cannot be opened ({err!r})")

    def spec(self) -> TrackerSpec:
        if self._fallback is not None:
            return TrackerSpec("local", str(self.fallback_dir))
        root = str(self.artifact_root) if self.artifact_root is not None else None
        return TrackerSpec("mlflow", self.uri, root, str(self.fallback_dir))

    # ------------------------------------------------------------------ state
    @property
    def using_fallback(self) -> bool:
        """True once results go to ``fallback_dir`` instead of MLflow."""
        return self._fallback is not None

    def _switch_to_fallback(self, reason: str) -> None:
        if self._fallback is not None:
            return
        self._fallback = LocalTracker(self.fallback_dir)
        self._failure = self._failure or "failed during the run"
        message = fallback_message(reason, self.fallback_dir, self.uri)
        # Said while the work goes on (it goes on, locally): status lines, which a Python caller
        # can capture or silence; the warning below is the same news for programs.
        for line in message.splitlines():
            status(line)
        warnings.warn(message, TrackingFallbackWarning, stacklevel=3)
        for run in list(self._open):
            self._hand_over(run, reason)

    def _hand_over(self, run: Run, reason: str) -> None:
        """Recreate ``run`` in the fallback with everything already sent (or being sent)."""
        assert self._fallback is not None
        if run.run_id:
            run.tags["mlflow_run_id"] = run.run_id
            if self._client is not None and not self._is_http:
                # A local store still answers: do not leave a RUNNING husk there (a dead
                # server cannot be told, and waiting for it would delay the work).
                try:
                    self._client.set_terminated(run.run_id, RunStatus.FAILED.value)
                except Exception:  # best effort; the fallback has the record
                    pass
        run.tags["tracking_fallback"] = reason[:500]
        run.run_id = self._fallback._create_run(run)
        sent = run.metrics[: len(run.metrics) - run._unsent]  # the unsent buffer comes later
        if sent:
            self._fallback._log_batch(run, sent, {}, {})
        for path, artifact_path in run.artifacts:
            if path.exists():
                self._fallback._log_artifact(run, path, artifact_path)
        if run.inputs:
            self._fallback._log_inputs(run, run.inputs)
        if run.status is not RunStatus.RUNNING:
            self._fallback._end_run(run, run.status)

    def _guard(self, what: str, call, *args) -> bool:
        """Run an MLflow call; on failure switch to the fallback. The hand-over replays the full
        record of every open run, so the failed call is not retried then. True if MLflow took it.

        A failure is first retried (``_RETRIES`` times, short pauses): processes writing to one
        sqlite store at once can hit "database is locked" or a check-then-insert race (two
        workers logging the same dataset: UNIQUE constraint failed); the retry then succeeds."""
        for attempt in range(_RETRIES + 1):
            try:
                call(*args)
                return True
            except Exception as err:
                if attempt == _RETRIES or (self._is_http and _is_connection_error(err)):
                    self._switch_to_fallback(f"MLflow call {what} failed ({err!r})")
                    return False
                time.sleep(_RETRY_PAUSE_S * (attempt + 1))
        return False

    # ------------------------------------------------------------------ experiments
    def _experiment_id(self, name: str) -> str:
        if name in self._experiment_ids:
            return self._experiment_ids[name]
        exp = self._client.get_experiment_by_name(name)
        if exp is None:
            location = None
            if self.artifact_root is not None:
                location = (self.artifact_root / _safe_dirname(name)).as_uri()
            try:
                exp_id = self._client.create_experiment(name, artifact_location=location)
            except Exception:
                # Another process may have created it between the two calls.
                exp = self._client.get_experiment_by_name(name)
                if exp is None:
                    raise
                exp_id = exp.experiment_id
        else:
            exp_id = exp.experiment_id
        self._experiment_ids[name] = exp_id
        return exp_id

    # ------------------------------------------------------------------ primitives
    def _create_run(self, run: Run) -> str:
        self._open.append(run)
        if self._fallback is None:
            from mlflow.utils.mlflow_tags import MLFLOW_PARENT_RUN_ID

            tags = dict(run.tags)
            if run.parent is not None:
                tags[MLFLOW_PARENT_RUN_ID] = run.parent.run_id

            def create() -> None:
                exp_id = self._experiment_id(run.experiment)
                created = self._client.create_run(
                    exp_id, start_time=run.start_time_ms, tags=tags, run_name=run.run_name
                )
                run.run_id = created.info.run_id

            self._guard("create_run", create)  # on failure the hand-over sets run.run_id
            return run.run_id
        return self._fallback._create_run(run)

    def _log_batch(
        self,
        run: Run,
        metrics: list[MetricPoint],
        params: Mapping[str, str],
        tags: Mapping[str, str],
    ) -> None:
        if self._fallback is not None:
            self._fallback._log_batch(run, metrics, params, tags)
            return
        from mlflow.entities import Metric, Param, RunTag

        metrics_all = [Metric(p.key, p.value, p.timestamp_ms, p.step) for p in metrics]
        params_all = [Param(k, v) for k, v in params.items()]
        tags_all = [RunTag(k, v) for k, v in tags.items()]

        def send() -> None:
            # Chunk to MLflow's per-request limits; typically a single request. A retry (see
            # _guard) resends everything: the chunks are cut from copies.
            m, p, t = list(metrics_all), list(params_all), list(tags_all)
            while m or p or t:
                cp, p[:] = p[:_MAX_PARAMS_TAGS], p[_MAX_PARAMS_TAGS:]
                ct, t[:] = t[:_MAX_PARAMS_TAGS], t[_MAX_PARAMS_TAGS:]
                room = min(_MAX_METRICS, _MAX_ENTITIES - len(cp) - len(ct))
                cm, m[:] = m[:room], m[room:]
                self._client.log_batch(run.run_id, metrics=cm, params=cp, tags=ct)

        self._guard("log_batch", send)

    def _log_artifact(self, run: Run, path: Path, artifact_path: str | None) -> None:
        if self._fallback is not None:
            self._fallback._log_artifact(run, path, artifact_path)
            return
        if path.is_dir():
            dest = f"{artifact_path}/{path.name}" if artifact_path else path.name
            self._guard("log_artifacts", self._client.log_artifacts, run.run_id, str(path), dest)
        else:
            self._guard(
                "log_artifact", self._client.log_artifact, run.run_id, str(path), artifact_path
            )

    def _end_run(self, run: Run, status: RunStatus) -> None:
        try:
            if self._fallback is not None:
                self._fallback._end_run(run, status)
            else:
                self._guard(
                    "set_terminated",
                    self._client.set_terminated,
                    run.run_id,
                    status.value,
                    run.end_time_ms,
                )
        finally:
            if run in self._open:
                self._open.remove(run)

    def _reopen_run(self, run: Run) -> None:
        if self._fallback is not None:
            self._fallback._reopen_run(run)
            return
        self._open.append(run)
        self._guard("update_run", self._client.update_run, run.run_id, RunStatus.RUNNING.value)

    def attach(self, info: RunInfo, *, reopen: bool = True) -> Run:
        if info.backend == "local":  # found in the fallback directory by an earlier invocation
            return LocalTracker(self.fallback_dir).attach(info, reopen=reopen)
        return super().attach(info, reopen=reopen)

    def _set_experiment_tags(self, experiment: str, tags: Mapping[str, str]) -> None:
        if self._fallback is not None:
            self._fallback._set_experiment_tags(experiment, tags)
            return

        def send() -> None:
            exp_id = self._experiment_id(experiment)
            for key, value in tags.items():
                self._client.set_experiment_tag(exp_id, key, value)

        if not self._guard("set_experiment_tag", send):
            self._fallback._set_experiment_tags(experiment, tags)

    # ------------------------------------------------------------------ lookup
    def find_runs(
        self, experiment: str, run_key: str | None = None, statuses: tuple[str, ...] = ()
    ) -> list[RunInfo]:
        """MLflow's runs first (most recent first), then those an earlier invocation wrote to
        the fallback directory (except those ``uavbench sync`` copied into this store: the
        store has them)."""
        if run_key is not None and not _RUN_KEY_RE.match(run_key):
            raise ValueError(f"run_key {run_key!r} must match {_RUN_KEY_RE.pattern}")
        found: list[RunInfo] = []
        if self._fallback is None:

            def search() -> None:
                exp = self._client.get_experiment_by_name(experiment)
                if exp is None:
                    return
                clauses = [f"tags.{RUN_KEY_TAG} = '{run_key}'"] if run_key else []
                if len(statuses) == 1:  # the common case (FINISHED, RUNNING): let the store filter
                    clauses.append(f"attributes.status = '{RunStatus(statuses[0]).value}'")
                runs = self._client.search_runs(
                    [exp.experiment_id],
                    filter_string=" and ".join(clauses),
                    order_by=["attributes.start_time DESC"],
                    max_results=1000,
                )
                found.extend(
                    self._info(r, experiment)
                    for r in runs
                    if not statuses or r.info.status in statuses
                )

            self._guard("search_runs", search)
        local = LocalTracker(self.fallback_dir).find_runs(experiment, run_key, statuses)
        if self._fallback is None:
            exp_dir = self.fallback_dir / _safe_dirname(experiment)
            local = [r for r in local if not is_synced(exp_dir / r.run_id, self.uri)]
        return found + local

    @staticmethod
    def _info(run: Any, experiment: str) -> RunInfo:
        return RunInfo(
            run_id=run.info.run_id,
            experiment=experiment,
            run_name=run.info.run_name or "",
            status=run.info.status,
            tags=dict(run.data.tags),
            params=dict(run.data.params),
            metrics=dict(run.data.metrics),
            artifact_uri=run.info.artifact_uri or "",
            backend="mlflow",
            start_time_ms=run.info.start_time,
            end_time_ms=run.info.end_time,
        )
