"""Independent work items of the report stage in a spawn pool: ``map_work``.

The units have their executor (``execute.pool``, ``execute.ray_executor``); the report stage's
smaller items (a non-learned row fused along a split, a table's intervals) run here, each a
function of its item and of a state sent once per process. The results are the same in any order
and with any number of workers: each item computes alone, and they come back in item order.
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

from benchmark.progress import Progress
from benchmark.runner.execute.pool import stop_pool
from benchmark.runner.execute.worker import worker_init

Item = TypeVar("Item")
Result = TypeVar("Result")


def _start(initializer: Callable[..., None] | None, initargs: tuple[Any, ...]) -> None:
    worker_init()
    if initializer is not None:
        initializer(*initargs)


def map_work(
    fn: Callable[[Item], Result],
    items: Sequence[Item],
    workers: int,
    *,
    label: str,
    name: Callable[[Item], str] = str,
    quiet: bool = False,
    initializer: Callable[..., None] | None = None,
    initargs: tuple[Any, ...] = (),
) -> list[Result]:
    """``[fn(item) for item in items]``, in item order: inline (``workers <= 1`` or one item;
    ``initializer(*initargs)`` called first) or in a spawn pool of ``workers`` processes, each
    started by ``worker_init`` (one thread, SIGINT ignored) and ``initializer(*initargs)`` (the
    state every item reads, pickled once per process rather than once per item). ``fn`` and
    ``initializer`` are module-level functions (the pool pickles them by name). A progress line
    ``label`` names each finished item (``name(item)``). An item that raises stops the pool and
    raises here."""
    results: list[Any] = [None] * len(items)
    with Progress(len(items), label, unit="item", enabled=not quiet) as bar:
        if workers <= 1 or len(items) <= 1:
            if initializer is not None:
                initializer(*initargs)
            for i, item in enumerate(items):
                results[i] = fn(item)
                bar.update(1, postfix=name(item))
            return results
        ctx = multiprocessing.get_context("spawn")
        pool = cf.ProcessPoolExecutor(
            workers, mp_context=ctx, initializer=_start, initargs=(initializer, initargs)
        )
        try:
            futures = {pool.submit(fn, item): i for i, item in enumerate(items)}
            for future in cf.as_completed(futures):
                i = futures[future]
                results[i] = future.result()
                bar.update(1, postfix=name(items[i]))
        except BaseException:
            stop_pool(pool)
            raise
        pool.shutdown(wait=True)
    return results
