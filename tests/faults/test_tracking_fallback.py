"""Issue 14, item 3: with the server down, the fallback is loud and the summary true; once the
server is back, a rerun says the runs exist only locally, and ``uavbench sync`` sends them with
identical metric histories, once."""

from __future__ import annotations

import warnings

import pytest
from mlflow.tracking import MlflowClient

from benchmark.cli import main
from benchmark.tracking import RunStatus, TrackingFallbackWarning, create_tracker
from benchmark.tracking.server import MlflowServer, free_port


def log_reproduction(tracker) -> dict[str, list[tuple[str, int, int, float]]]:
    """What a small reproduction logs: a parent, two units with per-epoch metrics (one FAILED
    with its reason), artifacts. Returns each run's metric points (the reference)."""
    points = {}
    tracker.describe_experiment("table2", "Table 2: attitude heads")
    with tracker.start_run("table2", "reproduce smoke", description="invocation") as parent:
        for seed in (0, 1):
            try:
                with tracker.start_run(
                    "table2", f"euler/seed{seed}", parent=parent, tags={"run_key": f"u{seed}"}
                ) as unit:
                    unit.log_params({"seed": seed, "optim.lr": 1e-3})
                    for epoch in range(4):
                        unit.log_metrics({"train_loss": 2.0 / (epoch + 1 + seed), "epoch": epoch},
                                         step=epoch)  # fmt: skip
                        unit.flush()
                    points[unit.run_name] = unit.metrics
                    if seed == 1:
                        raise FloatingPointError("val_loss_total is inf after epoch 3")
            except FloatingPointError:
                pass
        points[parent.run_name] = parent.metrics
    return {
        name: sorted((p.key, p.step, p.timestamp_ms, p.value) for p in metrics)
        for name, metrics in points.items()
    }


def test_fallback_is_loud_then_sync_sends_identical_runs(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    command = f"uavbench sync --from ./tracking-fallback --to {url}"

    # 1. Server down: one loud block (status lines, on stdout), the runs go to
    # ./tracking-fallback.
    with pytest.warns(TrackingFallbackWarning):
        tracker = create_tracker("mlflow", url, workdir=tmp_path)
    block = capsys.readouterr().out
    assert "MLFLOW TRACKING FAILED" in block and "unreachable" in block
    assert "runs go to:  ./tracking-fallback" in block and command in block
    reference = log_reproduction(tracker)
    summary = tracker.summary()
    assert summary == (
        f"tracking: 3 runs kept locally in ./tracking-fallback (MLflow server {url} was "
        f"unreachable); `{command}` sends them"
    )

    # 2. Server back: the rerun reuses the local runs and says loudly they are only local.
    server = MlflowServer(
        f"sqlite:///{tmp_path / 'server.db'}", tmp_path / "art", port=port,
        log_path=tmp_path / "server.log", startup_timeout=600,  # ~8 s on a quiet machine
    )  # fmt: skip
    with server as srv:
        with warnings.catch_warnings():
            warnings.simplefilter("error", TrackingFallbackWarning)
            rerun = create_tracker("mlflow", url, workdir=tmp_path)
        notice = capsys.readouterr().out  # status lines
        assert "3 runs (2 finished) exist ONLY in ./tracking-fallback" in notice
        assert command in notice
        assert rerun.find_finished_run("table2", "u0").backend == "local"

        # 3. uavbench sync: the server gets the same runs and metric histories.
        assert main(["sync", "--to", srv.url]) == 0
        out = capsys.readouterr().out
        assert "copied 3 runs" in out and "skipped 0" in out
        client = MlflowClient(srv.url)
        exp = client.get_experiment_by_name("table2")
        assert exp.tags["mlflow.note.content"] == "Table 2: attitude heads"
        runs = {r.info.run_name: r for r in client.search_runs([exp.experiment_id])}
        assert set(runs) == set(reference)
        for name, want in reference.items():
            got = sorted(
                (m.key, m.step, m.timestamp, m.value)
                for key in runs[name].data.metrics
                for m in client.get_metric_history(runs[name].info.run_id, key)
            )
            assert got == want, name
        assert runs["euler/seed0"].info.status == RunStatus.FINISHED.value
        failed = runs["euler/seed1"]
        assert failed.info.status == RunStatus.FAILED.value
        assert failed.data.tags["failure_reason"].endswith("val_loss_total is inf after epoch 3")
        assert failed.data.tags["mlflow.parentRunId"] == runs["reproduce smoke"].info.run_id

        # 4. A second sync copies nothing; the next invocation finds the runs on the server.
        assert main(["sync", "--to", srv.url]) == 0
        assert "copied 0 runs" in capsys.readouterr().out
        assert len(client.search_runs([exp.experiment_id])) == 3
        after = create_tracker("mlflow", url, workdir=tmp_path)
        assert capsys.readouterr() == ("", "")  # nothing pending any more: not a word
        assert after.find_finished_run("table2", "u0").backend == "mlflow"
        assert after.summary() == f"tracking: {url}"
