"""Rendering shards in worker processes: the render context, the per-shard task, the pool.

A task ``("uav" | "sat", k)`` renders shard ``k`` of the UAV or satellite table and writes it
atomically; every image depends only on its table row and the dataset seed, so any worker can
render any shard and the bytes do not depend on the number of workers. A task reports the sha256
of the bytes it rendered (computed in memory, before writing) and whether a file already at the
shard's path held exactly those bytes (``"same"``), other bytes (``"replaced"``) or none
(``"new"``): a shard found on disk is checked by rendering it again, never by trusting it.

The pool is a ``concurrent.futures.ProcessPoolExecutor`` of spawned workers: a worker that dies
(killed, out of memory, a crash in native code) breaks the pool, and the render stops with one
:class:`RenderWorkerError` naming the worker and its signal instead of waiting forever for a result
that will not come (``multiprocessing.Pool`` replaces the dead worker and waits). A worker whose
start-up (the city factory) raises reports that error with its first task. Shards finished before
are journalled by the caller, so rerunning the same command continues.
"""

from __future__ import annotations

import dataclasses
import hashlib
import multiprocessing as mp
import os
import signal
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from benchmark.data.camera_effects import apply_camera_effects
from benchmark.data.format import DatasetError, atomic_write_bytes, npy_bytes, shard_name
from benchmark.data.profiles import DataProfile


@dataclass
class RenderContext:
    """What rendering needs. ``cities`` is rebuilt in each worker by ``city_factory``."""

    root: Path
    profile: DataProfile
    seed: int
    cities: dict[tuple[str, str], Any]
    uav: pd.DataFrame
    sat: pd.DataFrame


_CTX: RenderContext | None = None
_INIT_ERROR: str | None = None  # why this worker's start-up failed (reported by its tasks)


class RenderWorkerError(DatasetError):
    """A render worker died or could not start: the dataset is incomplete (finished shards are
    journalled and kept; rerunning the same command renders the rest)."""


def _single_thread() -> None:
    """One thread per worker for numba/OpenMP/BLAS/cv2/torch: parallelism comes from processes."""
    os.environ.update(OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", NUMBA_NUM_THREADS="1")
    import cv2
    import torch

    cv2.setNumThreads(1)
    torch.set_num_threads(1)


def _worker_init(
    root: Path,
    profile: DataProfile,
    seed: int,
    city_factory: Callable[[], dict[tuple[str, str], Any]],
    uav: pd.DataFrame,
    sat: pd.DataFrame,
) -> None:
    global _CTX, _INIT_ERROR
    _single_thread()  # before the factory imports numba (it reads NUMBA_NUM_THREADS once)
    try:
        _CTX = RenderContext(root, profile, seed, city_factory(), uav, sat)
    except (
        Exception
    ) as err:  # sent back with the first task (a raising initializer breaks the pool)
        _INIT_ERROR = f"{type(err).__name__}: {err}"


def render_uav_rows(ctx: RenderContext, rows: pd.DataFrame) -> np.ndarray:
    """Render UAV samples; uint8 ``(n, S, S, 3)``. Each row's own seed drives its camera effects;
    its columns ``light`` and ``visibility_m`` (written by the plan) its illumination state and
    haze."""
    from benchmark.sim import Camera, render_uav, sample_seed

    p = ctx.profile
    camera = Camera(p.image_size, p.image_size, p.fov_deg)
    out = np.empty((len(rows), p.image_size, p.image_size, 3), np.uint8)
    for j, r in enumerate(rows.itertuples(index=False)):
        img = render_uav(
            ctx.cities[(r.city, "now")],
            np.array([r.E, r.N, r.U]),
            r.yaw,
            r.pitch,
            r.roll,
            camera,
            supersample=p.supersample,
            light=int(r.light),
            visibility_m=float(r.visibility_m),
        )
        if r.camera_effects:
            img = apply_camera_effects(
                img, np.random.default_rng(sample_seed(ctx.seed, r.uav_index))
            )
        out[j] = img
    return out


def render_sat_rows(ctx: RenderContext, rows: pd.DataFrame) -> np.ndarray:
    """Render satellite images; uint8 ``(n, S, S, 3)``, each under its row's ``light``."""
    from benchmark.sim import render_satellite

    p = ctx.profile
    out = np.empty((len(rows), p.image_size, p.image_size, 3), np.uint8)
    for j, r in enumerate(rows.itertuples(index=False)):
        out[j] = render_satellite(
            ctx.cities[(r.city, r.variant)],
            (r.E, r.N),
            height_m=r.height_m,
            footprint_m=(r.footprint_E_m, r.footprint_N_m),
            size=p.image_size,
            light=int(r.light),
        )
    return out


def _shard_rows(table: pd.DataFrame, k: int, size: int) -> pd.DataFrame:
    return table.iloc[k * size : (k + 1) * size]


def shard_size(kind: str, p: DataProfile) -> int:
    """Images per shard; satellite shards are small so their costly renders spread out."""
    return p.shard_size if kind == "uav" else p.sat_shard_size


def _shard_shape(kind: str, n_rows: int, k: int, p: DataProfile) -> tuple[int, int, int, int]:
    size = shard_size(kind, p)
    return (min(size, n_rows - k * size), p.image_size, p.image_size, 3)


@dataclass(frozen=True)
class ShardResult:
    """One rendered shard: ``n`` images, ``sha256`` and ``bytes`` of its .npy as rendered,
    ``status`` ``"new"`` / ``"same"`` / ``"replaced"`` (what the path held before)."""

    kind: str
    k: int
    n: int
    sha256: str
    bytes: int
    status: str


def _run_task(task: tuple[str, int]) -> ShardResult:
    if _INIT_ERROR is not None:
        raise RenderWorkerError(f"render worker {os.getpid()} could not start: {_INIT_ERROR}")
    ctx = _CTX
    assert ctx is not None, "worker context not set"
    kind, k = task
    if kind == "warmup":  # one tiny frame: loads the renderer's compiled code in this process
        tiny = dataclasses.replace(ctx, profile=dataclasses.replace(ctx.profile, image_size=8))
        render_uav_rows(tiny, ctx.uav.iloc[:1])
        time.sleep(0.05)  # let the other workers take the remaining warm-up tasks
        return ShardResult(kind, os.getpid(), 0, "", 0, "warmup")
    table = ctx.uav if kind == "uav" else ctx.sat
    rows = _shard_rows(table, k, shard_size(kind, ctx.profile))
    images = render_uav_rows(ctx, rows) if kind == "uav" else render_sat_rows(ctx, rows)
    data = npy_bytes(images)
    path = ctx.root / shard_name(kind, k)
    status = "new"
    if path.is_file():
        status = "same" if path.read_bytes() == data else "replaced"
    if status != "same":
        atomic_write_bytes(path, data)
    return ShardResult(kind, k, len(rows), hashlib.sha256(data).hexdigest(), len(data), status)


class RenderPool:
    """Worker processes that render shards of one ``RenderContext`` (``with RenderPool(...) as p``).

    With ``workers > 1`` and a picklable ``city_factory`` (returning ``ctx.cities``, normally by
    loading them from the city cache, which memory-maps them) the workers are *spawned*, not
    forked: a forked child deadlocks in OpenCV's or OpenMP's thread pool when the parent used it
    before forking. Otherwise the shards are rendered in this process.
    """

    def __init__(
        self,
        ctx: RenderContext,
        workers: int,
        city_factory: Callable[[], dict[tuple[str, str], Any]] | None = None,
    ) -> None:
        self.ctx = ctx
        self.workers = workers if city_factory is not None else 1
        self._factory = city_factory
        self._pool: ProcessPoolExecutor | None = None
        self._procs: dict[int, Any] = {}  # pid -> Process, kept to name a dead worker

    def __enter__(self) -> RenderPool:
        if self.workers > 1:
            c = self.ctx
            initargs = (c.root, c.profile, c.seed, self._factory, c.uav, c.sat)
            self._pool = ProcessPoolExecutor(
                self.workers,
                mp_context=mp.get_context("spawn"),
                initializer=_worker_init,
                initargs=initargs,
            )
        return self

    def __exit__(self, *exc: object) -> None:
        pool, self._pool = self._pool, None
        if pool is not None:
            # Workers still rendering (an error or Ctrl-C in the caller) are stopped, not awaited.
            for proc in list(self._processes(pool).values()):
                if proc.is_alive():
                    proc.terminate()
            pool.shutdown(wait=True, cancel_futures=True)

    @staticmethod
    def _processes(pool: ProcessPoolExecutor) -> dict[int, Any]:
        return dict(getattr(pool, "_processes", None) or {})  # CPython's pid -> Process map

    def _dead_workers(self) -> str:
        """``"pid 123 killed by SIGKILL, ..."`` for the workers that ended abnormally."""
        # The pool's manager thread notices the death before the dead process is reaped; on a
        # loaded machine that can take seconds, so poll (returns at once when an exit code is in).
        deadline = time.monotonic() + 10.0
        while True:
            found = []
            for pid, proc in sorted(self._procs.items()):
                proc.join(timeout=0.2)
                code = proc.exitcode
                if code is None or code == 0:
                    continue
                if code < 0:
                    try:
                        found.append(f"pid {pid} killed by {signal.Signals(-code).name}")
                    except ValueError:
                        found.append(f"pid {pid} killed by signal {-code}")
                else:
                    found.append(f"pid {pid} exited with code {code}")
            if found or time.monotonic() > deadline:
                return ", ".join(found) or "a worker ended abnormally"

    def imap(self, tasks: list[tuple[str, int]]) -> Iterator[ShardResult]:
        """Render and write ``tasks`` (``("uav"|"sat", k)``); yields a ShardResult as each ends.
        A worker that dies raises :class:`RenderWorkerError` (never a hang)."""
        global _CTX
        if self._pool is not None:
            futures = [self._pool.submit(_run_task, t) for t in tasks]
            self._procs.update(self._processes(self._pool))
            try:
                for future in as_completed(futures):
                    self._procs.update(self._processes(self._pool))
                    yield future.result()
            except BrokenProcessPool as err:
                dead = self._dead_workers()
                oom = "; the out-of-memory killer sends SIGKILL" if "SIGKILL" in dead else ""
                raise RenderWorkerError(
                    f"a render worker process died ({dead}{oom}) while rendering into "
                    f"{self.ctx.root}; rerun the same command (finished shards are kept), with "
                    "fewer workers if memory is short"
                ) from err
            return
        _CTX = self.ctx
        try:
            for task in tasks:
                yield _run_task(task)
        finally:
            _CTX = None

    def warm_up(self) -> None:
        """Wait until every worker has loaded the cities and the compiled renderer."""
        seen: set[int] = set()
        for _ in range(200):  # a worker still starting takes no task; ask again until all answer
            seen |= {r.k for r in self.imap([("warmup", k) for k in range(self.workers)])}
            if len(seen) >= self.workers:
                return
