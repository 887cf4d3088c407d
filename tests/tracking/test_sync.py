"""``uavbench sync``: local runs copied into a sqlite store completely, once, parents first.

The reference of every comparison is what the test logged (the runs' in-memory records,
``Run.metrics`` with each point's step and timestamp), not the local files sync reads.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from mlflow.entities import ViewType
from mlflow.tracking import MlflowClient

from benchmark.cli import main
from benchmark.tracking import DatasetRef, LocalTracker, MlflowTracker, RunStatus
from benchmark.tracking.pending import read_local_runs, unsynced_runs
from benchmark.tracking.sync import SYNC_TAG, SyncError, sync_runs


def make_runs(root: Path, tmp: Path) -> dict:
    """A parent with a FINISHED child (params, 3 metrics x 6 steps, input, artifacts), a FAILED
    child (with its reason) and a KILLED top-level run; returns the Run handles by name."""
    tracker = LocalTracker(root)
    tracker.describe_experiment("table 3/a", "Table 3 of the paper", {"profile": "smoke"})
    (tmp / "pred.csv").write_text("i,err\n0,1.5\n")
    (tmp / "hist").mkdir()
    (tmp / "hist" / "h.json").write_text('{"epochs": 6}')
    runs = {}
    with tracker.start_run("table 3/a", "reproduce", description="the invocation") as parent:
        runs["reproduce"] = parent
        with tracker.start_run(
            "table 3/a", "plain/seed0", parent=parent, tags={"run_key": "u1", "variant": "plain"}
        ) as child:
            runs["plain/seed0"] = child
            child.log_params({"optim.lr": 0.001, "model.width": 0.25, "seed": 0})
            child.log_input(DatasetRef("ds", "ab" * 32, "/data/ds", "standard/train"))
            for step in range(6):
                child.log_metrics(
                    {"loss": 1 / (step + 1), "val/dE": 10.0 - step, "lr": 1e-3 * 0.5**step}, step
                )
                child.flush()  # one CSV append per epoch, as a live run writes them
            child.log_artifact(tmp / "pred.csv", "predictions")
            child.log_artifact(tmp / "hist")
        with pytest.raises(ZeroDivisionError):
            with tracker.start_run("table 3/a", "bad/seed0", parent=parent) as bad:
                runs["bad/seed0"] = bad
                bad.log_metrics({"loss": float("nan")}, 0)
                raise ZeroDivisionError("division by zero in the loss")
    killed = tracker.start_run("fig5", "sweep", tags={"run_key": "u2"})
    killed.log_metrics({"loss": 3.0}, 0)
    killed.end(RunStatus.KILLED)
    runs["sweep"] = killed
    return runs


def copies(client: MlflowClient, experiment: str) -> dict:
    exp = client.get_experiment_by_name(experiment)
    return {r.info.run_name: r for r in client.search_runs([exp.experiment_id])}


@pytest.fixture
def synced(tmp_path):
    root = tmp_path / "tracking-fallback"
    runs = make_runs(root, tmp_path)
    uri = f"sqlite:///{tmp_path / 'store' / 'mlflow.db'}"
    report = sync_runs(root, uri)
    return runs, root, uri, report


def test_everything_is_copied(synced):
    runs, _root, uri, report = synced
    assert len(report.copied) == 4 and not report.skipped and not report.running
    client = MlflowClient(uri)
    exp = client.get_experiment_by_name("table 3/a")
    assert exp.tags["mlflow.note.content"] == "Table 3 of the paper"
    assert exp.tags["profile"] == "smoke"
    got = copies(client, "table 3/a")
    assert set(got) == {"reproduce", "plain/seed0", "bad/seed0"}
    for name, run in runs.items():
        copy = copies(client, run.experiment)[name]
        assert copy.info.status == run.status.value
        assert copy.info.start_time == run.start_time_ms
        assert copy.info.end_time == run.end_time_ms
        assert copy.data.params == run.params
        assert copy.data.tags[SYNC_TAG] == run.run_id
        for key, value in run.tags.items():
            assert copy.data.tags[key] == value
        keys = {p.key for p in run.metrics}
        for key in keys:
            history = client.get_metric_history(copy.info.run_id, key)
            got_points = sorted((m.step, m.timestamp, m.value) for m in history)
            want = sorted((p.step, p.timestamp_ms, p.value) for p in run.metrics if p.key == key)
            assert len(got_points) == len(want)
            for (gs, gt, gv), (ws, wt, wv) in zip(got_points, want, strict=True):
                assert (gs, gt) == (ws, wt)
                assert (math.isnan(gv) and math.isnan(wv)) or gv == wv
    child = got["plain/seed0"]
    assert child.data.tags["mlflow.parentRunId"] == got["reproduce"].info.run_id
    assert got["bad/seed0"].data.tags["mlflow.parentRunId"] == got["reproduce"].info.run_id
    assert "mlflow.parentRunId" not in got["reproduce"].data.tags
    assert child.data.tags["run_key"] == "u1"
    assert got["bad/seed0"].data.tags["failure_reason"] == (
        "ZeroDivisionError: division by zero in the loss"
    )
    (dataset,) = child.inputs.dataset_inputs
    assert (dataset.dataset.name, dataset.dataset.digest) == ("ds", ("ab" * 32)[:32])
    assert {t.key: t.value for t in dataset.tags}["mlflow.data.context"] == "standard/train"
    local = client.download_artifacts(child.info.run_id, "predictions/pred.csv")
    assert Path(local).read_text() == "i,err\n0,1.5\n"
    hist = Path(client.download_artifacts(child.info.run_id, "hist/h.json"))
    assert json.loads(hist.read_text()) == {"epochs": 6}
    assert report.metric_points == len(runs["plain/seed0"].metrics) + 1 + 1
    assert report.artifact_files == 2


def test_second_sync_copies_nothing_even_without_markers(synced):
    runs, root, uri, _ = synced
    assert unsynced_runs(root, uri) == []
    for marker in root.glob("*/*/synced.json"):
        marker.unlink()  # the store's tag decides, not the local marker
    again = sync_runs(root, uri)
    assert not again.copied and len(again.skipped) == 4
    client = MlflowClient(uri)
    for exp in ("table 3/a", "fig5"):
        eid = client.get_experiment_by_name(exp).experiment_id
        assert len(client.search_runs([eid], run_view_type=ViewType.ALL)) == len(
            [r for r in runs.values() if r.experiment == exp]
        )
    assert unsynced_runs(root, uri) == []  # markers rewritten


def test_a_partial_copy_is_replaced(tmp_path):
    root = tmp_path / "fb"
    runs = make_runs(root, tmp_path)
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    client = MlflowClient(uri)
    eid = client.create_experiment("fig5")
    # What a sync killed midway leaves: the copy created (RUNNING), not finished.
    client.create_run(eid, tags={SYNC_TAG: runs["sweep"].run_id}, run_name="sweep")
    report = sync_runs(root, uri)
    assert report.replaced == 1 and len(report.copied) == 4
    (copy,) = client.search_runs([eid])  # active runs: the complete copy only
    assert copy.info.status == "KILLED"
    assert [m.value for m in client.get_metric_history(copy.info.run_id, "loss")] == [3.0]


def test_running_runs_and_their_children_wait(tmp_path, capsys):
    root = tmp_path / "fb"
    tracker = LocalTracker(root)
    parent = tracker.start_run("t", "reproduce")  # a killed invocation: left RUNNING
    with tracker.start_run("t", "unit", parent=parent) as unit:
        unit.log_metrics({"loss": 1.0}, 0)
    with tracker.start_run("t", "other"):
        pass
    db = tmp_path / "m.db"
    code = main(["sync", "--from", str(root), "--to", str(db)])
    out = capsys.readouterr().out
    assert code == 1
    assert "copied 1 run" in out and "1 still RUNNING and 1 of their children" in out
    assert "rerun the command that made them" in out
    client = MlflowClient(f"sqlite:///{db}")
    assert set(copies(client, "t")) == {"other"}
    parent.end(RunStatus.KILLED)  # the rerun closes the stale parent, then sync sends the rest
    assert main(["sync", "--from", str(root), "--to", str(db)]) == 0
    got = copies(client, "t")
    assert set(got) == {"other", "reproduce", "unit"}
    assert got["unit"].data.tags["mlflow.parentRunId"] == got["reproduce"].info.run_id


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda tmp: tmp / "missing", "no such directory"),
        (lambda tmp: (tmp / "empty").mkdir() or tmp / "empty", "no runs in it"),
    ],
)
def test_missing_or_empty_source_is_one_line_exit_2(tmp_path, capsys, make, match):
    source = make(tmp_path)
    # A sqlite URI, not a plain path: a plain path adds its once-per-process "note: ... is a
    # path" line, which an earlier test of the same process may or may not have printed.
    assert main(["sync", "--from", str(source), "--to", f"sqlite:///{tmp_path / 'm.db'}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and match in err[0] and str(source) in err[0]
    with pytest.raises(SyncError, match=match):
        sync_runs(source, f"sqlite:///{tmp_path / 'm.db'}")


def test_unreachable_or_unusable_target_is_exit_2(tmp_path, capsys):
    from benchmark.tracking.server import free_port

    root = tmp_path / "fb"
    with LocalTracker(root).start_run("t", "r"):
        pass
    url = f"http://127.0.0.1:{free_port()}"
    assert main(["sync", "--from", str(root), "--to", url]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unreachable" in err[0] and url in err[0]
    assert main(["sync", "--from", str(root), "--to", str(tmp_path)]) == 2  # a directory
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is a directory" in err[0] and "mlflow.db" in err[0]
    assert read_local_runs(root)[0].synced() == {}


def test_tracker_on_the_store_sees_local_runs_until_synced(tmp_path, monkeypatch, capsys):
    """The rerun case: the store is back, finished runs exist only locally."""
    monkeypatch.chdir(tmp_path)
    make_runs(tmp_path / "tracking-fallback", tmp_path)
    from benchmark.tracking import create_tracker

    tracker = create_tracker("mlflow", workdir=tmp_path)
    notice = capsys.readouterr().out  # status lines (benchmark.progress.status)
    uri = tracker.uri
    assert "4 runs (2 finished) exist ONLY in ./tracking-fallback" in notice
    assert f"uavbench sync --from ./tracking-fallback --to {uri}" in notice
    assert tracker.summary().splitlines()[1].startswith("tracking: 4 runs exist only in")
    found = tracker.find_finished_run("table 3/a", "u1")
    assert found is not None and found.backend == "local"  # reused, and said loudly
    sync_runs(tmp_path / "tracking-fallback", uri)
    again = MlflowTracker(uri, fallback_dir=tmp_path / "tracking-fallback")
    assert again.pending_sync_notice() == ""
    assert len(again.summary().splitlines()) == 1
    hits = again.find_runs("table 3/a", "u1")
    assert [h.backend for h in hits] == ["mlflow"]  # found once, in the store


def test_handed_over_run_replaces_its_husk(tmp_path, monkeypatch):
    """A run the fallback took over mid-run: its partial husk in the store is retired."""
    import warnings

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    tracker = MlflowTracker(uri, fallback_dir=tmp_path / "fb")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with tracker.start_run("t", "unit", tags={"run_key": "k"}) as run:
            run.log_metrics({"loss": 4.0}, 0)
            run.flush()
            husk = run.run_id

            def broken(*args, **kwargs):
                raise ConnectionError("store went away")

            monkeypatch.setattr(tracker._client, "log_batch", broken)
            run.log_metrics({"loss": 2.0}, 1)
            run.flush()
    assert tracker.using_fallback
    sync_runs(tmp_path / "fb", uri)
    client = MlflowClient(uri)
    gone = client.get_run(husk)
    assert gone.info.lifecycle_stage == "deleted"
    (copy,) = copies(client, "t").values()
    assert gone.data.tags["superseded_by"] == copy.info.run_id
    assert [m.value for m in client.get_metric_history(copy.info.run_id, "loss")] == [4.0, 2.0]
    hits = MlflowTracker(uri, fallback_dir=tmp_path / "fb").find_runs("t", "k")
    assert [(h.run_id, h.backend) for h in hits] == [(copy.info.run_id, "mlflow")]
