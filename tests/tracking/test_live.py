"""Live logging from worker processes (issue 12): two spawned workers write to ONE embedded
sqlite store at once (the same dataset input, a metric per epoch sent at once), and every point
arrives without a fallback; experiment kind and description, run descriptions, real start and end
times, continued runs and dataset inputs behave alike on the MLflow, local and null trackers."""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import time

import pytest

from benchmark.tracking import (
    DatasetRef,
    LocalTracker,
    NullTracker,
    TrackerSpec,
    create_tracker,
    tracker_from_spec,
)

EPOCHS = 40
DATASET = DatasetRef("ds", "ab" * 32, "/data/ds", "standard/train")


def log_like_a_worker(spec: TrackerSpec, name: str) -> tuple[str, bool]:
    """What a reproduce worker does: open a run, log the dataset, one flush per epoch."""
    tracker = tracker_from_spec(spec)
    with tracker.start_run("training", name, tags={"run_key": name}) as run:
        run.log_input(DATASET)
        for epoch in range(1, EPOCHS + 1):
            run.log_metrics({"train_loss_total": 1.0 / epoch, "lr": 1e-3}, step=epoch)
            run.flush()
    return run.run_id, bool(getattr(tracker, "using_fallback", False))


def test_two_workers_on_one_sqlite_store(tmp_path):
    from mlflow.tracking import MlflowClient

    tracker = create_tracker("mlflow", workdir=tmp_path)
    tracker.describe_experiment("training", "two workers at once")  # the parent's part
    ctx = multiprocessing.get_context("spawn")
    with cf.ProcessPoolExecutor(2, mp_context=ctx) as pool:
        done = list(pool.map(log_like_a_worker, [tracker.spec()] * 2, ["w0", "w1"]))
    assert [fell_back for _, fell_back in done] == [False, False]
    assert not (tmp_path / "tracking-fallback").exists()
    client = MlflowClient(tracker.uri)
    for run_id, _ in done:
        run = client.get_run(run_id)
        assert run.info.status == "FINISHED"
        history = client.get_metric_history(run_id, "train_loss_total")
        assert sorted(m.step for m in history) == list(range(1, EPOCHS + 1))
        (inp,) = run.inputs.dataset_inputs
        assert inp.dataset.digest == DATASET.digest[:32]  # MLflow keeps at most 36 characters


@pytest.mark.parametrize("kind", ["mlflow", "local"])
def test_times_descriptions_inputs_and_continued_runs(tmp_path, kind):
    tracker = create_tracker(kind, workdir=tmp_path)
    tracker.describe_experiment("exp", "what this table is")
    start = int(time.time() * 1000) - 60_000  # the work began a minute ago
    run = tracker.start_run("exp", "row", tags={"run_key": "k1"}, description="row 1, seed 0",
                            start_time_ms=start)  # fmt: skip
    run.log_input(DATASET)
    run.log_metrics({"loss": 2.0}, step=1)
    run.end("KILLED")
    (info,) = tracker.find_runs("exp", "k1")
    assert info.status == "KILLED" and info.start_time_ms == start
    assert info.end_time_ms - info.start_time_ms >= 60_000
    assert info.tags["mlflow.note.content"] == "row 1, seed 0"
    # A later invocation continues the same run: start kept, status RUNNING, then FINISHED.
    again = create_tracker(kind, workdir=tmp_path)
    continued = again.attach(again.find_runs("exp", "k1")[0], reopen=True)
    assert again.find_runs("exp", "k1", ("RUNNING",))[0].run_id == info.run_id
    continued.log_metrics({"loss": 1.0}, step=2)
    continued.end()
    (final,) = again.find_runs("exp", "k1")
    assert final.status == "FINISHED" and final.start_time_ms == start
    assert final.metrics["loss"] == 1.0
    assert again.find_finished_run("exp", "k1").run_id == info.run_id
    if kind == "mlflow":
        from mlflow.tracking import MlflowClient

        client = MlflowClient(tracker.uri)
        exp = client.get_experiment_by_name("exp")
        (inp,) = client.get_run(info.run_id).inputs.dataset_inputs
        assert {t.key: t.value for t in inp.tags}["mlflow.data.context"] == "standard/train"
    else:
        assert isinstance(tracker, LocalTracker)
        exp_tags = tracker.experiment_tags("exp")
        exp = type("Exp", (), {"tags": exp_tags})
        run_json = (tmp_path / "tracking-local" / "exp" / info.run_id / "run.json").read_text()
        assert '"context": "standard/train"' in run_json
    assert exp.tags["mlflow.experimentKind"] == "custom_model_development"
    assert exp.tags["mlflow.note.content"] == "what this table is"


def test_empty_tags_are_refused_and_null_tracker_does_everything(tmp_path):
    with pytest.raises(ValueError, match="empty tag"):
        NullTracker().start_run("exp", "row", tags={"x": ""})
    null = NullTracker()
    null.describe_experiment("exp", "nothing stored")
    with null.start_run("exp", "row", description="d", start_time_ms=0) as run:
        run.log_input(DATASET)
        with run.system_metrics(0.1):
            run.log_metrics({"a": 1.0}, step=1)
        assert run.log_model(object(), None) == ""
    assert run.status.value == "FINISHED" and run.start_time_ms == 0
    assert null.find_runs("exp") == [] and tracker_from_spec(null.spec()) is not None
