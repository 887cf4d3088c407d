"""Train one unit and evaluate it on its splits; runs in a worker process.

Every split is evaluated twice: with each pair's true satellite image, and with the satellite image
of another place (the satellite-swap probe, ``PairDataset(..., satellite="swap")``). Results are
keyed by :func:`eval_key`: ``standard/test`` and ``standard/test/swap``. The swap summary also holds
the paired per-frame effect of the swap on the yaw and geodesic errors with its 95% flight
bootstrap interval (``swap_dpsi_diff_deg``, ``swap_dpsi_boot_lo_deg``, ...,
``benchmark.evaluation.paired.swap_effect``), so the claims need no predictions files.

Everything a unit produces lives in ``<workdir>/units/<key>/``: the training checkpoint (resumed
if present), one predictions CSV and one metrics JSON per evaluated split and satellite mode
(``eval/standard__test.csv``, ``eval/standard__test__swap.csv``), and ``unit.json`` with
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
from benchmark.data.swap import SATELLITE_MODES
from benchmark.training.config import TrainConfig

SWAP_SUFFIX = "/swap"


def eval_key(split: str, satellite: str) -> str:
    """Where one evaluation's numbers live: ``split`` (true image) or ``split + "/swap"``."""
    if satellite not in SATELLITE_MODES:
        raise ValueError(f"satellite must be one of {SATELLITE_MODES}, got {satellite!r}")
    return split if satellite == "true" else split + SWAP_SUFFIX


def eval_keys(splits: list[str] | tuple[str, ...]) -> list[str]:
    return [eval_key(s, m) for s in splits for m in SATELLITE_MODES]


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
    metrics: dict[str, dict[str, float]] = field(default_factory=dict)  # eval_key -> summary
    predictions: dict[str, str] = field(default_factory=dict)  # eval_key -> CSV path
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
    from benchmark.training.build import run_training

    task.unit_dir.mkdir(parents=True, exist_ok=True)
    (task.unit_dir / "unit.json").write_text(json.dumps(to_dict(task.cfg), indent=2, default=str))
    trained = run_training(task.cfg, task.unit_dir / "train", progress=False)
    model = trained.model.eval()
    result = UnitResult(task.key, True, history=list(trained.history))
    for split in task.eval_splits:
        for satellite in SATELLITE_MODES:  # true first: the swap summary compares with it
            key = eval_key(split, satellite)
            result.metrics[key], result.predictions[key] = _evaluate_split(
                task, model, split, satellite
            )
    result.seconds = time.perf_counter() - start
    return result


def _evaluate_split(task: UnitTask, model, split: str, satellite: str) -> tuple[dict, str]:
    """Evaluate one split in one satellite mode, or read the files a previous run wrote."""
    import pandas as pd

    from benchmark.data import PairDataset
    from benchmark.evaluation.evaluate import evaluate
    from benchmark.evaluation.paired import swap_effect

    stem = task.unit_dir / "eval" / split_filename(eval_key(split, satellite))
    csv_path, json_path = stem.with_suffix(".csv"), stem.with_suffix(".json")
    if json_path.is_file() and csv_path.is_file():
        return json.loads(json_path.read_text()), str(csv_path)
    dataset = PairDataset(task.cfg.data.root, split, verify="size", satellite=satellite)
    summary, _ = evaluate(model, dataset, out_csv=csv_path, batch_size=task.eval_batch)
    if satellite == "swap":
        # Both frames as written (10 significant digits): identical predictions give a zero
        # difference, not the rounding error of one of them.
        true_csv = (task.unit_dir / "eval" / split_filename(split)).with_suffix(".csv")
        summary.update(swap_effect(pd.read_csv(true_csv), pd.read_csv(csv_path)))
    tmp = json_path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(summary, indent=2))
    tmp.replace(json_path)  # written last: its presence means the split is done
    return summary, str(csv_path)
