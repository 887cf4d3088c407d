"""References evaluated like models on the smoke dataset: columns, swap probe, failure rule, CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest

from benchmark.cli import main
from benchmark.data import PairDataset
from benchmark.evaluation import constant_predictor
from benchmark.references import (
    Estimate,
    Reference,
    create_reference,
    default_train_split,
    evaluate_reference,
    fallback_pose,
)


class AlwaysFails(Reference):
    name = "always_fails"
    title = "Always fails"

    def estimate(self, frame):
        return Estimate(np.eye(3), np.zeros(3), failed=True)


@pytest.fixture(scope="module")
def smoke_test_split(smoke_dataset):
    return PairDataset(smoke_dataset, "standard/test", verify="size")


class TestEvaluateReference:
    def test_columns_and_given_values(self, smoke_dataset, smoke_test_split):
        train = PairDataset(smoke_dataset, "standard/train", verify="size")
        summary, frame = evaluate_reference(create_reference("geometry_oracle"), smoke_test_split)
        _, constant = constant_predictor(train, smoke_test_split)
        assert set(constant.columns) <= set(frame.columns)
        assert {"city", "flight", "sat_index", "reference_failed"} <= set(frame.columns)
        for col in ("dE_m", "dN_m", "dU_m", "dtheta_deg", "dgamma_deg"):
            assert np.allclose(frame[col], 0.0, atol=1e-4), col  # given: 0 by construction
        assert np.allclose(frame["dpsi_deg"], frame["dphi_deg"], atol=1e-4)
        for key in ("dpsi_deg", "median_dpsi_deg", "acc10", "failure_rate", "acc_5m_5deg"):
            assert key in summary

    def test_swap_serves_another_image_and_keeps_the_labels(self, smoke_dataset):
        true = PairDataset(smoke_dataset, "standard/test", verify="size")
        swap = PairDataset(smoke_dataset, "standard/test", verify="size", satellite="swap")
        ref = create_reference("geometry_oracle")
        _, f_true = evaluate_reference(ref, true)
        _, f_swap = evaluate_reference(ref, swap)
        assert (f_true["sat_index"] != f_swap["sat_index"]).all()
        assert np.allclose(f_true["yaw_deg"], f_swap["yaw_deg"])

    def test_failed_frames_get_the_constant_predictors_pose(self, smoke_dataset, smoke_test_split):
        train = PairDataset(smoke_dataset, "standard/train", verify="size")
        summary, frame = evaluate_reference(
            AlwaysFails(), smoke_test_split, fallback=fallback_pose(train)
        )
        _, constant = constant_predictor(train, smoke_test_split)
        assert summary["failure_rate"] == 1.0
        for col in ("dE_m", "dN_m", "dU_m", "dtheta_deg", "dgamma_deg", "dpsi_deg", "dphi_deg"):
            assert np.allclose(frame[col], constant[col], atol=1e-6), col

    def test_default_train_split(self):
        assert default_train_split("towns/test") == "towns/train"
        assert default_train_split("generalized/test") == "standard/train"
        assert default_train_split("height600/test") == "height600/train"
        assert default_train_split("pitch-40to-50/test") == "standard/train"
        assert default_train_split("towns/test", ["standard/train"]) == "standard/train"


class TestReferenceCommand:
    def test_writes_predictions_and_summary(self, smoke_dataset, tmp_path, capsys):
        out = tmp_path / "ref" / "towns_test__swap.csv"
        argv = ["reference", "gravity_template", "--data", str(smoke_dataset), "--split",
                "towns/test", "--satellite", "swap", "--out", str(out), "--quiet",
                "--set", "step_deg=15", "--limit", "2"]  # fmt: skip
        assert main(argv) == 0
        assert "not learned" in capsys.readouterr().out
        record = json.loads(out.with_suffix(".json").read_text())
        assert record["train_split"] == "towns/train" and record["satellite"] == "swap"
        assert record["options"]["step_deg"] == 15.0 and record["summary"]["n"] == 2
        assert out.is_file()

    @pytest.mark.parametrize(
        ("args", "message"),
        [
            (["geometry_oracle", "--split", "nope/test"], "available"),
            (["sift_magic", "--split", "standard/test"], "known"),
            (["feature_pnp", "--split", "standard/test", "--set", "foo=1"], "foo"),
            (["feature_pnp", "--split", "standard/test", "--set", "detector"], "KEY=VALUE"),
        ],
    )
    def test_bad_input_is_one_line_exit_2(self, smoke_dataset, capsys, args, message):
        assert main(["reference", *args[:1], "--data", str(smoke_dataset), *args[1:]]) == 2
        err = capsys.readouterr().err
        assert message in err and "Traceback" not in err
