"""Experiment tracking behind one small interface (pykeen style).

``create_tracker()`` gives an :class:`MlflowTracker` on the embedded sqlite store (or a server from
``--tracking-uri`` / ``MLFLOW_TRACKING_URI``) that falls back to local files if MLflow fails;
:class:`NullTracker` logs nothing (tests). mlflow is imported only when an MlflowTracker is built.
"""

from __future__ import annotations

from pathlib import Path

from benchmark.tracking.base import (
    DESCRIPTION_TAG,
    EXPERIMENT_KIND,
    EXPERIMENT_KIND_TAG,
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

__all__ = [
    "DESCRIPTION_TAG",
    "EXPERIMENT_KIND",
    "EXPERIMENT_KIND_TAG",
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
    ``workdir/tracking-local``) or ``"null"``."""
    base = Path(workdir) if workdir is not None else Path.cwd()
    if kind == "null":
        return NullTracker()
    if kind == "local":
        return LocalTracker(base / "tracking-local")
    if kind == "mlflow":
        return MlflowTracker(
            tracking_uri or default_tracking_uri(base),
            artifact_root=base / "mlartifacts",
            fallback_dir=base / "tracking-fallback",
        )
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
