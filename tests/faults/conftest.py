"""Fault injection (issue 14): copies of one smoke dataset, damaged the way a user would meet it."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import pytest


@pytest.fixture(autouse=True)
def verify_cache(tmp_path_factory, monkeypatch):
    """Each test's verification cache (benchmark.data.integrity) in its own temporary directory,
    and no cache remembered in this process from an earlier test."""
    from benchmark.data import integrity

    path = tmp_path_factory.mktemp("verified")
    monkeypatch.setenv("UAVBENCH_VERIFY_CACHE", str(path))
    integrity._MEMO.clear()
    return path


@pytest.fixture(scope="session")
def city_cache(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("fault-cities")


@pytest.fixture(scope="session")
def reference(tmp_path_factory, city_cache) -> Path:
    """A finished smoke dataset (seed 0), never modified: copy it with ``fresh_copy``."""
    from benchmark.data.profiles import DATA_PROFILES
    from benchmark.data.writer import simulate_dataset

    root = tmp_path_factory.mktemp("fault-ref") / "ds"
    stats = simulate_dataset(
        root, DATA_PROFILES["smoke"], 0, workers=1, cache_dir=city_cache, progress=False
    )
    assert stats["state"] == "written"
    return root


@pytest.fixture
def dataset(reference, tmp_path) -> Path:
    """A private copy of the reference dataset, to damage."""
    return Path(shutil.copytree(reference, tmp_path / "ds"))


@pytest.fixture(scope="session")
def checkpoint(reference, tmp_path_factory) -> Path:
    """A tiny model trained for one step on the reference dataset (for ``uavbench evaluate``)."""
    import torch

    from benchmark.config import apply_overrides
    from benchmark.training import TrainConfig
    from benchmark.training.build import run_training

    torch.set_num_threads(1)
    cfg = apply_overrides(
        TrainConfig(),
        [f"data.root={reference}", "data.val_split=None", "data.limit_train=4",
         "model.width=0.25", "model.variant=/", "optim.epochs=1", "optim.batch_size=4",
         "threads=1"],
    )  # fmt: skip
    out = tmp_path_factory.mktemp("fault-run")
    run_training(cfg, out, progress=False)
    return out / "checkpoint.pt"
