"""MlflowTracker against a REAL MLflow server on loopback, read back through the REST API.

The reads use plain urllib on MLflow's documented REST endpoints, not MLflow's own client, so the
test checks what any other consumer of the server would see.
"""

from __future__ import annotations

import json
import urllib.parse
import urllib.request
import warnings

import pytest

from benchmark.tracking import MlflowTracker, RunStatus, TrackingFallbackWarning


def rest_get(base_url: str, endpoint: str, **query: str) -> dict:
    url = f"{base_url}/api/2.0/mlflow/{endpoint}?{urllib.parse.urlencode(query)}"
    with urllib.request.urlopen(url, timeout=10) as resp:
        return json.loads(resp.read())


def rest_post(base_url: str, endpoint: str, body: dict) -> dict:
    req = urllib.request.Request(
        f"{base_url}/api/2.0/mlflow/{endpoint}",
        data=json.dumps(body).encode(),
        headers={"Content-Type": "application/json"},
        method="POST",
    )
    with urllib.request.urlopen(req, timeout=10) as resp:
        return json.loads(resp.read())


def tags_of(run: dict) -> dict[str, str]:
    return {t["key"]: t["value"] for t in run["data"].get("tags", [])}


def params_of(run: dict) -> dict[str, str]:
    return {p["key"]: p["value"] for p in run["data"].get("params", [])}


class TestMlflowTrackerOnServer:
    def test_parent_nested_failed_runs_read_back_over_rest(self, mlflow_server, tmp_path):
        url = mlflow_server.url
        with warnings.catch_warnings():
            warnings.simplefilter("error", TrackingFallbackWarning)  # must NOT fall back
            tracker = MlflowTracker(url, fallback_dir=tmp_path / "fallback")
            assert not tracker.using_fallback
            predictions = tmp_path / "predictions.csv"
            predictions.write_text("index,yaw_err_deg\n0,1.5\n1,-2.0\n")
            with tracker.start_run("table1", "reproduce", tags={"table": "table1"}) as parent:
                with tracker.start_run(
                    "table1",
                    "pdre-net/seed0",
                    parent=parent,
                    tags={"head": "pdre_net", "encoder": "a-f", "seed": 0, "run_key": "k0"},
                ) as child:
                    child.log_params({"optim.lr": 0.001, "optim.batch_size": 20})
                    for epoch in range(4):
                        child.log_metrics({"loss": 1.0 / (epoch + 1), "err": 10.0 - epoch}, epoch)
                    child.log_artifact(predictions, "predictions")
                with pytest.raises(RuntimeError):
                    with tracker.start_run("table1", "re-net-r/seed0", parent=parent) as bad:
                        bad.log_metrics({"loss": float("nan")}, 0)
                        raise RuntimeError("non-finite loss")
        assert not tracker.using_fallback

        exp = rest_get(url, "experiments/get-by-name", experiment_name="table1")["experiment"]
        runs = rest_post(
            url, "runs/search", {"experiment_ids": [exp["experiment_id"]], "max_results": 50}
        )["runs"]
        by_name = {r["info"]["run_name"]: r for r in runs}
        assert set(by_name) == {"reproduce", "pdre-net/seed0", "re-net-r/seed0"}

        parent_id = by_name["reproduce"]["info"]["run_id"]
        assert by_name["reproduce"]["info"]["status"] == "FINISHED"
        assert tags_of(by_name["reproduce"])["table"] == "table1"
        assert "mlflow.parentRunId" not in tags_of(by_name["reproduce"])

        good = by_name["pdre-net/seed0"]
        assert good["info"]["status"] == "FINISHED"
        tags = tags_of(good)
        assert tags["mlflow.parentRunId"] == parent_id
        assert (tags["head"], tags["encoder"], tags["seed"], tags["run_key"]) == (
            "pdre_net",
            "a-f",
            "0",
            "k0",
        )
        assert params_of(good) == {"optim.lr": "0.001", "optim.batch_size": "20"}
        history = rest_get(
            url, "metrics/get-history", run_id=good["info"]["run_id"], metric_key="loss"
        )["metrics"]
        assert sorted((m["step"], m["value"]) for m in history) == [
            (0, 1.0),
            (1, 0.5),
            (2, pytest.approx(1 / 3)),
            (3, 0.25),
        ]
        files = rest_get(
            url, "artifacts/list", run_id=good["info"]["run_id"], path="predictions"
        ).get("files", [])
        assert [f["path"] for f in files] == ["predictions/predictions.csv"]
        # The artifact's bytes, through the server's artifact proxy.
        artifact_url = f"{url}/get-artifact?" + urllib.parse.urlencode(
            {"path": "predictions/predictions.csv", "run_uuid": good["info"]["run_id"]}
        )
        with urllib.request.urlopen(artifact_url, timeout=10) as resp:
            assert resp.read().decode() == predictions.read_text()

        bad_run = by_name["re-net-r/seed0"]
        assert bad_run["info"]["status"] == RunStatus.FAILED.value
        assert tags_of(bad_run)["mlflow.parentRunId"] == parent_id

        # find_finished_run sees the finished run, not the failed one, not other keys.
        found = tracker.find_finished_run("table1", "k0")
        assert found is not None and found.run_id == good["info"]["run_id"]
        assert found.backend == "mlflow" and found.metrics["err"] == 7.0
        assert tracker.find_finished_run("table1", "k1") is None
        assert tracker.find_finished_run("no-such-experiment", "k0") is None

    def test_killed_run_status(self, mlflow_server, tmp_path):
        tracker = MlflowTracker(mlflow_server.url, fallback_dir=tmp_path / "fallback")
        with pytest.raises(KeyboardInterrupt):
            with tracker.start_run("fig7", "interrupted", tags={"run_key": "kk"}):
                raise KeyboardInterrupt
        exp = rest_get(mlflow_server.url, "experiments/get-by-name", experiment_name="fig7")
        runs = rest_post(
            mlflow_server.url,
            "runs/search",
            {"experiment_ids": [exp["experiment"]["experiment_id"]]},
        )["runs"]
        assert [r["info"]["status"] for r in runs] == ["KILLED"]
        assert tracker.find_finished_run("fig7", "kk") is None


@pytest.mark.slow
class TestServerDiesMidRun:
    def test_everything_lands_in_the_fallback(self, tmp_path, monkeypatch):
        from benchmark.tracking.server import MlflowServer

        # No retries: the dead server is noticed at once (a user's setting would win).
        monkeypatch.setenv("MLFLOW_HTTP_REQUEST_MAX_RETRIES", "0")
        monkeypatch.setenv("MLFLOW_HTTP_REQUEST_TIMEOUT", "5")
        server = MlflowServer(f"sqlite:///{tmp_path / 'db.sqlite'}", tmp_path / "art").start()
        try:
            tracker = MlflowTracker(server.url, fallback_dir=tmp_path / "fb")
            (tmp_path / "table.md").write_text("| x |\n")
            with pytest.warns(TrackingFallbackWarning, match="failed") as record:
                with tracker.start_run("table3", "reproduce") as parent:
                    with tracker.start_run(
                        "table3", "v/s0", parent=parent, tags={"run_key": "z"}
                    ) as r:
                        r.log_params({"optim.lr": 0.001})
                        r.log_metrics({"loss": 3.0}, 1)
                        r.flush()
                        first_id = r.run_id
                        server.stop()  # the server dies mid-run
                        r.log_metrics({"loss": 2.0}, 2)
                        r.log_artifact(tmp_path / "table.md")
        finally:
            server.stop()
        assert len(record) == 1 and tracker.using_fallback
        found = tracker.find_finished_run("table3", "z")
        assert found is not None and found.backend == "local"
        assert found.tags["mlflow_run_id"] == first_id
        assert found.params == {"optim.lr": "0.001"} and found.metrics == {"loss": 2.0}
        run_dir = tmp_path / "fb" / "table3" / found.run_id
        assert (run_dir / "artifacts" / "table.md").is_file()
        assert (run_dir / "metrics.csv").read_text().count("loss") == 2
