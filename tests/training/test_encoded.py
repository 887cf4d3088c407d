"""Heads on a frozen pretrained encoder (``benchmark.training.encoded``): the encoder's weights
never move, the cached features are the encoder's own, heads on them predict what the whole
model predicts on the images, the cache is reused and invalidated, and a wrong checkpoint is a
clear error."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import torch

from benchmark.config import ConfigError
from benchmark.evaluation.sequence import FusionSettings
from benchmark.training.config import PretrainedConfig, load_train_config
from benchmark.training.identity import numbers_hash, run_key
from benchmark.training.pipeline import train_and_evaluate

BASE = [
    "data.limit_train=8", "data.limit_val=4", "data.verify=size", "model.encoder=matching",
    "model.variant=/", "optim.name=adam", "optim.batch_size=4", "optim.epochs=1", "threads=1",
    "model.attitude_options.hidden=32",
]  # fmt: skip


@pytest.fixture(scope="module")
def pretrained(smoke_dataset, tmp_path_factory):
    """A matching encoder trained end to end (Pd/Re-Net head, 1 epoch on 8 pairs)."""
    cfg = load_train_config(None, [f"data.root={smoke_dataset}", *BASE, "model.attitude=pd_re_net"])
    out = tmp_path_factory.mktemp("pretrain") / "run"
    train_and_evaluate(cfg, out, [])
    return out / "train" / "checkpoint.pt"


def _frozen_cfg(root, checkpoint, *extra):
    return load_train_config(
        None,
        [f"data.root={root}", *BASE, "model.attitude=re_net_r",
         f"pretrained.checkpoint={checkpoint}", *extra],
    )  # fmt: skip


def _encoder_state(state: dict) -> dict:
    return {k: v for k, v in state.items() if k.startswith("encoder.")}


class TestFrozenTraining:
    def test_encoder_weights_never_move_and_add_no_loss_term(
        self, smoke_dataset, pretrained, tmp_path
    ):
        cfg = _frozen_cfg(smoke_dataset, pretrained, "optim.epochs=2")
        done = train_and_evaluate(cfg, tmp_path / "run", [])
        before = torch.load(pretrained, weights_only=False)["model"]
        after = done.trained.model.state_dict()
        for k, v in _encoder_state(before).items():
            assert torch.equal(v, after[k]), k
        assert len(done.trained.history) == 2
        assert "train_loss_enc" not in done.trained.history[0]  # no encoder term: frozen

    def test_cached_features_give_the_whole_models_predictions(
        self, smoke_dataset, pretrained, tmp_path
    ):
        from benchmark.data import PairDataset
        from benchmark.evaluation.evaluate import predict
        from benchmark.training.encoded import encode_for_heads

        cfg = _frozen_cfg(smoke_dataset, pretrained)
        done = train_and_evaluate(cfg, tmp_path / "run", [])
        model = done.trained.model.eval()
        images = PairDataset(smoke_dataset, "standard/test", verify="size")
        cached = encode_for_heads(model, cfg, images)
        a = predict(model, images, batch_size=3)  # end to end, other batches than the cache
        b = predict(model, cached, batch_size=5)
        torch.testing.assert_close(a.R_hat, b.R_hat, rtol=1e-4, atol=1e-4)
        torch.testing.assert_close(a.T_hat, b.T_hat, rtol=1e-4, atol=1e-3)
        torch.testing.assert_close(a.R_gt, b.R_gt)
        torch.testing.assert_close(a.T_gt, b.T_gt)


class TestCache:
    def test_reused_then_recomputed_when_the_checkpoint_changes(
        self, smoke_dataset, pretrained, tmp_path, monkeypatch
    ):
        import shutil

        from benchmark.data import PairDataset
        from benchmark.training import encoded

        checkpoint = tmp_path / "train" / "checkpoint.pt"
        checkpoint.parent.mkdir()
        shutil.copy(pretrained, checkpoint)
        cfg = _frozen_cfg(smoke_dataset, checkpoint)
        from benchmark.training.build import image_size_of, model_factory

        dataset = PairDataset(smoke_dataset, "standard/test", verify="size")
        model = model_factory(cfg, image_size_of(dataset))()
        encoded.load_pretrained_encoder(model, cfg)
        calls = []
        real = encoded._encode
        monkeypatch.setattr(encoded, "_encode", lambda *a, **k: calls.append(1) or real(*a, **k))
        first = encoded.encode_for_heads(model, cfg, dataset)
        again = encoded.encode_for_heads(model, cfg, dataset)
        assert len(calls) == 1 and torch.equal(first.features, again.features)
        assert len(list((checkpoint.parent / "encodings").glob("*/standard__test.pt"))) == 1
        swapped = PairDataset(smoke_dataset, "standard/test", verify="size", satellite="swap")
        swap = encoded.encode_for_heads(model, cfg, swapped)
        assert len(calls) == 2 and not torch.equal(swap.features, first.features)
        state = torch.load(checkpoint, weights_only=False)
        state["epoch"] = state["epoch"] + 1  # another file: another digest
        torch.save(state, checkpoint)
        encoded.encode_for_heads(model, cfg, dataset)
        assert len(calls) == 3

    def test_items_and_per_frame_columns(self, smoke_dataset, pretrained, tmp_path):
        from benchmark.data import PairDataset
        from benchmark.evaluation.evaluate import pair_columns
        from benchmark.training.build import image_size_of, model_factory
        from benchmark.training.encoded import encode_for_heads, load_pretrained_encoder

        cfg = _frozen_cfg(smoke_dataset, pretrained)
        dataset = PairDataset(smoke_dataset, "standard/test", verify="size", satellite="swap")
        model = model_factory(cfg, image_size_of(dataset))()
        load_pretrained_encoder(model, cfg)
        enc = encode_for_heads(model, cfg, dataset)
        assert len(enc) == len(dataset)
        item, ref = enc[2], dataset[2]
        assert item["features"].shape == (model.encoder.feature_dim,)
        torch.testing.assert_close(item["R"], ref["R"])
        torch.testing.assert_close(item["T"], ref["T"])
        assert pair_columns(enc) == pair_columns(dataset)  # flights, swapped sat_index


class TestErrorsAndIdentity:
    def test_missing_checkpoint_is_named(self, smoke_dataset, tmp_path):
        cfg = _frozen_cfg(smoke_dataset, tmp_path / "nope.pt")
        with pytest.raises(ConfigError, match=r"pretrained\.checkpoint=.*nope\.pt.*no such file"):
            train_and_evaluate(cfg, tmp_path / "run", [])

    def test_another_encoder_is_refused_naming_the_option(self, smoke_dataset, pretrained,
                                                          tmp_path):  # fmt: skip
        cfg = _frozen_cfg(smoke_dataset, pretrained, "model.encoder_options.n_yaw=24")
        with pytest.raises(ConfigError, match=r"encoder_options.*n_yaw"):
            train_and_evaluate(cfg, tmp_path / "run", [])

    def test_identity_names_the_weights_not_the_path(self, smoke_dataset, pretrained):
        cfg = _frozen_cfg(smoke_dataset, pretrained)
        keyed = dataclasses.replace(cfg, pretrained=PretrainedConfig(str(pretrained), "k1"))
        moved = dataclasses.replace(keyed, pretrained=PretrainedConfig("/elsewhere.pt", "k1"))
        other = dataclasses.replace(keyed, pretrained=PretrainedConfig(str(pretrained), "k2"))
        assert run_key(keyed, "m") == run_key(moved, "m") != run_key(other, "m")
        plain = dataclasses.replace(cfg, pretrained=PretrainedConfig())
        assert numbers_hash(plain) != numbers_hash(keyed)


class TestProtocols:
    def test_a_gravity_aided_head_sits_on_a_vision_only_encoder(self, smoke_dataset, pretrained,
                                                                tmp_path):  # fmt: skip
        from benchmark.data import PairDataset
        from benchmark.training.build import image_size_of, model_factory
        from benchmark.training.encoded import encode_for_heads, load_pretrained_encoder

        dataset = PairDataset(smoke_dataset, "standard/test", verify="size")
        feats = {}
        for protocol in ("vision_only", "gravity_aided"):
            cfg = _frozen_cfg(smoke_dataset, pretrained,
                              f"model.encoder_options.protocol={protocol}")  # fmt: skip
            model = model_factory(cfg, image_size_of(dataset))()
            load_pretrained_encoder(model, cfg)
            feats[protocol] = encode_for_heads(model, cfg, dataset).features
        # The same weights: the matcher's inputs differ (priors against the gravity branch's
        # prediction), so do the features; each protocol has its own cache file.
        assert not torch.equal(feats["vision_only"], feats["gravity_aided"])


class TestJoinedTrainingSplits:
    def test_two_splits_train_as_one_set(self, smoke_dataset):
        from benchmark.data import PairDataset
        from benchmark.training.build import open_datasets
        from benchmark.training.loop import translation_labels

        cfg = load_train_config(
            None, [f"data.root={smoke_dataset}", "data.train_split=standard/train+towns/train",
                   "data.verify=size"],
        )  # fmt: skip
        train_set, _ = open_datasets(cfg)
        a = PairDataset(smoke_dataset, "standard/train", verify="size")
        b = PairDataset(smoke_dataset, "towns/train", verify="size")
        assert len(train_set) == len(a) + len(b)
        torch.testing.assert_close(train_set[len(a)]["T"], b[0]["T"])
        labels = translation_labels(train_set)
        assert labels.shape == (len(a) + len(b), 3)
        torch.testing.assert_close(labels[len(a)], b[0]["T"].double())


class TestPoseVolumeFusion:
    """The frozen matcher's own pose volume fused along long flights (issue 39): the heads are
    trained on cached features, the volume comes from a pass over the images."""

    def test_fused_and_its_frame_row_is_the_volumes_maximum(
        self, smoke_dataset, pretrained, tmp_path
    ):
        import math

        import pandas as pd

        from benchmark.data import PairDataset
        from benchmark.evaluation.volume_beliefs import gives_pose_volume
        from benchmark.geometry import angle_difference
        from benchmark.training.pipeline import (
            sequence_paths,
            volume_calibration_path,
            volume_sequence_paths,
        )

        cfg = _frozen_cfg(smoke_dataset, pretrained, "model.attitude=pd_re_net")
        split, out = "long/standard", tmp_path / "run"
        done = train_and_evaluate(cfg, out, ["standard/val", split], volume_splits=[split])
        model = done.trained.model.eval()
        assert gives_pose_volume(model)
        csv, js = volume_sequence_paths(out, split)
        assert csv.is_file() and js.is_file() and split in done.volume_sequences
        assert not sequence_paths(out, split)[0].exists()  # the heads' fusion was not asked for
        table = pd.read_csv(csv)
        assert set(table["odometry"]) == {"data", "4x"}
        assert set(table["mode"]) == {"frame", "filter", "smooth"}
        # the frame row's yaw: the yaw bin of the volume's largest marginal mass (independent
        # of the fusion code: the encoder's extras through the whole model)
        data = PairDataset(smoke_dataset, split, verify="size")
        batch = torch.utils.data.default_collate(list(data))
        with torch.no_grad():
            enc = model.encode_pairs(batch["uav"], batch["sat"], None, batch["context"])
        # the temperature fitted on standard/val (the file the run wrote)
        calibration = json.loads(volume_calibration_path(out).read_text())
        assert calibration["split"] == "standard/val" and calibration["temperature"] > 0
        # fitted on the validation frames, every one of them, and recorded with the fusion
        assert calibration["n_total"] == len(PairDataset(smoke_dataset, "standard/val"))
        recorded = json.loads(js.read_text())
        for name in ("temperature", "yaw_temperature", "position_temperature"):
            assert calibration[name] > 0 and recorded[f"volume_{name}"] == calibration[name]
        # fitted under the likelihood the fusion reads: the fusion's own outlier weight
        w = FusionSettings().outlier_weight
        assert calibration["outlier_weight"] == recorded["volume_outlier_weight"] == w
        # the frame rows are the untempered volume's maxima: a calibration changes the votes
        yaw_p = torch.logsumexp(enc.extras["log_volume"].double(), dim=(2, 3))
        expected = model.encoder.yaws.double()[yaw_p.argmax(-1)]
        frame = table[(table["mode"] == "frame") & (table["odometry"] == "data")]
        frame = frame.sort_values("index")
        got = torch.tensor(frame["yaw_hat_deg"].to_numpy()) * math.pi / 180
        assert float(angle_difference(got, expected[frame["index"].to_numpy()]).abs().max()) < 1e-6
        # the per-frame error column scores that estimate against the truth
        truth = torch.tensor(data.poses["yaw"].to_numpy())[frame["index"].to_numpy()]
        err = angle_difference(got, truth).abs() * 180 / math.pi
        np.testing.assert_allclose(frame["dpsi_deg"].to_numpy(), err.numpy(), atol=1e-6)
        # a second call reads the files back (nothing is written again)
        written = csv.stat().st_mtime_ns
        again = train_and_evaluate(cfg, out, ["standard/val", split], volume_splits=[split])
        summary = again.volume_sequences[split][0]
        assert (
            summary["seq_smooth_dpsi_deg"] == done.volume_sequences[split][0]["seq_smooth_dpsi_deg"]
        )
        assert csv.stat().st_mtime_ns == written

    def test_joint_fusion_is_written_beside_the_marginal_one(
        self, smoke_dataset, pretrained, tmp_path
    ):
        import pandas as pd

        from benchmark.training.pipeline import joint_sequence_paths, volume_sequence_paths

        cfg = _frozen_cfg(smoke_dataset, pretrained, "model.attitude=pd_re_net")
        split, out = "long/standard", tmp_path / "run"
        done = train_and_evaluate(cfg, out, ["standard/val", split], joint_splits=[split])
        csv, js = joint_sequence_paths(out, split)
        assert csv.is_file() and js.is_file() and split in done.joint_sequences
        assert not done.volume_sequences  # the marginal fusion was not asked for (but is kept)
        marginal = pd.read_csv(volume_sequence_paths(out, split)[0])
        table = pd.read_csv(csv)
        assert list(table.columns) == list(marginal.columns)
        # long flights: the dataset's odometry, and the 4x stress odometry (causal filter only,
        # for the figure), as the marginal fusion has
        assert set(table["odometry"]) == set(marginal["odometry"]) == {"data", "4x"}
        stress = table[table["odometry"] == "4x"]
        assert set(stress["mode"]) == {"frame", "filter"}
        assert "seq4x_filter_dpsi_deg" in done.joint_sequences[split][0]
        table = table[table["odometry"] == "data"]
        # the same frames and the same per-frame estimates as the marginal fusion's
        frame = table[table["mode"] == "frame"].sort_values("index")
        ref = marginal[(marginal["mode"] == "frame") & (marginal["odometry"] == "data")]
        np.testing.assert_array_equal(
            frame["yaw_hat_deg"].to_numpy(), ref.sort_values("index")["yaw_hat_deg"].to_numpy()
        )
        written = csv.stat().st_mtime_ns
        again = train_and_evaluate(cfg, out, ["standard/val", split], joint_splits=[split])
        assert again.joint_sequences[split][0] == done.joint_sequences[split][0]
        assert csv.stat().st_mtime_ns == written
