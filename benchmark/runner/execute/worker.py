"""Train one unit and evaluate it on its splits; runs in a worker process.

A unit is ``benchmark.training.pipeline.train_and_evaluate`` (the same train-then-evaluate path
as ``uavbench train``) into ``<workdir>/units/<key>/``: the training checkpoint
(``train/checkpoint.pt``, resumed if present), one predictions CSV and one metrics JSON per
evaluated split and satellite mode (``eval/standard__test.csv``, ``eval/standard__test__swap.csv``;
keys :func:`eval_key`: ``standard/test`` and ``standard/test/swap``), ``history.json`` and
``config.yaml``. A unit whose files are complete costs nothing to "run" again, so an interrupted
reproduction resumes where it stopped.

Live tracking (:class:`UnitTracking`): the worker opens the unit's training run when training
starts (``benchmark.runner.execute.live.open_unit_run``: a FINISHED run of the unit is reused, an
interrupted one continues), logs each epoch's metrics as it ends, system metrics while it trains,
then the evaluations, the dataset inputs and the model, and closes the run when evaluation ends,
so its duration is the real one. Pool workers ignore SIGINT: on Ctrl-C the parent stops them and
marks their runs KILLED, so the terminal shows one message, not a traceback per worker.
"""

from __future__ import annotations

import os
import signal
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

from benchmark.data.swap import SATELLITE_MODES
from benchmark.models.device import Placement, resolve_placement
from benchmark.runner.execute.heartbeat import write_heartbeat
from benchmark.runner.execute.live import UnitTracking, open_unit_run, track_unit
from benchmark.training.config import TrainConfig
from benchmark.training.identity import device_tags
from benchmark.training.pipeline import (
    EVAL_BATCH,
    SWAP_SUFFIX,
    eval_key,
    eval_keys,
    eval_paths,
    fusion_done,
    fusion_paths,
    joint_sequence_paths,
    sequence_paths,
    split_filename,
    train_and_evaluate,
    volume_sequence_paths,
)

__all__ = [
    "SATELLITE_MODES",
    "SWAP_SUFFIX",
    "UnitResult",
    "UnitTask",
    "UnitTracking",
    "eval_key",
    "eval_keys",
    "eval_paths",
    "fusion_done",
    "fusion_paths",
    "joint_sequence_paths",
    "run_unit",
    "sequence_paths",
    "split_filename",
    "unit_placement",
    "volume_sequence_paths",
    "worker_init",
]


@dataclass
class UnitTask:
    key: str
    cfg: TrainConfig
    eval_splits: list[str]
    unit_dir: Path
    eval_batch: int = EVAL_BATCH
    tracking: UnitTracking | None = None  # None: nothing is logged from the worker
    fuse_splits: list[str] = field(default_factory=list)  # fused along their flights (issue 39)
    volume_splits: list[str] = field(default_factory=list)  # the pose volume fused along them
    joint_splits: list[str] = field(default_factory=list)  # ... and jointly (heading, E, N)


@dataclass
class UnitResult:
    key: str
    ok: bool
    history: list[dict[str, float]] = field(default_factory=list)
    metrics: dict[str, dict[str, float]] = field(default_factory=dict)  # eval_key -> summary
    predictions: dict[str, str] = field(default_factory=dict)  # eval_key -> CSV path
    sequences: dict[str, str] = field(default_factory=dict)  # fused split -> sequence CSV path
    volume_sequences: dict[str, str] = field(default_factory=dict)  # the pose volume's, the same
    joint_sequences: dict[str, str] = field(default_factory=dict)  # its joint fusion's
    seconds: float = 0.0
    error: str = ""
    # where the worker computed (benchmark.training.identity.device_tags of its own placement):
    # the table runs' device/precision/accelerator tags, written from what the worker resolved
    placement_tags: dict[str, str] = field(default_factory=dict)
    run_id: str = ""  # the unit's training run ("" without tracking)
    started_ms: int | None = None  # when its training started / evaluation ended (epoch ms);
    ended_ms: int | None = None  # a reused run gives its own times
    model_uri: str = ""


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
    # Ctrl-C reaches the whole process group; the parent alone handles it (stops the workers,
    # marks their runs KILLED), so workers print no KeyboardInterrupt traceback.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
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


def unit_placement(cfg: TrainConfig) -> Placement:
    """``cfg``'s device and precision resolved on this worker, once per unit, and checked (bf16
    where this machine cannot run it is a ``PrecisionUnsupportedError``). The precision must
    arrive resolved: the plan computed the unit's key, which names it, on the driver, and
    ``"auto"`` resolved here could name another precision (a CPU driver, a GPU worker)."""
    if cfg.precision == "auto":
        raise ValueError(
            "a unit's precision must be resolved by the plan (fp32, bf16 or fp16), not 'auto': "
            "its key, computed on the driver, names the precision it trains in"
        )
    return resolve_placement(cfg.device, cfg.precision)


def _run_unit(task: UnitTask, start: float) -> UnitResult:
    epochs = task.cfg.optim.epochs
    placement = unit_placement(task.cfg)
    where = device_tags(task.cfg, placement)
    write_heartbeat(task.unit_dir, 0, epochs)  # the driver's progress line: this unit started

    def beat(epoch: int, _record: dict[str, float]) -> None:
        write_heartbeat(task.unit_dir, epoch, epochs)

    if task.tracking is None:
        done = train_and_evaluate(
            task.cfg, task.unit_dir, task.eval_splits, on_epoch_end=beat,
            eval_batch=task.eval_batch, fuse_splits=task.fuse_splits,
            volume_splits=task.volume_splits, joint_splits=task.joint_splits,
            placement=placement,
        )  # fmt: skip
        return _result(task, done, start, where)
    run, reused = open_unit_run(task.tracking)
    if reused is not None:  # a FINISHED run of this unit: compute (or read) the numbers only
        done = train_and_evaluate(
            task.cfg, task.unit_dir, task.eval_splits, on_epoch_end=beat,
            eval_batch=task.eval_batch, fuse_splits=task.fuse_splits,
            volume_splits=task.volume_splits, joint_splits=task.joint_splits,
            placement=placement,
        )  # fmt: skip
        result = _result(task, done, start, where)
        result.run_id, result.model_uri = reused.run_id, reused.tags.get("model_uri", "")
        result.started_ms, result.ended_ms = reused.start_time_ms, reused.end_time_ms
        return result
    with run:  # FINISHED, FAILED on an exception, KILLED on KeyboardInterrupt (one worker: inline)
        done, model_uri = track_unit(run, task.tracking, task.cfg, task.unit_dir, task.eval_splits,
                                     task.eval_batch, heartbeat=beat,
                                     fuse_splits=task.fuse_splits,
                                     volume_splits=task.volume_splits,
                                     joint_splits=task.joint_splits,
                                     placement=placement)  # fmt: skip
    result = _result(task, done, start, where)
    result.run_id, result.model_uri = run.run_id, model_uri
    result.started_ms, result.ended_ms = run.start_time_ms, run.end_time_ms
    return result


def _result(task: UnitTask, done, start: float, where: dict[str, str]) -> UnitResult:
    return UnitResult(
        task.key,
        True,
        history=list(done.history),
        metrics=done.metrics,
        predictions={k: str(v) for k, v in done.predictions.items()},
        sequences={k: str(path) for k, (_, path) in done.sequences.items()},
        volume_sequences={k: str(path) for k, (_, path) in done.volume_sequences.items()},
        joint_sequences={k: str(path) for k, (_, path) in done.joint_sequences.items()},
        seconds=time.perf_counter() - start,
        placement_tags=where,
    )
