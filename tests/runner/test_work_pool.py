"""``execute.work_pool.map_work``: the report stage's work items give the same results in item
order, inline and in a spawn pool, and read the state their process was started with."""

from __future__ import annotations

import os

import pytest

from benchmark.runner.execute.work_pool import map_work

_STATE: dict = {}


def _remember(value: int) -> None:
    _STATE["offset"] = value


def _shifted(item: int) -> tuple[int, int]:
    """The item plus the process's offset, and the process id (which worker ran it)."""
    return item + _STATE["offset"], os.getpid()


def _fails_on_three(item: int) -> int:
    if item == 3:
        raise ValueError(f"item {item} cannot be computed")
    return item


class TestMapWork:
    @pytest.mark.parametrize("workers", [1, 2])
    def test_results_in_item_order_with_the_state(self, workers):
        items = list(range(12))
        out = map_work(_shifted, items, workers, label="test", quiet=True,
                       initializer=_remember, initargs=(100,))  # fmt: skip
        assert [value for value, _ in out] == [i + 100 for i in items]
        pids = {pid for _, pid in out}
        if workers == 1:
            assert pids == {os.getpid()}  # inline: this process
        else:
            assert os.getpid() not in pids  # spawned workers computed every item

    @pytest.mark.parametrize("workers", [1, 2])
    def test_a_failing_item_raises_here(self, workers):
        with pytest.raises(ValueError, match="item 3 cannot be computed"):
            map_work(_fails_on_three, list(range(6)), workers, label="test", quiet=True)

    def test_no_items(self):
        assert map_work(_shifted, [], 2, label="test", quiet=True) == []
