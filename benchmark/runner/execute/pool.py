"""The default executor of ``uavbench reproduce``: a local pool of spawned worker processes.

The contract every executor keeps (see also :mod:`benchmark.runner.execute.ray_executor`): ``todo``
holds ``(unit, UnitTask)`` pairs; each task runs :func:`benchmark.runner.execute.worker.run_unit`
somewhere and ``on_done(unit, UnitResult)`` is called in this (driver) process, in order of
completion. Work items (``execute.work_items``: the references' chunks, the audit's datasets)
go the same way through :func:`run_work_items`: ``on_done(item, ItemOutcome)``.
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from benchmark.errors import InputError
from benchmark.progress import Progress
from benchmark.runner.execute import heartbeat
from benchmark.runner.execute.ray_executor import (
    check_ray_tracking,
    execute_items_ray,
    execute_units_ray,
    import_ray,
    resolve_resources,
)
from benchmark.runner.execute.work_items import Entry, ItemOutcome, WorkItem, item_entries, run_item
from benchmark.runner.execute.worker import UnitResult, UnitTask, run_unit, worker_init
from benchmark.runner.plan.units import Unit

EXECUTORS = ("pool", "ray")
OnDone = Callable[[Unit, UnitResult], None]


@dataclass(frozen=True)
class ExecutorConfig:
    """Where the units run (``uavbench reproduce --executor ...``).

    ``workers`` units train at once on this machine (``--workers``, processes) with either
    executor. The Ray-only fields are None when not given (defaults in ``ray_executor``), so a
    pool run that sets one is refused rather than silently ignored."""

    kind: str = "pool"  # one of EXECUTORS
    workers: int = 2
    ray_address: str | None = None  # None: a local Ray started for the run
    cpus_per_unit: float | None = None
    gpus_per_unit: float | None = None
    max_retries: int | None = None


RAY_ONLY_FIELDS = ("ray_address", "cpus_per_unit", "gpus_per_unit", "max_retries")


def check_executor(config: ExecutorConfig, tracking_uri: str | None) -> None:
    """Refuse a bad executor choice before any work is done (a dataset rendered, a unit
    planned): an unknown kind, Ray-only fields without ``kind="ray"``, Ray not installed,
    resources out of range, a node-local tracking store (``tracking_uri``: where the units will
    log; None: nothing is logged) with a cluster."""
    if config.kind not in EXECUTORS:
        raise InputError(f"executor must be one of {EXECUTORS}, got {config.kind!r}")
    if config.kind != "ray":
        given = [name for name in RAY_ONLY_FIELDS if getattr(config, name)]
        if given:
            raise InputError(f"executor {', '.join(given)} only apply to kind 'ray'")
        return
    import_ray()
    resolve_resources(config.cpus_per_unit, config.gpus_per_unit, config.max_retries)
    check_ray_tracking(config.ray_address, tracking_uri)


def run_executor(
    config: ExecutorConfig,
    todo: list[tuple[Unit, UnitTask]],
    on_done: OnDone,
    quiet: bool,
    tracking_uri: str | None,
) -> None:
    """Run ``todo`` with the executor ``config`` chose. ``tracking_uri`` is where the units log
    (the tracker's resolved URI; None when nothing is logged)."""
    check_executor(config, tracking_uri)
    if config.kind == "pool":
        execute_units(todo, config.workers, on_done, quiet)
        return
    cpus, gpus, retries = resolve_resources(
        config.cpus_per_unit, config.gpus_per_unit, config.max_retries
    )
    local = config.ray_address is None or config.ray_address == "local"
    execute_units_ray(
        todo,
        on_done,
        quiet,
        address=config.ray_address,
        cpus_per_unit=cpus,
        gpus_per_unit=gpus,
        max_retries=retries,
        # workers means the same for both executors: units training at once on this machine
        num_cpus=max(1, round(config.workers * cpus)) if local else None,
    )


def run_work_items(
    config: ExecutorConfig,
    items: list[WorkItem],
    on_done: Callable[[WorkItem, ItemOutcome], None],
    quiet: bool,
    *,
    label: str = "work",
    unit: str = "item",
) -> None:
    """Run ``items`` with the executor ``config`` chose, as the units run: ``workers`` processes
    of the pool, or Ray tasks (a local Ray, or the cluster at ``ray_address``: each item then
    runs on whichever node has room, and must find its files on a shared file system).
    ``on_done(item, outcome)`` here, in order of completion; an item that raises is an outcome
    with its error, and the others go on."""
    if not items:
        return
    if config.kind == "pool":
        execute_items(items, config.workers, on_done, quiet, label, unit)
        return
    # An item needs no GPU (references and rendering run on CPUs): the GPUs stay with the units.
    cpus, _, retries = resolve_resources(
        config.cpus_per_unit, config.gpus_per_unit, config.max_retries
    )
    local = config.ray_address is None or config.ray_address == "local"
    execute_items_ray(items, on_done, quiet, address=config.ray_address, cpus_per_item=cpus,
                      max_retries=retries, label=label, unit=unit,
                      num_cpus=max(1, round(config.workers * cpus)) if local else None)  # fmt: skip


def execute_units(
    todo: list[tuple[Unit, UnitTask]], workers: int, on_done: OnDone, quiet: bool
) -> None:
    """Run tasks inline (``workers == 1``) or in a spawn pool; ``on_done(unit, result)`` in order of
    completion, in this process. While none completes, the progress line names the units being
    trained and their epoch (their heartbeats)."""
    entries = [Entry(unit, task, unit.title, data_root=str(task.cfg.data.root),
                     heartbeat_dir=task.unit_dir) for unit, task in todo]  # fmt: skip
    _pool_loop(entries, run_unit, workers, on_done, quiet, "reproduce", "run")


def execute_items(
    items: list[WorkItem],
    workers: int,
    on_done: Callable[[WorkItem, ItemOutcome], None],
    quiet: bool,
    label: str = "work",
    unit: str = "item",
) -> None:
    """Run work items inline (``workers == 1``) or in a spawn pool of ``workers`` processes;
    ``on_done(item, outcome)`` in order of completion, in this process; the progress counts
    the items' sizes in ``unit``."""
    _pool_loop(item_entries(items), run_item, workers, on_done, quiet, label, unit)


def _pool_loop(
    entries: list[Entry],
    fn: Callable[[Any], Any],
    workers: int,
    on_done: Callable[[Any, Any], None],
    quiet: bool,
    label: str,
    unit: str,
) -> None:
    """``on_done(entry.handle, fn(entry.payload))`` for every entry, inline or in a spawn pool.

    Ctrl-C: pool workers ignore SIGINT (``execute.worker_init``); this process stops them
    (SIGTERM) and re-raises, so the user sees one message, not a traceback per worker."""
    total = sum(e.size for e in entries)
    with Progress(total, label, unit=unit, enabled=not quiet) as bar:
        if workers == 1 or len(entries) <= 1:
            for entry in entries:
                bar.update(0, postfix=f"running {entry.name}")
                on_done(entry.handle, fn(entry.payload))
                bar.update(entry.size, postfix=f"done {entry.name}")
            return
        ctx = multiprocessing.get_context("spawn")
        pool = cf.ProcessPoolExecutor(workers, mp_context=ctx, initializer=worker_init)
        try:
            # Workers are spawned by submit; started with SIGINT ignored (kept across exec, and
            # then Python installs no KeyboardInterrupt handler) they cannot print a traceback
            # even while still importing, before worker_init runs.
            previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
            submitted = time.time()
            try:
                futures = {pool.submit(fn, entry.payload): entry for entry in entries}
            finally:
                signal.signal(signal.SIGINT, previous)
            _wait_reporting(futures, on_done, bar, submitted)
        except BaseException:
            stop_pool(pool)
            raise
        pool.shutdown(wait=True)


def _wait_reporting(
    futures: dict[cf.Future, Entry],
    on_done: Callable[[Any, Any], None],
    bar: Progress,
    submitted: float,
) -> None:
    """``on_done`` for each future as it completes; while none completes, every
    ``heartbeat.POLL_S`` the progress line names the units being trained and their epoch
    (``heartbeat.running_status`` of the heartbeats written since ``submitted``, a
    ``time.time()`` taken before the futures were submitted), drawn when that changed."""
    line = heartbeat.RunningLine(bar, since=submitted)
    pending = set(futures)
    while pending:
        done, pending = cf.wait(pending, timeout=heartbeat.POLL_S, return_when=cf.FIRST_COMPLETED)
        for future in done:
            entry = futures[future]
            on_done(entry.handle, future.result())
            bar.update(entry.size, postfix=f"done {entry.name}")
        line.show([(futures[f].name, futures[f].heartbeat_dir) for f in pending
                   if futures[f].heartbeat_dir is not None])  # fmt: skip


def stop_pool(pool: cf.ProcessPoolExecutor) -> None:
    """Cancel what has not started and terminate the workers (they may be mid-training)."""
    processes = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        if process.is_alive():
            process.terminate()
    for process in processes:
        process.join(timeout=10)
