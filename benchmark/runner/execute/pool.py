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

from benchmark.progress import Progress
from benchmark.runner.execute.worker import UnitTask, run_unit, worker_init
from benchmark.runner.plan.units import Unit


def execute_units(todo: list[tuple[Unit, UnitTask]], jobs: int, on_done, quiet: bool) -> None:
    """Run tasks inline (``jobs == 1``) or in a spawn pool; ``on_done(unit, result)`` in order of
    completion, in this process.

    Ctrl-C: pool workers ignore SIGINT (``execute.worker_init``); this process stops them
    (SIGTERM) and re-raises, so the user sees one message, not a traceback per worker."""
    with Progress(len(todo), "reproduce", unit="run", enabled=not quiet) as bar:
        if jobs == 1 or len(todo) <= 1:
            for unit, task in todo:
                bar.update(0, postfix=f"running {unit.title}")
                on_done(unit, run_unit(task))
                bar.update(1, postfix=f"done {unit.title}")
            return
        ctx = multiprocessing.get_context("spawn")
        pool = cf.ProcessPoolExecutor(jobs, mp_context=ctx, initializer=worker_init)
        try:
            # Workers are spawned by submit; started with SIGINT ignored (kept across exec, and
            # then Python installs no KeyboardInterrupt handler) they cannot print a traceback
            # even while still importing, before worker_init runs.
            previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
            try:
                futures = {pool.submit(run_unit, task): unit for unit, task in todo}
            finally:
                signal.signal(signal.SIGINT, previous)
            for future in cf.as_completed(futures):
                unit = futures[future]
                on_done(unit, future.result())
                bar.update(1, postfix=f"done {unit.title}")
        except BaseException:
            _stop_pool(pool)
            raise
        pool.shutdown(wait=True)


def _stop_pool(pool: cf.ProcessPoolExecutor) -> None:
    """Cancel what has not started and terminate the workers (they may be mid-training)."""
    processes = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        if process.is_alive():
            process.terminate()
    for process in processes:
        process.join(timeout=10)
