"""Divergence fails the run (issue 14 item 5): a non-finite training loss at any step, non-finite
weights after the last step, a non-finite validation or evaluation number. The command exits 1
with one line naming when, which term and the fix; the checkpoint written before stays intact; the
MLflow run ends FAILED.

The issue's case is replayed as reported: ``uavbench train --set optim.lr=1e6`` with one short
epoch (one optimiser step), which used to finish with exit 0, ``val_loss_total=inf`` and
dE 1.9e24 m.
"""

from __future__ import annotations

import hashlib
import math

import pytest
import torch
from torch.utils.data import Dataset

from benchmark.cli import main
from benchmark.config import apply_overrides
from benchmark.data import PairDataset
from benchmark.training import CHECKPOINT, TrainConfig, load_checkpoint, model_factory, train
from benchmark.training.loop import DivergenceError, check_finite, non_finite_term

TINY = ["model.width=0.25", "model.variant=/", "optim.batch_size=4", "threads=1"]


def tiny_cfg(root, *overrides: str) -> TrainConfig:
    return apply_overrides(TrainConfig(), [f"data.root={root}", *TINY, *overrides])


def train_cli(root, out, *overrides: str, track: list[str] | None = None) -> int:
    args = ["train", "--quiet", "--out", str(out)]
    args += track if track is not None else ["--no-track"]
    for item in [f"data.root={root}", *TINY, *overrides]:
        args += ["--set", item]
    return main(args)


def one_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    return err


def fresh_store(tmp_path, capsys):
    """An MLflow sqlite store created before the command runs (MLflow logs its table creation)."""
    import mlflow

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    client = mlflow.MlflowClient(uri)
    client.search_experiments()
    capsys.readouterr()
    return uri, client


def sha256(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


class PoisonAfter(Dataset):
    """``base`` whose translation labels become NaN after ``clean`` item reads: a loss that goes
    non-finite at a known later step, like a divergence, without changing the model."""

    def __init__(self, base: Dataset, clean: int) -> None:
        self.base, self.clean, self.reads = base, clean, 0
        self.poses = base.poses  # translation statistics read from the labels, as for the base

    def __len__(self) -> int:
        return len(self.base)

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        item = dict(self.base[i])
        self.reads += 1
        if self.reads > self.clean:
            item["T"] = torch.full_like(item["T"], math.nan)
        return item


class TestIssueCase:
    def test_lr_1e6_one_short_epoch_fails_the_tracked_run(self, reference, tmp_path, capsys):
        """One optimiser step, then validation: val_loss_tran is inf -> exit 1, one line, FAILED
        in MLflow with the reason (tag and note), no checkpoint of the diverged epoch."""
        uri, client = fresh_store(tmp_path, capsys)
        code = train_cli(reference, tmp_path / "o", "optim.lr=1e6", "optim.epochs=1",
                         "data.limit_train=4", track=["--tracking-uri", uri,
                                                      "--experiment", "div"])  # fmt: skip
        err = one_line(capsys)
        assert code == 1
        assert err.startswith("uavbench train: diverged: non-finite validation loss or metric ")
        assert "at validation after epoch 1: val_loss_tran=inf" in err
        assert "lower optim.lr (now 1e+06)" in err and "marked FAILED in " + uri in err
        assert not (tmp_path / "o" / "train" / CHECKPOINT).exists()  # nothing diverged is kept
        (run,) = client.search_runs([client.get_experiment_by_name("div").experiment_id])
        assert run.info.status == "FAILED"  # with the reason as a tag and in its note
        assert "DivergenceError: diverged: " in run.data.tags["failure_reason"]
        assert "val_loss_tran=inf" in run.data.tags["failure_reason"]
        assert "lower optim.lr" in run.data.tags["mlflow.note.content"]

    def test_without_validation_the_evaluation_fails_it(self, reference, tmp_path, capsys):
        """No validation split: the finished checkpoint's model gives inf losses on the test split;
        the run fails before its summary is written, and `uavbench evaluate` of that checkpoint
        exits 1 naming the non-finite metrics."""
        out = tmp_path / "o"
        code = train_cli(reference, out, "optim.lr=1e6", "optim.epochs=1", "data.limit_train=4",
                         "data.val_split=None")  # fmt: skip
        err = one_line(capsys)
        assert code == 1
        assert "non-finite evaluation metric at evaluation of standard/test: loss_tran=inf" in err
        assert not list((out / "eval").glob("*.json"))  # a rerun evaluates again
        ckpt = out / "train" / CHECKPOINT
        assert main(["evaluate", "--quiet", "--checkpoint", str(ckpt), "--data-root",
                     str(reference), "--out", str(tmp_path / "e")]) == 1  # fmt: skip
        err = capsys.readouterr().err
        assert "standard/test: non-finite loss_total, loss_tran" in err and "diverged" in err


class TestAnyStep:
    def test_later_step_names_epoch_step_and_term_keeps_checkpoint(self, reference, tmp_path):
        """Epoch 1 is clean and checkpointed; the loss goes NaN at epoch 2 step 2: the error names
        both and the translation term, and the epoch-1 checkpoint is byte for byte unchanged."""
        cfg = tiny_cfg(reference, "optim.epochs=2", "data.val_split=None", "optim.lr=0.01")
        base = PairDataset(reference, "standard/train", verify="size")
        data = PoisonAfter(base, clean=len(base) + 4)  # epoch 2's first batch of 4 is clean
        hashes = []

        def snapshot(epoch, record):
            hashes.append(sha256(tmp_path / CHECKPOINT))

        with pytest.raises(DivergenceError) as caught:
            train(cfg, model_factory(cfg, 32), data, None, tmp_path, on_epoch_end=snapshot,
                  progress=False)  # fmt: skip
        err = caught.value
        assert (err.where, err.term) == ("epoch 2, step 2", "tran")
        assert math.isnan(err.values["tran"]) and math.isfinite(err.values["att"])
        assert "non-finite training loss at epoch 2, step 2: tran=nan" in str(err)
        assert len(hashes) == 1 and sha256(tmp_path / CHECKPOINT) == hashes[0]
        assert load_checkpoint(tmp_path / CHECKPOINT)["epoch"] == 1

    def test_weights_broken_by_the_last_step_are_caught(self, reference, tmp_path):
        """A finite loss whose gradient is NaN: the one step leaves NaN weights, which no later
        loss would reveal; the end-of-epoch weight check fails the run and writes nothing."""
        cfg = tiny_cfg(reference, "optim.epochs=1", "data.val_split=None", "data.limit_train=4")
        build = model_factory(cfg, 32)

        def factory():
            model = build()
            weight = model.translation_head.net[0].weight  # any parameter will do
            weight.register_hook(lambda g: torch.full_like(g, math.nan))
            return model

        data = PairDataset(reference, "standard/train", verify="size")
        with pytest.raises(DivergenceError, match=r"non-finite weights at the end of epoch 1 "
                           r"\(\d+ tensors\): translation_head\.net\.0\.weight=nan"):  # fmt: skip
            train(cfg, factory, torch.utils.data.Subset(data, range(4)), None, tmp_path,
                  progress=False)  # fmt: skip
        assert not (tmp_path / CHECKPOINT).exists()


class TestCheckFinite:
    def test_component_named_before_total(self):
        values = {"total": math.inf, "att": 3.0, "tran": math.inf}
        assert non_finite_term(values) == "tran"
        overflowed = {"total": math.nan, "att": 1.0}  # finite parts, non-finite sum
        assert non_finite_term(overflowed) == "total"
        assert non_finite_term({"total": 1.0, "att": 1.0}) is None

    def test_only_the_given_keys_count(self):
        values = {"dE_m": 1.0, "spearman_unc_err": math.nan}
        check_finite("evaluation metric", "x", values, 0.1, keys=["dE_m"])  # NaN rho is legal
        with pytest.raises(DivergenceError, match="spearman_unc_err=nan"):
            check_finite("evaluation metric", "x", values, 0.1)

    def test_message_is_one_line_with_the_fix(self):
        values = {"total": math.inf, "att": 2.5, "tran": math.inf}
        with pytest.raises(DivergenceError) as caught:
            check_finite("training loss", "epoch 3, step 7", values, 0.5)
        text = str(caught.value)
        assert "\n" not in text
        assert text.startswith("diverged: non-finite training loss at epoch 3, step 7: tran=inf")
        assert "(total=inf, att=2.5, tran=inf)" in text and "lower optim.lr (now 0.5)" in text
