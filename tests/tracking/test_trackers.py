"""Run handle semantics, the local tracker, the embedded sqlite store and the fallback."""

from __future__ import annotations

import csv
import hashlib
import json
import subprocess
import time
import warnings
from pathlib import Path

import pytest

from benchmark.tracking import (
    LocalTracker,
    MlflowTracker,
    NullTracker,
    RunStatus,
    TrackingFallbackWarning,
    create_tracker,
    file_sha256,
    git_commit,
    manifest_sha256,
    server_is_healthy,
)
from benchmark.tracking.server import free_port


class CountingTracker(NullTracker):
    def __init__(self) -> None:
        self.batches: list[tuple[int, int, int]] = []
        self.ended: list[RunStatus] = []

    def _log_batch(self, run, metrics, params, tags) -> None:
        self.batches.append((len(metrics), len(params), len(tags)))

    def _end_run(self, run, status) -> None:
        self.ended.append(status)


def read_local_run(root: Path, experiment: str, name: str) -> tuple[dict, list[dict], Path]:
    for path in (root / experiment).glob("*/run.json"):
        rec = json.loads(path.read_text())
        if rec["run_name"] == name:
            with open(path.parent / "metrics.csv", newline="") as fh:
                return rec, list(csv.DictReader(fh)), path.parent
    raise AssertionError(f"no local run {name!r} under {root}")


class TestRun:
    def test_metrics_are_sent_in_batches(self):
        tracker = CountingTracker()
        with tracker.start_run("exp", "r") as run:
            for epoch in range(50):
                run.log_metrics({"loss": 1.0, "err": 2.0, "acc": 0.5}, step=epoch)
        # 150 points, batch size 200: one request, at the end, not 150.
        assert tracker.batches == [(150, 0, 0)]
        assert tracker.ended == [RunStatus.FINISHED]

    def test_large_history_flushes_every_batch_size(self):
        tracker = CountingTracker()
        with tracker.start_run("exp", "r") as run:
            for step in range(450):
                run.log_metrics({"x": step}, step)
        assert [b[0] for b in tracker.batches] == [200, 200, 50]

    @pytest.mark.parametrize(
        ("error", "status"),
        [(None, RunStatus.FINISHED), (ValueError, RunStatus.FAILED), (KeyboardInterrupt, "KILLED")],
    )
    def test_context_manager_status(self, error, status):
        tracker = CountingTracker()
        try:
            with tracker.start_run("exp", "r") as run:
                if error is not None:
                    raise error
        except (ValueError, KeyboardInterrupt):
            pass
        assert run.status == RunStatus(status)
        assert tracker.ended == [RunStatus(status)]

    def test_end_twice_is_noop(self):
        tracker = CountingTracker()
        run = tracker.start_run("exp", "r")
        run.end(RunStatus.FAILED)
        run.end(RunStatus.FINISHED)
        assert tracker.ended == [RunStatus.FAILED]

    def test_param_cannot_change(self):
        with NullTracker().start_run("exp", "r") as run:
            run.log_params({"optim.lr": 0.001})
            run.log_params({"optim.lr": 0.001})  # same value: fine
            with pytest.raises(ValueError, match=r"optim\.lr.*0\.001.*0\.01"):
                run.log_params({"optim.lr": 0.01})

    def test_non_numeric_metric_names_key(self):
        with NullTracker().start_run("exp", "r") as run:
            with pytest.raises(TypeError, match="'loss'"):
                run.log_metrics({"loss": "high"})

    def test_nested_run_must_share_experiment(self):
        tracker = NullTracker()
        with tracker.start_run("table1", "parent") as parent:
            with pytest.raises(ValueError, match="table1"):
                tracker.start_run("table2", "child", parent=parent)

    def test_missing_artifact_raises(self, tmp_path):
        with NullTracker().start_run("exp", "r") as run:
            with pytest.raises(FileNotFoundError, match=r"nope\.csv"):
                run.log_artifact(tmp_path / "nope.csv")


class TestLocalTracker:
    def test_layout_and_find_finished_run(self, tmp_path):
        tracker = LocalTracker(tmp_path / "runs")
        (tmp_path / "a.txt").write_text("hello")
        with tracker.start_run("table 1/std", "parent") as parent:
            with tracker.start_run(
                "table 1/std", "child", parent=parent, tags={"run_key": "k"}
            ) as r:
                r.log_params({"model.head": "pdre_net"})
                r.log_metrics({"loss": 0.5}, 0)
                r.log_metrics({"loss": 0.25}, 1)
                r.log_artifact(tmp_path / "a.txt", "cfg")
        with pytest.raises(RuntimeError):
            with tracker.start_run("table 1/std", "child-again", tags={"run_key": "k"}):
                raise RuntimeError
        rec, metrics, run_dir = read_local_run(tmp_path / "runs", "table_1_std", "child")
        assert rec["status"] == "FINISHED" and rec["parent_run_id"] == parent.run_id
        assert rec["params"] == {"model.head": "pdre_net"}
        assert [(m["key"], float(m["value"]), int(m["step"])) for m in metrics] == [
            ("loss", 0.5, 0),
            ("loss", 0.25, 1),
        ]
        assert (run_dir / "artifacts" / "cfg" / "a.txt").read_text() == "hello"
        found = tracker.find_finished_run("table 1/std", "k")
        assert found is not None and found.run_name == "child"  # the FAILED one is skipped
        assert found.metrics == {"loss": 0.25}
        assert tracker.find_finished_run("table 1/std", "other") is None

    def test_a_row_still_being_written_by_another_process_is_not_read(self, tmp_path):
        # two workers share one store: one lists the runs (to reuse a finished one) while the
        # other appends to its run's metrics.csv; a half-written last row used to raise
        # "float() argument must be ... not 'NoneType'" (seen once through Ray under load)
        tracker = LocalTracker(tmp_path / "runs")
        with tracker.start_run("t", "done", tags={"run_key": "k"}) as r:
            r.log_metrics({"loss": 0.5}, 0)
        with tracker.start_run("t", "writing", tags={"run_key": "w"}) as r:
            r.log_metrics({"loss": 0.75}, 0)
            r.flush()
            _, _, run_dir = read_local_run(tmp_path / "runs", "t", "writing")
            with open(run_dir / "metrics.csv", "a", encoding="utf-8") as fh:
                fh.write("loss")  # the other process is mid-row
            runs = {info.run_name: info for info in tracker.list_runs("t")}
            assert runs["done"].metrics == {"loss": 0.5}
            assert runs["writing"].metrics == {"loss": 0.75}  # the partial row is not read
            found = tracker.find_finished_run("t", "k")
            assert found is not None and found.metrics == {"loss": 0.5}


@pytest.fixture
def in_tmp_cwd(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    return tmp_path


class TestMlflowTrackerEmbedded:
    def test_convention_default_store_is_sqlite_in_cwd(self, in_tmp_cwd):
        tracker = create_tracker()
        assert tracker.uri == f"sqlite:///{in_tmp_cwd / 'mlflow.db'}"
        assert (in_tmp_cwd / "mlflow.db").is_file()

    def test_env_var_selects_store(self, in_tmp_cwd, monkeypatch):
        monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{in_tmp_cwd / 'other.db'}")
        assert create_tracker().uri.endswith("other.db")

    def test_runs_and_find_finished_run(self, in_tmp_cwd):
        from mlflow.tracking import MlflowClient

        tracker = create_tracker()
        (in_tmp_cwd / "out").mkdir()
        (in_tmp_cwd / "out" / "table.md").write_text("| a |\n")
        with tracker.start_run("table3", "reproduce") as parent:
            with tracker.start_run("table3", "v/s0", parent=parent, tags={"run_key": "abc"}) as r:
                r.log_params({"seed": 0})
                r.log_metrics({"dE": 3.0}, 0)
                r.log_artifact(in_tmp_cwd / "out")
        assert not tracker.using_fallback
        client = MlflowClient(tracker.uri)
        got = client.get_run(r.run_id)
        assert got.data.tags["mlflow.parentRunId"] == parent.run_id
        assert got.info.status == "FINISHED"
        assert (in_tmp_cwd / "mlartifacts" / "table3" / r.run_id / "artifacts" / "out").is_dir()
        # A new tracker (a later invocation) finds it again.
        found = create_tracker().find_finished_run("table3", "abc")
        assert found is not None and found.run_id == r.run_id and found.params == {"seed": "0"}

    def test_bad_run_key_rejected(self, in_tmp_cwd):
        with pytest.raises(ValueError, match="run_key"):
            create_tracker().find_finished_run("t", "x' or '1'='1")

    def test_mid_run_failure_hands_over_everything(self, in_tmp_cwd, monkeypatch):
        tracker = create_tracker()
        (in_tmp_cwd / "p.csv").write_text("i,err\n0,1\n")
        with pytest.warns(TrackingFallbackWarning) as record:
            with tracker.start_run("t", "parent", tags={"table": "t"}) as parent:
                with tracker.start_run("t", "child", parent=parent, tags={"run_key": "k9"}) as r:
                    r.log_params({"a": 1})
                    r.log_metrics({"loss": 4.0}, 0)
                    r.flush()  # sent to MLflow
                    mlflow_id = r.run_id
                    r.log_artifact(in_tmp_cwd / "p.csv", "pred")

                    def broken(*args, **kwargs):
                        raise ConnectionError("server went away")

                    monkeypatch.setattr(tracker._client, "log_batch", broken)
                    r.log_metrics({"loss": 2.0}, 1)
                    r.flush()  # fails -> fallback
                    r.log_metrics({"loss": 1.0}, 2)
        assert len(record) == 1 and "server went away" in str(record[0].message)
        assert tracker.using_fallback
        rec, metrics, run_dir = read_local_run(in_tmp_cwd / "tracking-fallback", "t", "child")
        assert rec["status"] == "FINISHED"
        assert rec["tags"]["mlflow_run_id"] == mlflow_id and rec["tags"]["run_key"] == "k9"
        assert rec["params"] == {"a": "1"}
        assert [(int(m["step"]), float(m["value"])) for m in metrics] == [
            (0, 4.0),
            (1, 2.0),
            (2, 1.0),
        ]
        assert (run_dir / "artifacts" / "pred" / "p.csv").is_file()
        parent_rec, _, _ = read_local_run(in_tmp_cwd / "tracking-fallback", "t", "parent")
        assert rec["parent_run_id"] == parent_rec["run_id"]
        assert parent_rec["status"] == "FINISHED"
        # The next invocation does not redo it, though it is only in the fallback.
        found = create_tracker().find_finished_run("t", "k9")
        assert found is not None and found.backend == "local"


class TestUnreachableServer:
    def test_fallback_with_one_warning(self, tmp_path):
        port = free_port()  # nothing listens there
        start = time.monotonic()
        with pytest.warns(TrackingFallbackWarning, match="unreachable") as record:
            tracker = MlflowTracker(f"http://127.0.0.1:{port}", fallback_dir=tmp_path / "fb")
        assert time.monotonic() - start < 10
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # no second warning
            with tracker.start_run("table1", "reproduce") as parent:
                with tracker.start_run(
                    "table1", "child", parent=parent, tags={"run_key": "kk"}
                ) as run:
                    run.log_params({"x": 1})
                    run.log_metrics({"loss": 1.5}, 3)
        assert len(record) == 1 and str(tmp_path / "fb") in str(record[0].message)
        rec, metrics, _ = read_local_run(tmp_path / "fb", "table1", "child")
        assert rec["status"] == "FINISHED" and rec["params"] == {"x": "1"}
        assert metrics[0]["key"] == "loss" and float(metrics[0]["value"]) == 1.5
        assert tracker.find_finished_run("table1", "kk").run_id == rec["run_id"]

    def test_server_is_healthy_closed_port(self):
        ok, reason = server_is_healthy(f"http://127.0.0.1:{free_port()}", timeout=2)
        assert not ok and "/health" in reason


class TestProvenance:
    def test_file_sha256_known_vector(self, tmp_path):
        (tmp_path / "manifest.json").write_bytes(b"abc")
        # FIPS 180-2 test vector for "abc".
        expected = "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        assert file_sha256(tmp_path / "manifest.json") == expected
        assert manifest_sha256(tmp_path) == expected  # directory holding manifest.json
        assert manifest_sha256(tmp_path / "manifest.json") == hashlib.sha256(b"abc").hexdigest()

    def test_manifest_missing(self, tmp_path):
        with pytest.raises(FileNotFoundError, match="manifest"):
            manifest_sha256(tmp_path)

    def test_git_commit(self, tmp_path):
        assert git_commit(tmp_path) is None  # not a work tree
        git = ["git", "-c", "user.name=t", "-c", "user.email=t@t"]
        subprocess.run([*git, "init", "-q", str(tmp_path)], check=True)
        (tmp_path / "f").write_text("1")
        subprocess.run([*git, "-C", str(tmp_path), "add", "f"], check=True)
        subprocess.run([*git, "-C", str(tmp_path), "commit", "-qm", "x"], check=True)
        head = subprocess.run(
            ["git", "-C", str(tmp_path), "rev-parse", "HEAD"], capture_output=True, text=True
        ).stdout.strip()
        assert git_commit(tmp_path) == head and len(head) == 40
        (tmp_path / "f").write_text("2")
        assert git_commit(tmp_path) == head + "-dirty"
