"""Train one unit and evaluate it on its splits; runs in a worker process.

A unit is ``benchmark.training.pipeline.train_and_evaluate`` (the same train-then-evaluate path
as ``uavbench train``) into ``<workdir>/units/<key>/``: the training checkpoint
(``train/checkpoint.pt``, resumed if present), one predictions CSV and one metrics JSON per
evaluated split and satellite mode (``eval/standard__test.csv``, ``eval/standard__test__swap.csv``;
keys :func:`eval_key`: ``standard/test`` and ``standard/test/swap``), ``history.json`` and
``config.yaml``. A unit whose files are complete costs nothing to "run" again, so an interrupted
reproduction resumes where it stopped.
"""

from __future__ import annotations

import os
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

from benchmark.data.swap import SATELLITE_MODES
from benchmark.training.config import TrainConfig
from benchmark.training.pipeline import (
    EVAL_BATCH,
    SWAP_SUFFIX,
    eval_key,
    eval_keys,
    split_filename,
    train_and_evaluate,
)

__all__ = [
    "SATELLITE_MODES",
    "SWAP_SUFFIX",
    "UnitResult",
    "UnitTask",
    "eval_key",
    "eval_keys",
    "run_unit",
    "split_filename",
    "worker_init",
]


@dataclass
class UnitTask:
    key: str
    cfg: TrainConfig
    eval_splits: list[str]
    unit_dir: Path
    eval_batch: int = EVAL_BATCH


@dataclass
class UnitResult:
    key: str
    ok: bool
    history: list[dict[str, float]] = field(default_factory=list)
    metrics: dict[str, dict[str, float]] = field(default_factory=dict)  # eval_key -> summary
    predictions: dict[str, str] = field(default_factory=dict)  # eval_key -> CSV path
    seconds: float = 0.0
    error: str = ""


def _die_with_parent() -> None:
    """Linux: have the kernel send SIGTERM to this worker when the reproduce process dies, so a
    killed reproduction leaves no orphan still training (seen here: orphans kept cores busy)."""
    try:
        import ctypes
        import signal

        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG = 1
    except (OSError, AttributeError):  # not Linux / no glibc: fall back to the pool's own checks
        pass


def worker_init() -> None:
    """One thread per worker process: two processes computing at once on two cores with two
    threads each ran up to 90x slower here."""
    _die_with_parent()
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ[var] = "1"
    import torch

    torch.set_num_threads(1)


def run_unit(task: UnitTask) -> UnitResult:
    """Train (or resume) and evaluate; never raises: failures come back as ``ok=False``."""
    start = time.perf_counter()
    try:
        return _run_unit(task, start)
    except Exception as err:  # reported per unit; the reproduction carries on with the rest
        detail = "".join(traceback.format_exception_only(type(err), err)).strip()
        return UnitResult(task.key, False, seconds=time.perf_counter() - start, error=detail)


def _run_unit(task: UnitTask, start: float) -> UnitResult:
    done = train_and_evaluate(task.cfg, task.unit_dir, task.eval_splits, eval_batch=task.eval_batch)
    return UnitResult(
        task.key,
        True,
        history=list(done.history),
        metrics=done.metrics,
        predictions={k: str(v) for k, v in done.predictions.items()},
        seconds=time.perf_counter() - start,
    )
