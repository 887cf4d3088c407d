"""A smoke dataset rendered once per test session (real worlds and renderer, tiny images)."""

from __future__ import annotations

import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import pytest


@pytest.fixture(autouse=True)
def verify_cache(tmp_path_factory, monkeypatch):
    """Each test's verification cache (benchmark.data.integrity) in a temporary directory."""
    path = tmp_path_factory.mktemp("verified")
    monkeypatch.setenv("UAVBENCH_VERIFY_CACHE", str(path))
    return path


@pytest.fixture(scope="session")
def city_cache(tmp_path_factory):
    return tmp_path_factory.mktemp("cities")


@pytest.fixture(scope="session")
def smoke_root(tmp_path_factory, city_cache):
    from benchmark.data.profiles import DATA_PROFILES
    from benchmark.data.writer import simulate_dataset

    root = tmp_path_factory.mktemp("smoke") / "ds"
    stats = simulate_dataset(
        root, DATA_PROFILES["smoke"], 0, workers=1, cache_dir=city_cache, progress=False
    )
    assert stats["state"] == "written"
    return root
