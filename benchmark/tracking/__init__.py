"""Experiment tracking behind one small interface (pykeen style).

``create_tracker()`` gives an :class:`MlflowTracker` on the embedded sqlite store (or a server from
``--tracking-uri`` / ``MLFLOW_TRACKING_URI``, checked by :func:`normalize_tracking_uri`) that
falls back to local files, loudly, if MLflow fails; :class:`NullTracker` logs nothing (tests).
``tracker.summary()`` says at the end where the runs are; ``uavbench sync``
(:mod:`benchmark.tracking.sync`) copies fallback runs into a store. mlflow is imported only when
an MlflowTracker is built.
"""

from __future__ import annotations

from pathlib import Path

from benchmark.progress import status
from benchmark.tracking.base import (
    DESCRIPTION_TAG,
    EXPERIMENT_KIND,
    EXPERIMENT_KIND_TAG,
    FAILURE_REASON_TAG,
    RUN_KEY_TAG,
    DatasetRef,
    MetricPoint,
    Run,
    RunInfo,
    RunStatus,
    Tracker,
    TrackerSpec,
)
from benchmark.tracking.local import LocalTracker, NullTracker
from benchmark.tracking.mlflow_tracker import (
    MlflowTracker,
    TrackingFallbackWarning,
    default_tracking_uri,
    server_is_healthy,
)
from benchmark.tracking.provenance import file_sha256, git_commit, manifest_sha256
from benchmark.tracking.uri import normalize_tracking_uri

__all__ = [
    "DESCRIPTION_TAG",
    "EXPERIMENT_KIND",
    "EXPERIMENT_KIND_TAG",
    "FAILURE_REASON_TAG",
    "RUN_KEY_TAG",
    "DatasetRef",
    "LocalTracker",
    "MetricPoint",
    "MlflowTracker",
    "NullTracker",
    "Run",
    "RunInfo",
    "RunStatus",
    "Tracker",
    "TrackerSpec",
    "TrackingFallbackWarning",
    "create_tracker",
    "default_tracking_uri",
    "file_sha256",
    "git_commit",
    "manifest_sha256",
    "normalize_tracking_uri",
    "server_is_healthy",
    "tracker_from_spec",
]


def create_tracker(
    kind: str = "mlflow",
    tracking_uri: str | None = None,
    *,
    workdir: str | Path | None = None,
) -> Tracker:
    """``kind``: ``"mlflow"`` (default store in ``workdir`` or a server), ``"local"`` (files under
    ``workdir/tracking-local``) or ``"null"``.

    ``tracking_uri`` goes through :func:`normalize_tracking_uri` (``x.db`` -> ``sqlite:///``;
    an unusable value raises :class:`~benchmark.errors.InputError`). An MLflow tracker whose
    store is reachable but misses runs an earlier invocation kept in ``tracking-fallback`` says
    its :meth:`~MlflowTracker.pending_sync_notice` here, once per command, as
    :func:`~benchmark.progress.status` lines. Returns the tracker."""
    base = Path(workdir) if workdir is not None else Path.cwd()
    if kind == "null":
        return NullTracker()
    if kind == "local":
        return LocalTracker(base / "tracking-local")
    if kind == "mlflow":
        tracker = MlflowTracker(
            normalize_tracking_uri(tracking_uri) or default_tracking_uri(base),
            artifact_root=base / "mlartifacts",
            fallback_dir=base / "tracking-fallback",
        )
        notice = tracker.pending_sync_notice()
        # A warning said as the work starts, for people (programs read pending_sync_notice()):
        # the status channel, which a Python caller can capture or silence, not a print.
        for line in notice.splitlines():
            status(line)
        return tracker
    raise ValueError(f"unknown tracker kind {kind!r}; expected one of 'mlflow', 'local', 'null'")


_BY_SPEC: dict[TrackerSpec, Tracker] = {}


def tracker_from_spec(spec: TrackerSpec) -> Tracker:
    """The tracker ``spec`` (``Tracker.spec()``) describes, built once per process: how a worker
    process logs to the store of the process that started it."""
    if spec not in _BY_SPEC:
        if spec.kind == "null":
            _BY_SPEC[spec] = NullTracker()
        elif spec.kind == "local":
            _BY_SPEC[spec] = LocalTracker(spec.uri)
        elif spec.kind == "mlflow":
            _BY_SPEC[spec] = MlflowTracker(
                spec.uri, artifact_root=spec.artifact_root, fallback_dir=spec.fallback_dir
            )
        else:
            raise ValueError(f"unknown tracker kind {spec.kind!r} in {spec}")
    return _BY_SPEC[spec]
