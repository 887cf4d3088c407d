"""evaluate(): a model over a dataset -> predictions CSV + summary, through the head contract."""

from __future__ import annotations

import math

import pandas as pd
import pytest
import torch
from scipy.spatial.transform import Rotation
from torch import nn

from benchmark.evaluation.evaluate import evaluate, predict
from benchmark.models import PoseOutput


class Items(torch.utils.data.Dataset):
    """n items in PairDataset's format; labels from scipy rotations about the satellite frame."""

    def __init__(self, n: int) -> None:
        rot = Rotation.from_euler("ZXY", [[10.0 * i, -20.0, 5.0] for i in range(n)], degrees=True)
        sat = Rotation.from_euler("ZXY", [0.0, -90.0, 0.0], degrees=True).as_matrix()
        self.R = torch.from_numpy(rot.as_matrix() @ sat.T).float()
        self.T = torch.arange(3 * n, dtype=torch.float32).view(n, 3)

    def __len__(self) -> int:
        return len(self.R)

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        return {
            "uav": torch.full((3, 8, 8), float(i)),
            "sat": torch.zeros(3, 8, 8),
            "sat_id": torch.tensor(0),
            "R": self.R[i],
            "T": self.T[i],
            "index": torch.tensor(100 + i),
        }


class FakeHead(nn.Module):
    """Contract-only probabilistic head: decode gives Rz(3 i deg) R_gt (so dphi = 3 i deg),
    log_prob = -i, uncertainty = i."""

    is_probabilistic = True

    def __init__(self, dataset: Items) -> None:
        super().__init__()
        self.dataset = dataset

    def decode(self, raw):
        i = raw.long()
        Rz = torch.from_numpy(
            Rotation.from_euler(
                "z", 3.0 * i.numpy().astype(float)[:, None], degrees=True
            ).as_matrix()
        ).float()
        return Rz @ self.dataset.R[i]

    def log_prob(self, raw, R):
        return -raw

    def uncertainty(self, raw):
        return raw


class FakeTranslation(nn.Module):
    def decode(self, raw):
        return raw + 1.0


class FakeModel(nn.Module):
    def __init__(self, dataset: Items) -> None:
        super().__init__()
        self.attitude_head = FakeHead(dataset)
        self.translation_head = FakeTranslation()
        self.dataset = dataset

    def forward(self, uav, sat, sat_ids=None):
        i = uav[:, 0, 0, 0]
        return PoseOutput(attitude=i, translation=self.dataset.T[i.long()])

    def decode(self, out):
        return self.attitude_head.decode(out.attitude), self.translation_head.decode(
            out.translation
        )

    def loss(self, out, R_gt, T_gt):
        return {"total": out.attitude.mean() * 0 + 2.0}


class TestEvaluate:
    def test_summary_and_csv_from_contract(self, tmp_path):
        data = Items(7)
        model = FakeModel(data).train()
        summary, _ = evaluate(model, data, out_csv=tmp_path / "pred.csv", batch_size=3)
        assert model.training  # mode restored
        back = pd.read_csv(tmp_path / "pred.csv")
        assert list(back["index"]) == list(range(100, 107))
        # Rz(3i deg) @ R_gt is 3i deg away from R_gt (Eq. 16): 0, 3, ..., 18 (no threshold ties).
        assert back["dphi_deg"].tolist() == pytest.approx(list(range(0, 21, 3)), abs=1e-4)
        assert summary["dphi_deg"] == pytest.approx(9.0, abs=1e-4)
        assert (summary["acc5"], summary["acc10"], summary["acc30"]) == (2 / 7, 4 / 7, 1.0)
        assert summary["dE_m"] == pytest.approx(1.0) and summary["dU_m"] == pytest.approx(1.0)
        assert summary["loglik"] == pytest.approx(-3.0)
        assert summary["spearman_unc_err"] == pytest.approx(1.0)
        assert summary["loss_total"] == pytest.approx(2.0)
        assert summary["n"] == 7

    def test_regression_model_has_no_probabilistic_columns(self):
        data = Items(4)
        model = FakeModel(data)
        model.attitude_head.is_probabilistic = False
        pred = predict(model, data, batch_size=2)
        assert pred.log_likelihood is None and pred.uncertainty is None
        summary, frame = evaluate(model, data)
        assert "loglik" not in summary and "uncertainty" not in frame

    @pytest.mark.parametrize(
        ("flag", "present", "absent"),
        [
            ("gives_log_prob", "log_likelihood", "uncertainty"),
            ("gives_uncertainty", "uncertainty", "log_likelihood"),
        ],
    )
    def test_capability_flags_without_grid_contract(self, flag, present, absent):
        # A density head that is not a grid distribution (Bingham, matrix Fisher) declares only
        # what it gives; evaluation asks for exactly that.
        data = Items(4)
        model = FakeModel(data)
        model.attitude_head.is_probabilistic = False
        setattr(model.attitude_head, flag, True)
        pred = predict(model, data, batch_size=2)
        assert getattr(pred, present) is not None and getattr(pred, absent) is None

    def test_empty(self):
        with pytest.raises(ValueError, match="empty"):
            predict(FakeModel(Items(1)), torch.utils.data.Subset(Items(1), []))


class TestEvaluateRealModels:
    @pytest.mark.parametrize("attitude", ["pd_re_net", "re_net_r"])
    def test_real_heads(self, attitude):
        from benchmark.models import create_model

        class Tiny(torch.utils.data.Dataset):
            def __len__(self):
                return 3

            def __getitem__(self, i):
                item = Items(3)[i]
                item["uav"] = torch.rand(3, 32, 32, generator=torch.Generator().manual_seed(i))
                item["sat"] = torch.zeros(3, 32, 32)
                return item

        torch.manual_seed(0)
        model = create_model(width=0.25, input_size=32, attitude=attitude, variant="/")
        summary, frame = evaluate(model, Tiny(), batch_size=2)
        assert 0 <= summary["dphi_deg"] <= 180 and math.isfinite(summary["dpsi_deg"])
        assert ("loglik" in summary) == (attitude == "pd_re_net")
        assert len(frame) == 3
