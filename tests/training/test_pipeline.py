"""The one train-then-evaluate path (``uavbench train`` and every reproduce unit): files, swap
probe, resume from the files already written."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from benchmark.evaluation.sequence import FusionSettings
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


def _tiny_config(root, *extra):
    """One epoch of Re-Net-R at width 0.25 on 8 smoke pairs: a unit in seconds."""
    return load_train_config(
        None,
        [
            f"data.root={root}", "data.limit_train=8", "data.limit_val=4",
            "model.width=0.25", "model.variant=/", "model.attitude=re_net_r",
            "model.attitude_options.hidden=32", "optim.name=adam", "optim.batch_size=4",
            "optim.epochs=1", "threads=1", *extra,
        ],
    )  # fmt: skip


@pytest.mark.slow
class TestTrainAndEvaluate:
    def test_files_swap_and_resume(self, smoke_dataset, tmp_path, monkeypatch):
        cfg = _tiny_config(smoke_dataset)
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


class TestFusionFromTheEvaluationPass:
    def test_fusion_reads_the_evaluation_pass(self, smoke_dataset, tmp_path, monkeypatch):
        """A fused split's beliefs come from its true image's evaluation pass (no second pass
        of the model), and fuse to exactly what a pass of their own gives (the path of a unit
        evaluated before fusion existed)."""
        from benchmark.evaluation import evaluate as evaluation
        from benchmark.evaluation import sequence_eval
        from benchmark.training.pipeline import beliefs_path, sequence_paths

        cfg = _tiny_config(smoke_dataset)
        split = "long/standard"
        passes = []
        real_predict = evaluation.predict

        def counted(*args, **kwargs):
            passes.append(kwargs.get("desc"))
            return real_predict(*args, **kwargs)

        monkeypatch.setattr(evaluation, "predict", counted)
        monkeypatch.setattr(sequence_eval, "predict", counted)
        out = tmp_path / "one-pass"
        done = train_and_evaluate(cfg, out, ["standard/test", split], fuse_splits=[split])
        assert not any(str(d).startswith("beliefs") for d in passes)  # no pass of its own
        assert not beliefs_path(out, split).exists()  # an intermediate, removed
        csv, _ = sequence_paths(out, split)
        one_pass = pd.read_csv(csv)

        # The same unit's fusion from a pass of its own: files gone, beliefs not recorded.
        csv.unlink()
        passes.clear()
        again = train_and_evaluate(cfg, out, ["standard/test", split], fuse_splits=[split])
        assert [d for d in passes if str(d).startswith("beliefs")] == [f"beliefs {split}"]
        # equal up to the evaluation CSV's 10 significant digits
        pd.testing.assert_frame_equal(pd.read_csv(csv), one_pass, check_exact=False, rtol=1e-7)
        summary, _ = done.sequences[split]
        assert again.sequences[split][0] == pytest.approx(summary, rel=1e-7, nan_ok=True)
        assert {"seq_filter_dpsi_deg", "seq4x_smooth_dpsi_deg"} <= set(summary)


@pytest.mark.slow
class TestHeadPositionDensity:
    def test_the_laplace_heads_own_density_and_an_older_fusion_redone(self, smoke_dataset,
                                                                     tmp_path):  # fmt: skip
        """A translation head with ``position_log_prob`` (Laplace) fuses its own density, not
        the calibrated Gaussian; a fusion written before that (no flag) is done again."""
        import json

        from benchmark.evaluation.sequence_eval import POSITION_FROM_HEAD
        from benchmark.training.pipeline import sequence_paths

        split, out = "long/standard", tmp_path / "laplace"
        cfg = _tiny_config(smoke_dataset, "model.translation=laplace")
        done = train_and_evaluate(cfg, out, ["standard/test", split], fuse_splits=[split])
        assert done.sequences[split][0][POSITION_FROM_HEAD] == 1.0
        csv, js = sequence_paths(out, split)
        own = pd.read_csv(csv)
        # a translation head without a density of its own: the calibrated one
        regression = _tiny_config(smoke_dataset)
        other = train_and_evaluate(regression, tmp_path / "regression", ["standard/test", split],
                                   fuse_splits=[split])  # fmt: skip
        assert other.sequences[split][0][POSITION_FROM_HEAD] == 0.0
        # an older fusion of the Laplace unit (no flag): read, found stale, fused again
        stale = json.loads(js.read_text())
        del stale[POSITION_FROM_HEAD]
        js.write_text(json.dumps(stale))
        csv.write_text(csv.read_text())  # still there: only the flag says it is stale
        again = train_and_evaluate(cfg, out, ["standard/test", split], fuse_splits=[split])
        assert again.sequences[split][0][POSITION_FROM_HEAD] == 1.0
        pd.testing.assert_frame_equal(pd.read_csv(csv), own, check_exact=False, rtol=1e-7)


class TestFusionDone:
    """Fused files count as done when complete; a pose volume's only when fused with the
    calibrated volume (its summary holds the temperatures and the outlier weight they were
    fitted under, the fusion's own)."""

    @staticmethod
    def write(paths, out, split: str, summary: dict) -> None:
        csv, js = paths(out, split)
        csv.parent.mkdir(parents=True, exist_ok=True)
        csv.write_text("index\n0\n")
        js.write_text(json.dumps(summary))

    def test_missing_files_are_not_done(self, tmp_path):
        from benchmark.training.pipeline import fusion_done, sequence_paths

        assert not fusion_done(sequence_paths, tmp_path, "long/standard")
        self.write(sequence_paths, tmp_path, "long/standard", {"seq_filter_dpsi_mean_deg": 1.0})
        sequence_paths(tmp_path, "long/standard")[0].unlink()  # the JSON alone: not done
        assert not fusion_done(sequence_paths, tmp_path, "long/standard")

    def test_a_heads_fusion_needs_no_temperature(self, tmp_path):
        from benchmark.training.pipeline import fusion_done, sequence_paths

        self.write(sequence_paths, tmp_path, "long/standard", {"seq_filter_dpsi_mean_deg": 1.0})
        assert fusion_done(sequence_paths, tmp_path, "long/standard")

    @pytest.mark.parametrize("kind", ["volume_sequence_paths", "joint_sequence_paths"])
    def test_a_volume_fused_before_calibration_is_stale(self, tmp_path, kind):
        from benchmark.training import pipeline

        paths = getattr(pipeline, kind)
        self.write(paths, tmp_path, "long/towns", {"seq_filter_dpsi_mean_deg": 1.0})
        assert not pipeline.fusion_done(paths, tmp_path, "long/towns")
        self.write(paths, tmp_path, "long/towns", {"volume_temperature": 1.9})  # one of three
        assert not pipeline.fusion_done(paths, tmp_path, "long/towns")
        temperatures = {f"volume_{k}": 1.0 for k in pipeline.VOLUME_TEMPERATURES}
        self.write(paths, tmp_path, "long/towns", temperatures)  # fitted without the outlier share
        assert not pipeline.fusion_done(paths, tmp_path, "long/towns")
        other = {**temperatures, "volume_outlier_weight": 0.1}  # under another outlier share
        self.write(paths, tmp_path, "long/towns", other)
        assert not pipeline.fusion_done(paths, tmp_path, "long/towns")
        every = {**temperatures, "volume_outlier_weight": FusionSettings().outlier_weight}
        self.write(paths, tmp_path, "long/towns", every)
        assert pipeline.fusion_done(paths, tmp_path, "long/towns")
