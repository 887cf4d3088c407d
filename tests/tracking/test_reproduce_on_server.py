"""Acceptance test of issue 12: ``uavbench reproduce`` (smoke profile, Table 3, two epochs, two
worker processes) against a REAL MLflow server on loopback, invoked twice, read back through
``MlflowClient``: the experiments' kind and description, one parent per reproduction, training
runs with real durations and per-epoch curves, dataset inputs with the manifest digest, and a
logged model that loads back and reproduces the unit's own predictions."""

from __future__ import annotations

import dataclasses
import hashlib
import json

import numpy as np
import pandas as pd
import pytest

from benchmark.cli import main
from benchmark.runner.plan import repro_profiles as profiles_module

EPOCHS = 2


@pytest.fixture(scope="module")
def reproduced(mlflow_server, smoke_dataset, tmp_path_factory):
    """Two invocations of the same reproduction; the store and the work dir after them."""
    tmp = tmp_path_factory.mktemp("repro-server")
    mp = pytest.MonkeyPatch()
    smoke = profiles_module.PROFILES["smoke"]
    two_epochs = dataclasses.replace(smoke, optim=dataclasses.replace(smoke.optim, epochs=EPOCHS))
    mp.setitem(profiles_module.PROFILES, "smoke", two_epochs)
    mp.chdir(tmp)
    mp.setenv("NUMBA_NUM_THREADS", "1")
    argv = [
        "reproduce", "--profile", "smoke", "--only", "table3", "--workers", "2", "--quiet",
        "--tracking-uri", mlflow_server.url, "--data", str(smoke_dataset),
        "--workdir", str(tmp / "work"), "--out", str(tmp / "reports"),
    ]  # fmt: skip
    try:
        codes = [main(argv), main(argv)]
    finally:
        mp.undo()
    from mlflow import MlflowClient

    return codes, MlflowClient(mlflow_server.url), tmp


def runs_of(client, name: str) -> tuple[object, list]:
    exp = client.get_experiment_by_name(name)
    assert exp is not None, name
    return exp, client.search_runs([exp.experiment_id], max_results=200)


class TestReproduceOnServer:
    def test_both_invocations_succeed(self, reproduced, capsys):
        codes, _, _ = reproduced
        assert codes == [0, 0]

    def test_experiments_kind_and_description(self, reproduced):
        _, client, _ = reproduced
        for name in ("uavbench-smoke/table3", "uavbench-smoke/training"):
            exp, _ = runs_of(client, name)
            assert exp.tags["mlflow.experimentKind"] == "custom_model_development"
            assert len(exp.tags["mlflow.note.content"]) > 100
        exp, _ = runs_of(client, "uavbench-smoke/table3")
        text = exp.tags["mlflow.note.content"]
        assert "Translation estimation" in text and "paper Table 3" in text and "`dE_m`" in text

    def test_one_parent_per_reproduction(self, reproduced):
        _, client, _ = reproduced
        _, runs = runs_of(client, "uavbench-smoke/table3")
        parents = [r for r in runs if "mlflow.parentRunId" not in r.data.tags]
        children = [r for r in runs if "mlflow.parentRunId" in r.data.tags]
        assert len(parents) == 1 and parents[0].info.status == "FINISHED"
        assert len(children) == 4  # Pd/Re-Net, Re-Net-T, Laplace, the UAV-only control; one seed
        for child in children:
            tags = child.data.tags
            assert tags["mlflow.parentRunId"] == parents[0].info.run_id
            assert child.info.status == "FINISHED"
            assert (
                "row **" in tags["mlflow.note.content"] and "seed 0" in tags["mlflow.note.content"]
            )
            assert "x" not in tags and "x" not in child.data.params  # not a sweep
            assert all(v != "" for v in tags.values())
            assert all(v != "None" for v in child.data.params.values())
            metrics = child.data.metrics
            assert {"test_dE_m", "test_dphi_deg", "val_dE_m", "standard/test/dE_m"} <= set(metrics)
            assert metrics["test_dE_m"] == metrics["standard/test/dE_m"]
        heads = sorted(c.data.tags["translation_head"] for c in children)
        assert heads == ["laplace", "re_net_t", "regression", "regression"]

    def test_training_runs_live_with_real_durations(self, reproduced):
        _, client, tmp = reproduced
        _, runs = runs_of(client, "uavbench-smoke/training")
        assert len(runs) == 4  # one per unit, not one per invocation
        _, rows = runs_of(client, "uavbench-smoke/table3")
        by_id = {r.info.run_id: r for r in runs}
        for run in runs:
            assert run.info.status == "FINISHED"
            history = json.loads((tmp / "work" / "units" / run.data.tags["unit"] / "history.json")
                                 .read_text())  # fmt: skip
            trained_s = sum(record["epoch_time_s"] for record in history)
            duration_s = (run.info.end_time - run.info.start_time) / 1000
            assert duration_s >= trained_s > 0
            losses = client.get_metric_history(run.info.run_id, "train_loss_total")
            assert sorted(m.step for m in losses) == list(range(1, EPOCHS + 1))
            assert len(client.get_metric_history(run.info.run_id, "val_dphi_deg")) == EPOCHS
            assert "standard/test/dphi_deg" in run.data.metrics
        # CPU and memory, sampled every 2 s while a unit trains and evaluates.
        assert any("system/cpu_utilization_percentage" in r.data.metrics for r in runs)
        for row in rows:
            if "training_run_id" in row.data.tags:
                unit_run = by_id[row.data.tags["training_run_id"]]
                assert row.info.start_time == unit_run.info.start_time  # the unit's real times
                assert row.info.end_time == unit_run.info.end_time

    def test_dataset_inputs_carry_the_manifest_digest(self, reproduced, smoke_dataset):
        _, client, _ = reproduced
        manifest = hashlib.sha256((smoke_dataset / "manifest.json").read_bytes()).hexdigest()
        for name, context in (("training", "standard/train"), ("table3", "standard/test")):
            _, runs = runs_of(client, f"uavbench-smoke/{name}")
            for run in runs:
                if "mlflow.parentRunId" not in run.data.tags and name == "table3":
                    continue  # the parent reads no dataset itself
                (inp,) = run.inputs.dataset_inputs
                assert inp.dataset.digest == manifest[:32] and inp.dataset.name == "ds"
                assert str(smoke_dataset) in inp.dataset.source
                assert {t.key: t.value for t in inp.tags}["mlflow.data.context"] == context
                assert run.data.tags["dataset_manifest_sha256"] == manifest

    def test_logged_model_reproduces_the_units_predictions(self, reproduced, smoke_dataset):
        import mlflow
        import mlflow.pytorch
        import torch

        from benchmark.data import PairDataset
        from benchmark.tracking.models import pack_items

        _, client, tmp = reproduced
        _, runs = runs_of(client, "uavbench-smoke/training")
        run = next(r for r in runs if r.data.tags["head"] == "pd_re_net")
        mlflow.set_tracking_uri(client.tracking_uri)
        model = mlflow.pytorch.load_model(run.data.tags["model_uri"])
        frame = pd.read_csv(tmp / "work" / "units" / run.data.tags["unit"] / "eval"
                            / "standard__test.csv").head(3)  # fmt: skip
        data = PairDataset(smoke_dataset, "standard/test")
        items = [data[int(i)] for i in frame["index"]]
        pair = pack_items(items)  # the images and their context, as the unit's evaluation saw
        with torch.no_grad():
            out = model.eval()(pair).numpy()
        rotations = frame[[f"Rhat{r}{c}" for r in range(3) for c in range(3)]].to_numpy()
        np.testing.assert_allclose(out[:, :9], rotations, rtol=1e-4, atol=1e-5)
        translations = frame[["E_hat_m", "N_hat_m", "U_hat_m"]].to_numpy()
        np.testing.assert_allclose(out[:, 9:], translations, rtol=1e-4, atol=1e-3)
