"""The one train-then-evaluate path (``uavbench train`` and every reproduce unit): files, swap
probe, resume from the files already written."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from benchmark.training import load_train_config, train_and_evaluate
from benchmark.training.pipeline import eval_key, eval_keys, eval_paths, split_filename


class TestKeys:
    def test_eval_keys_and_file_names(self, tmp_path):
        assert eval_keys(["standard/test", "height600/test"]) == [
            "standard/test", "standard/test/swap", "height600/test", "height600/test/swap",
        ]  # fmt: skip
        assert split_filename("standard/test/swap") == "standard__test__swap"
        csv, js = eval_paths(tmp_path, eval_key("standard/test", "swap"))
        assert (csv.name, js.name) == ("standard__test__swap.csv", "standard__test__swap.json")
        with pytest.raises(ValueError, match="satellite must be one of"):
            eval_key("standard/test", "grey")


@pytest.mark.slow
class TestTrainAndEvaluate:
    def test_files_swap_and_resume(self, smoke_dataset, tmp_path, monkeypatch):
        cfg = load_train_config(
            None,
            [
                f"data.root={smoke_dataset}", "data.limit_train=8", "data.limit_val=4",
                "model.width=0.25", "model.variant=/", "model.attitude=re_net_r",
                "model.attitude_options.hidden=32", "optim.name=adam", "optim.batch_size=4",
                "optim.epochs=1", "threads=1",
            ],
        )  # fmt: skip
        out = tmp_path / "run"
        done = train_and_evaluate(cfg, out, ["standard/test"])
        assert set(done.metrics) == {"standard/test", "standard/test/swap"}
        assert load_train_config(out / "config.yaml") == cfg
        assert (out / "train" / "checkpoint.pt").is_file()
        assert [h["epoch"] for h in json.loads((out / "history.json").read_text())] == [1]
        true = pd.read_csv(out / "eval" / "standard__test.csv")
        assert len(true) == done.metrics["standard/test"]["n"]
        swap = done.metrics["standard/test/swap"]
        assert {"swap_dphi_diff_deg", "swap_dpsi_diff_deg"} <= set(swap)
        written = json.loads((out / "eval" / "standard__test__swap.json").read_text())
        assert written == pytest.approx(swap, nan_ok=True)

        # Again: nothing is trained or evaluated; the numbers are read back.
        import benchmark.evaluation.evaluate as evaluation

        def refuse(*args, **kwargs):
            raise AssertionError("evaluated again")

        monkeypatch.setattr(evaluation, "evaluate", refuse)
        again = train_and_evaluate(cfg, out, ["standard/test"])
        assert again.trained.resumed_from_epoch == 1
        assert again.metrics.keys() == done.metrics.keys()
        for key, summary in done.metrics.items():
            assert again.metrics[key] == pytest.approx(summary, nan_ok=True)
        # A missing summary is recomputed, and only that one.
        monkeypatch.undo()
        (out / "eval" / "standard__test__swap.json").unlink()
        third = train_and_evaluate(cfg, out, ["standard/test"])
        assert third.metrics["standard/test/swap"] == pytest.approx(swap, nan_ok=True)
