"""A tiny ``uavbench reproduce`` (smoke profile, Table 3) against a REAL MLflow server on
loopback, read back through MLflow's REST API with plain HTTP; a second invocation finds every
run in the store and trains nothing."""

from __future__ import annotations

import json
import urllib.parse
import urllib.request

from benchmark.cli import main


def rest(base: str, endpoint: str, body: dict | None = None, **query: str) -> dict:
    url = f"{base}/api/2.0/mlflow/{endpoint}"
    if body is None:
        req = urllib.request.Request(f"{url}?{urllib.parse.urlencode(query)}")
    else:
        req = urllib.request.Request(
            url, json.dumps(body).encode(), {"Content-Type": "application/json"}, method="POST"
        )
    with urllib.request.urlopen(req, timeout=10) as resp:
        return json.loads(resp.read())


def tags(run: dict) -> dict[str, str]:
    return {t["key"]: t["value"] for t in run["data"].get("tags", [])}


class TestReproduceAgainstServer:
    def test_smoke_table3(self, mlflow_server, smoke_dataset, tmp_path, monkeypatch):
        monkeypatch.chdir(tmp_path)
        monkeypatch.setenv("NUMBA_NUM_THREADS", "1")
        argv = [
            "reproduce",
            "--profile",
            "smoke",
            "--only",
            "table3",
            "--jobs",
            "1",
            "--quiet",
            "--tracking-uri",
            mlflow_server.url,
            "--data",
            str(smoke_dataset),
            "--workdir",
            str(tmp_path / "work"),
            "--out",
            str(tmp_path / "reports"),
        ]
        assert main(argv) == 0
        base = mlflow_server.url
        exp = rest(base, "experiments/get-by-name", experiment_name="uavbench-smoke/table3")
        exp_id = exp["experiment"]["experiment_id"]
        runs = rest(base, "runs/search", {"experiment_ids": [exp_id], "max_results": 100})["runs"]
        parents = [r for r in runs if "mlflow.parentRunId" not in tags(r)]
        children = [r for r in runs if "mlflow.parentRunId" in tags(r)]
        assert len(parents) == 1 and parents[0]["info"]["status"] == "FINISHED"
        assert len(children) == 3  # Pd/Re-Net, Re-Net-T and the UAV-only control, one seed
        for child in children:
            t = tags(child)
            assert child["info"]["status"] == "FINISHED"
            assert t["mlflow.parentRunId"] == parents[0]["info"]["run_id"]
            assert t["table"] == "table3" and t["seed"] == "0" and t["run_key"]
            assert {"head", "encoder", "git_commit"} <= set(t)
            metrics = {m["key"] for m in child["data"]["metrics"]}
            assert {"standard/test/dE_m", "standard/test/dN_m", "standard/test/dU_m"} <= metrics
            params = {p["key"] for p in child["data"]["params"]}
            assert {"optim.lr", "optim.batch_size", "model.attitude", "seed"} <= params
        translations = sorted(tags(c)["translation_head"] for c in children)
        assert translations == ["re_net_t", "regression", "regression"]

        # Idempotent: the second invocation finds the runs in the store and adds no nested run.
        assert main(argv) == 0
        again = rest(base, "runs/search", {"experiment_ids": [exp_id], "max_results": 100})["runs"]
        assert len([r for r in again if "mlflow.parentRunId" in tags(r)]) == 3
