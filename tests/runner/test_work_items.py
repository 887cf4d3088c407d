"""``execute.work_items`` run by the units' executor (``pool.run_work_items``): the report stage's
references and audit datasets as work items give the numbers of a run in this process, in the
pool and on Ray; an item that raises is an outcome with its error and the others go on."""

from __future__ import annotations

import importlib.util
import math

import cv2
import pandas as pd
import pytest
from test_reference_rows import oracle_spec

from benchmark.runner.execute import reference_rows as rr
from benchmark.runner.execute.audit import cue_dataset_items, cue_dataset_plan
from benchmark.runner.execute.pool import ExecutorConfig, run_work_items
from benchmark.runner.execute.work_items import ItemOutcome, WorkItem, item_entries, run_item

HAVE_RAY = importlib.util.find_spec("ray") is not None
STD = "standard/test"


# Library functions, not this module's: a Ray worker imports a function by its module, and
# this test module is not importable there. math.sqrt refuses a negative number (ValueError).
VALUES = (0.0, 1.0, 4.0, -1.0, 9.0, 16.0)
ROOTS = {"k0": 0.0, "k1": 1.0, "k2": 2.0, "k4": 3.0, "k5": 4.0}


def _refuses_three(x: int) -> int:
    if x == 3:
        raise ValueError(f"three is refused\nsecond line of {x}")
    return x


def items_of(fn, values) -> list[WorkItem]:
    return [WorkItem(f"k{i}", f"value {v}", fn, v) for i, v in enumerate(values)]


def run_all(config: ExecutorConfig, items: list[WorkItem]) -> dict[str, ItemOutcome]:
    got: dict[str, ItemOutcome] = {}
    run_work_items(config, items, lambda item, outcome: got.__setitem__(item.key, outcome), True)
    return got


class TestRunItem:
    def test_value_and_time(self):
        outcome = run_item(WorkItem("a", "a", math.sqrt, 49.0))
        assert outcome.ok and outcome.value == 7.0 and outcome.seconds >= 0

    def test_an_exception_is_the_outcome_type_and_first_line(self):
        outcome = run_item(WorkItem("a", "a", _refuses_three, 3))
        assert not outcome.ok and outcome.value is None
        assert outcome.error == "ValueError: three is refused"

    def test_opencv_threads_restored(self):
        before = cv2.getNumThreads()
        cv2.setNumThreads(3)
        try:
            run_item(WorkItem("a", "a", math.sqrt, 2.0))
            assert cv2.getNumThreads() == 3
        finally:
            cv2.setNumThreads(before)

    def test_duplicate_keys_refused(self):
        with pytest.raises(ValueError, match="unique"):
            item_entries([WorkItem("a", "a", math.sqrt, 1.0), WorkItem("a", "b", math.sqrt, 2.0)])


class TestRunWorkItemsPool:
    @pytest.mark.parametrize("workers", [1, 2])
    def test_every_item_once_and_the_error_kept(self, workers):
        got = run_all(ExecutorConfig(workers=workers), items_of(math.sqrt, VALUES))
        assert sorted(got) == [f"k{i}" for i in range(len(VALUES))]
        assert got["k3"].error == "ValueError: math domain error"
        assert {k: got[k].value for k in ROOTS} == ROOTS

    def test_nothing_to_do(self):
        assert run_all(ExecutorConfig(workers=2), []) == {}


def reference_frames(smoke_dataset, tmp_path, config: ExecutorConfig | None) -> dict:
    """The oracle's evaluations as a reproduction runs them: planned, its chunks (a frame
    each) run by the executor of ``config`` (None: ``evaluate_references`` in this process)."""
    spec = oracle_spec(tmp_path)
    if config is None:
        return rr.evaluate_references([spec], smoke_dataset, None, "smoke", quiet=True).frames
    work = rr.plan_references([spec], smoke_dataset, None, "smoke", chunk_frames=1)
    items = work.items()
    assert len(items) > 2 and {i.data_root for i in items} == {str(smoke_dataset)}
    run_work_items(config, items, work.collect, True, label="references", unit="pair")
    return work.results().frames


def assert_same_frames(a: dict, b: dict) -> None:
    assert sorted(a) == sorted(b) and a
    for key in a:
        pd.testing.assert_frame_equal(a[key], b[key])


class TestReferencesAsWorkItems:
    def test_the_pool_gives_this_process_numbers(self, smoke_dataset, tmp_path):
        here = reference_frames(smoke_dataset, tmp_path, None)
        pooled = reference_frames(smoke_dataset, tmp_path, ExecutorConfig(workers=2))
        assert_same_frames(here, pooled)
        assert {k[2] for k in here} == {"true", "swap"} and ("geometry_oracle", STD, "true") in here

    @pytest.mark.skipif(not HAVE_RAY, reason='ray is not installed (pip install -e ".[ray]")')
    def test_ray_gives_this_process_numbers(self, smoke_dataset, tmp_path):
        here = reference_frames(smoke_dataset, tmp_path, None)
        on_ray = reference_frames(smoke_dataset, tmp_path, ExecutorConfig(kind="ray", workers=2))
        assert_same_frames(here, on_ray)

    @pytest.mark.skipif(not HAVE_RAY, reason='ray is not installed (pip install -e ".[ray]")')
    def test_ray_keeps_an_items_error(self):
        got = run_all(ExecutorConfig(kind="ray", workers=2), items_of(math.sqrt, VALUES))
        assert got["k3"].error == "ValueError: math domain error"
        assert {k: got[k].value for k in ROOTS} == ROOTS


class TestAuditDatasetsAsWorkItems:
    def test_one_item_per_missing_dataset_none_when_rendered(self, smoke_dataset, tmp_path):
        import shutil

        data = tmp_path / "quick-s0"
        shutil.copytree(smoke_dataset, data)
        items = cue_dataset_items(data, n_extra=2)
        plan = cue_dataset_plan(data, 2)
        assert [i.arg[0] for i in items] == [str(root) for root, _, _ in plan]
        assert {i.data_root for i in items} == {str(data)}
        got = run_all(ExecutorConfig(workers=2), items)
        assert all(o.ok for o in got.values()), got
        assert cue_dataset_items(data, n_extra=2) == []  # rendered: nothing left to do
        # the bytes of the audit's own render (simulate_dataset with 2 processes)
        from benchmark.data.writer import simulate_dataset

        root, profile, seed = plan[0]
        again = tmp_path / "again"
        simulate_dataset(again, profile, seed, workers=2, progress=False)
        assert (again / "manifest.json").read_text() == (root / "manifest.json").read_text()
