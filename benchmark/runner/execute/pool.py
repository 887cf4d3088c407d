"""The default executor of ``uavbench reproduce``: a local pool of spawned worker processes.

The contract every executor keeps (see also :mod:`benchmark.runner.execute.ray_executor`): ``todo``
holds ``(unit, UnitTask)`` pairs; each task runs :func:`benchmark.runner.execute.worker.run_unit`
somewhere and ``on_done(unit, UnitResult)`` is called in this (driver) process, in order of
completion.
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass

from benchmark.errors import InputError
from benchmark.progress import Progress
from benchmark.runner.execute import heartbeat
from benchmark.runner.execute.ray_executor import (
    check_ray_tracking,
    execute_units_ray,
    import_ray,
    resolve_resources,
)
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


def execute_units(
    todo: list[tuple[Unit, UnitTask]], workers: int, on_done: OnDone, quiet: bool
) -> None:
    """Run tasks inline (``workers == 1``) or in a spawn pool; ``on_done(unit, result)`` in order of
    completion, in this process.

    Ctrl-C: pool workers ignore SIGINT (``execute.worker_init``); this process stops them
    (SIGTERM) and re-raises, so the user sees one message, not a traceback per worker."""
    with Progress(len(todo), "reproduce", unit="run", enabled=not quiet) as bar:
        if workers == 1 or len(todo) <= 1:
            for unit, task in todo:
                bar.update(0, postfix=f"running {unit.title}")
                on_done(unit, run_unit(task))
                bar.update(1, postfix=f"done {unit.title}")
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
                futures = {pool.submit(run_unit, task): unit for unit, task in todo}
            finally:
                signal.signal(signal.SIGINT, previous)
            _wait_reporting(futures, on_done, bar, [task for _, task in todo], submitted)
        except BaseException:
            stop_pool(pool)
            raise
        pool.shutdown(wait=True)


def _wait_reporting(
    futures: dict[cf.Future, Unit],
    on_done: OnDone,
    bar: Progress,
    tasks: list[UnitTask],
    submitted: float,
) -> None:
    """``on_done`` for each future as it completes; while none completes, every
    ``heartbeat.POLL_S`` the progress line names the units being trained and their epoch
    (``heartbeat.running_status`` of the heartbeats written since ``submitted``, a
    ``time.time()`` taken before the futures were submitted), drawn when that changed."""
    line = heartbeat.RunningLine(bar, since=submitted)
    dirs = {task.key: task.unit_dir for task in tasks}
    pending = set(futures)
    while pending:
        done, pending = cf.wait(pending, timeout=heartbeat.POLL_S, return_when=cf.FIRST_COMPLETED)
        for future in done:
            unit = futures[future]
            on_done(unit, future.result())
            bar.update(1, postfix=f"done {unit.title}")
        line.show([(futures[f].title, dirs[futures[f].key]) for f in pending])


def stop_pool(pool: cf.ProcessPoolExecutor) -> None:
    """Cancel what has not started and terminate the workers (they may be mid-training)."""
    processes = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        if process.is_alive():
            process.terminate()
    for process in processes:
        process.join(timeout=10)
