"""Work items: the report stage's work the executors run beside the training units (issue 41).

A training unit is one kind of work; the non-learned references' evaluations (in chunks of
frames) and the heading-cue audit's extra datasets are others. Each is a :class:`WorkItem`:
``fn(arg)`` with ``fn`` a module-level function (a pool pickles it by name), run where the
executor has room (a spawned process of the pool, or a Ray task on any node of a cluster: see
:func:`benchmark.runner.execute.pool.run_work_items`), its :class:`ItemOutcome` handed back to the
driver, which records it (a reference's CSV and record, nothing for a dataset: the task wrote it).

:func:`run_item` never raises: an item's exception comes back as its outcome's ``error``, so one
failing reference costs its own rows, not the others' (the units' contract, ``run_unit``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any


@dataclass(frozen=True)
class WorkItem:
    """``fn(arg)`` somewhere. ``key`` is unique among the items of one call; ``title`` names it on
    the progress line; ``size`` is its share of the progress (frames of a reference chunk, 1 for
    a dataset); ``data_root`` a dataset it reads (a Ray node must see the driver's, checked by
    its manifest's sha256 before the item runs; None: nothing to check)."""

    key: str
    title: str
    fn: Callable[[Any], Any]
    arg: Any
    size: int = 1
    data_root: str | None = None


@dataclass(frozen=True)
class ItemOutcome:
    """What running an item gave: its ``value`` (None on an error), the ``error`` ("" when it
    ran; one line otherwise: the exception, or why the executor lost the item) and the
    ``seconds`` it took where it ran."""

    value: Any = None
    error: str = ""
    seconds: float = 0.0

    @property
    def ok(self) -> bool:
        return not self.error


def run_item(item: WorkItem) -> ItemOutcome:
    """``item.fn(item.arg)`` as an outcome; never raises (an exception is the outcome's error:
    its type and the first line of its message). One OpenCV thread while it runs, as torch's
    (``worker_init``): two items at once on two cores (the caller's setting is restored)."""
    import cv2

    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    start = time.perf_counter()
    try:
        value = item.fn(item.arg)
    except Exception as err:  # this item's failure; the executor carries on with the rest
        first = (str(err).strip().splitlines() or [""])[0][:300]
        return ItemOutcome(None, f"{type(err).__name__}: {first}", time.perf_counter() - start)
    finally:
        cv2.setNumThreads(threads)
    return ItemOutcome(value, "", time.perf_counter() - start)


@dataclass(frozen=True)
class Entry:
    """One thing an executor runs, as its loops see it: ``handle`` goes back to ``on_done``
    (a ``Unit``, a :class:`WorkItem`), ``payload`` to the function the executor runs (a
    ``UnitTask`` for ``run_unit``, the item for :func:`run_item`); ``name`` for the progress and
    Ray's task list, ``size`` its progress share, ``data_root`` checked on a Ray node, and
    ``heartbeat_dir`` where a unit's worker writes its epochs (None: no heartbeat)."""

    handle: Any
    payload: Any
    name: str
    size: int = 1
    data_root: str | None = None
    heartbeat_dir: Path | None = None


def item_entries(items: list[WorkItem]) -> list[Entry]:
    """The executors' view of ``items`` (duplicate keys refused: on_done could not tell them
    apart)."""
    keys = [item.key for item in items]
    if len(set(keys)) != len(keys):
        raise ValueError(f"work item keys must be unique, got {len(keys) - len(set(keys))} repeats")
    return [Entry(item, item, item.title, item.size, item.data_root) for item in items]
