"""Session fixtures shared across test folders."""

from __future__ import annotations

import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import pytest


@pytest.fixture(scope="session")
def smoke_dataset(tmp_path_factory):
    """A ``smoke`` dataset (real worlds and renderer, tiny images), rendered once per session."""
    from benchmark.data.profiles import PROFILES
    from benchmark.data.writer import simulate_dataset

    root = tmp_path_factory.mktemp("smoke-dataset") / "ds"
    cache = tmp_path_factory.mktemp("smoke-cities")
    simulate_dataset(root, PROFILES["smoke"], 0, workers=1, cache_dir=cache, progress=False)
    return root


@pytest.fixture(autouse=True)
def _no_leaked_tracking_uri():
    """``mlflow.set_tracking_uri`` also writes ``MLFLOW_TRACKING_URI`` into ``os.environ``: a test
    that tracks to a server must not point every later test (and ``uavbench ui``'s default) at a
    server that is gone."""
    before = os.environ.get("MLFLOW_TRACKING_URI")
    yield
    if before is None:
        os.environ.pop("MLFLOW_TRACKING_URI", None)
    else:
        os.environ["MLFLOW_TRACKING_URI"] = before
