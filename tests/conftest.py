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
