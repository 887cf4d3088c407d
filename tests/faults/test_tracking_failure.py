"""Issue 14, item 5 (tracking side): a FAILED run carries its reason in MLflow, as the tag
``failure_reason`` and below its description in the run's note."""

from __future__ import annotations

import pytest
from mlflow.tracking import MlflowClient

from benchmark.tracking import (
    DESCRIPTION_TAG,
    FAILURE_REASON_TAG,
    LocalTracker,
    MlflowTracker,
    RunStatus,
)
from benchmark.tracking.records import MAX_TAG_VALUE


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("failure-store")
    tracker = MlflowTracker(f"sqlite:///{tmp / 'mlflow.db'}", fallback_dir=tmp / "fb")
    return tracker, MlflowClient(tracker.uri)


def test_an_exception_fails_the_run_with_its_reason(store):
    tracker, client = store
    with pytest.raises(FloatingPointError):
        with tracker.start_run("t", "diverged", description="**Unit** euler/seed0") as run:
            run.log_metrics({"loss": 1.0}, 0)
            raise FloatingPointError("val_loss_total = inf at epoch 3")
    stored = client.get_run(run.run_id)
    assert stored.info.status == "FAILED"
    reason = "FloatingPointError: val_loss_total = inf at epoch 3"
    assert stored.data.tags[FAILURE_REASON_TAG] == reason
    assert stored.data.tags[DESCRIPTION_TAG] == f"**Unit** euler/seed0\n\n**FAILED**: {reason}"
    assert not tracker.using_fallback


def test_fail_with_an_explicit_reason(store):
    tracker, client = store
    with tracker.start_run("t", "explicit") as run:
        run.log_metrics({"loss": float("inf")}, 4)
        run.fail("non-finite train_loss_total = inf at step 4")
        run.fail("a second reason is ignored")  # the run has ended already
    stored = client.get_run(run.run_id)
    assert stored.info.status == "FAILED"  # the with block did not turn it FINISHED
    assert stored.data.tags[FAILURE_REASON_TAG] == "non-finite train_loss_total = inf at step 4"
    assert stored.data.tags[DESCRIPTION_TAG] == (
        "**FAILED**: non-finite train_loss_total = inf at step 4"
    )


def test_a_long_reason_is_cut_to_the_tag_limit(store):
    tracker, client = store
    description = "d" * 7900  # near the limit: the reason must still fit and be readable
    with tracker.start_run("t", "long", description=description) as run:
        run.fail("x" * 20000)
    tags = client.get_run(run.run_id).data.tags
    assert len(tags[FAILURE_REASON_TAG]) == MAX_TAG_VALUE
    assert tags[FAILURE_REASON_TAG].endswith("…")
    note = tags[DESCRIPTION_TAG]
    assert len(note) <= MAX_TAG_VALUE and note.startswith("ddd") and "**FAILED**: xxx" in note


def test_ctrl_c_is_killed_without_a_failure_reason(tmp_path):
    tracker = LocalTracker(tmp_path)
    with pytest.raises(KeyboardInterrupt):
        with tracker.start_run("t", "stopped") as run:
            raise KeyboardInterrupt
    assert run.status is RunStatus.KILLED and FAILURE_REASON_TAG not in run.tags
    (info,) = tracker.find_runs("t")
    assert info.status == "KILLED"


def test_a_multiline_exception_becomes_one_line(tmp_path):
    tracker = LocalTracker(tmp_path)
    with pytest.raises(RuntimeError):
        with tracker.start_run("t", "r"):
            raise RuntimeError("first line\n  second line")
    (info,) = tracker.find_runs("t")
    assert info.status == "FAILED"
    assert info.tags[FAILURE_REASON_TAG] == "RuntimeError: first line second line"
