"""Train one unit and evaluate it on its splits; runs in a worker process.

Everything a unit produces lives in ``<workdir>/units/<key>/``: the training checkpoint (resumed
if present), one predictions CSV and one metrics JSON per evaluated split, and ``unit.json`` with
the config. A unit whose files are complete costs nothing to "run" again, so an interrupted
reproduction resumes where it stopped: mid-training from the last epoch's checkpoint, after
training from the evaluations already written.
"""

from __future__ import annotations

import json
import os
import re
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

from benchmark.config import to_dict
from benchmark.training.config import TrainConfig


@dataclass
class UnitTask:
    key: str
    cfg: TrainConfig
    eval_splits: list[str]
    unit_dir: Path
    eval_batch: int = 64


@dataclass
class UnitResult:
    key: str
    ok: bool
    history: list[dict[str, float]] = field(default_factory=list)
    metrics: dict[str, dict[str, float]] = field(default_factory=dict)  # split -> summary
    predictions: dict[str, str] = field(default_factory=dict)  # split -> CSV path
    seconds: float = 0.0
    error: str = ""


def split_filename(split: str) -> str:
    """``height600/test -> height600__test`` (file-system safe, reversible enough to read)."""
    return re.sub(r"[^A-Za-z0-9_.-]", "_", split.replace("/", "__"))


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
    from benchmark.data import PairDataset
    from benchmark.evaluation.evaluate import evaluate
    from benchmark.training.build import run_training

    task.unit_dir.mkdir(parents=True, exist_ok=True)
    (task.unit_dir / "unit.json").write_text(json.dumps(to_dict(task.cfg), indent=2, default=str))
    trained = run_training(task.cfg, task.unit_dir / "train", progress=False)
    model = trained.model.eval()
    result = UnitResult(task.key, True, history=list(trained.history))
    for split in task.eval_splits:
        stem = task.unit_dir / "eval" / split_filename(split)
        csv_path, json_path = stem.with_suffix(".csv"), stem.with_suffix(".json")
        if json_path.is_file() and csv_path.is_file():
            summary = json.loads(json_path.read_text())
        else:
            dataset = PairDataset(task.cfg.data.root, split, verify="size")
            summary, _ = evaluate(model, dataset, out_csv=csv_path, batch_size=task.eval_batch)
            tmp = json_path.with_suffix(".json.tmp")
            tmp.write_text(json.dumps(summary, indent=2))
            tmp.replace(json_path)  # written last: its presence means the split is done
        result.metrics[split] = summary
        result.predictions[split] = str(csv_path)
    result.seconds = time.perf_counter() - start
    return result
