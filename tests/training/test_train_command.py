"""``uavbench train``: argument errors (fast) and a full run on a smoke dataset (slow)."""

from __future__ import annotations

import json
import subprocess
import sys

import pandas as pd
import pytest

from benchmark.cli import main


class TestTrainCommandErrors:
    def test_no_dataset(self, capsys):
        assert main(["train"]) == 2
        assert "data.root" in capsys.readouterr().err

    def test_bad_override(self, capsys):
        assert main(["train", "--set", "optim.batch_size=many"]) == 2
        assert "optim.batch_size='many': expected int" in capsys.readouterr().err

    def test_unknown_key(self, capsys):
        assert main(["train", "--set", "optim.learning_rate=1"]) == 2
        assert "unknown config key 'optim.learning_rate'" in capsys.readouterr().err

    def test_bad_yaml(self, tmp_path, capsys):
        (tmp_path / "c.yaml").write_text("optim:\n  epochs: -1\n")
        assert main(["train", "--config", str(tmp_path / "c.yaml")]) == 2
        err = capsys.readouterr().err
        assert "c.yaml" in err and "epochs must be >= 1" in err


class TestImportDirection:
    def test_training_and_evaluation_do_not_import_tracking(self):
        code = (
            "import sys, benchmark.training, benchmark.evaluation, benchmark.evaluation.evaluate\n"
            "bad = [m for m in sys.modules if m.startswith(('benchmark.tracking', 'mlflow'))]\n"
            "assert not bad, bad\n"
        )
        subprocess.run([sys.executable, "-c", code], check=True)


@pytest.fixture(scope="module")
def smoke_dataset(tmp_path_factory):
    from benchmark.data.profiles import DATA_PROFILES
    from benchmark.data.writer import simulate_dataset

    root = tmp_path_factory.mktemp("smoke") / "ds"
    cache = tmp_path_factory.mktemp("cities")
    simulate_dataset(root, DATA_PROFILES["smoke"], 0, workers=1, cache_dir=cache, progress=False)
    return root


@pytest.mark.slow
class TestLabelsFromPairDataset:
    def test_dataset_labels_match_items(self, smoke_dataset):
        import torch

        from benchmark.data import PairDataset
        from benchmark.evaluation.constant import constant_predictor, dataset_labels

        ds = PairDataset(smoke_dataset, "standard/train")
        sub = torch.utils.data.Subset(ds, [3, 0, 5])
        R, T, index = dataset_labels(sub)
        items = [sub[i] for i in range(3)]
        torch.testing.assert_close(R.float(), torch.stack([it["R"] for it in items]))
        torch.testing.assert_close(T.float(), torch.stack([it["T"] for it in items]))
        assert index.tolist() == [3, 0, 5]
        summary, _ = constant_predictor(ds, PairDataset(smoke_dataset, "standard/test"))
        assert 0 < summary["dphi_deg"] < 180


@pytest.mark.slow
class TestTrainCommandEndToEnd:
    def test_train_track_resume_and_fail(self, smoke_dataset, tmp_path, monkeypatch):
        from mlflow.tracking import MlflowClient

        monkeypatch.chdir(tmp_path)
        monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
        base = [
            "train",
            "--quiet",
            "--set",
            f"data.root={smoke_dataset}",
            "--set",
            "model.width=0.25",
            "--set",
            "optim.batch_size=4",
            "--set",
            "threads=1",
            "--out",
            str(tmp_path / "out"),
        ]
        assert main([*base, "--set", "optim.epochs=2"]) == 0
        # The files of a reproduce unit (benchmark.training.pipeline): true and swapped satellite.
        pred = pd.read_csv(tmp_path / "out" / "eval" / "standard__test.csv")
        assert len(pred) > 0 and {"dpsi_deg", "dphi_deg", "uncertainty"} <= set(pred.columns)
        swap = json.loads((tmp_path / "out" / "eval" / "standard__test__swap.json").read_text())
        assert "swap_dphi_diff_deg" in swap
        history = json.loads((tmp_path / "out" / "history.json").read_text())
        assert [h["epoch"] for h in history] == [1, 2]

        client = MlflowClient(f"sqlite:///{tmp_path / 'mlflow.db'}")
        exp = client.get_experiment_by_name("train")
        (run,) = client.search_runs([exp.experiment_id])
        assert run.info.status == "FINISHED"
        assert run.data.params["optim.batch_size"] == "4"
        assert run.data.params["model.attitude"] == "pd_re_net"
        assert run.data.tags["head"] == "pd_re_net" and len(run.data.tags["run_key"]) == 16
        assert run.data.tags["model_key"] == run.data.tags["run_key"]
        steps = [m.step for m in client.get_metric_history(run.info.run_id, "train_loss_total")]
        assert steps == [1, 2]
        assert "standard/test/dphi_deg" in run.data.metrics
        assert "standard/test/swap/dphi_deg" in run.data.metrics

        # uavbench evaluate on the checkpoint reproduces the predictions byte for byte.
        first = (tmp_path / "out" / "eval" / "standard__test.csv").read_bytes()
        ckpt = str(tmp_path / "out" / "train" / "checkpoint.pt")
        assert (
            main(["evaluate", "--quiet", "--checkpoint", ckpt, "--out", str(tmp_path / "ev")]) == 0
        )
        assert (tmp_path / "ev" / "standard_test.csv").read_bytes() == first
        metrics = json.loads((tmp_path / "ev" / "metrics.json").read_text())
        assert metrics["standard/test"]["dphi_deg"] == pytest.approx(
            run.data.metrics["standard/test/dphi_deg"]
        )

        # The same config again: found in the store, not rerun.
        assert main([*base, "--set", "optim.epochs=2"]) == 0
        assert len(client.search_runs([exp.experiment_id])) == 1

        # A diverging config: exit 1, run FAILED.
        assert main([*base, "--set", "optim.lr=1e30", "--out", str(tmp_path / "bad")]) == 1
        statuses = sorted(r.info.status for r in client.search_runs([exp.experiment_id]))
        assert statuses == ["FAILED", "FINISHED"]
