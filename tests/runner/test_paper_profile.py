"""The ``paper`` profile is for a GPU, but it must start and run training steps on the CPU."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import torch
from scipy.spatial.transform import Rotation
from torch.utils.data import Dataset

from benchmark.runner.plan.repro_profiles import PROFILES
from benchmark.runner.plan.specs import load_specs
from benchmark.runner.plan.units import train_config
from benchmark.training.build import model_factory
from benchmark.training.loop import train


class TinyPairs(Dataset):
    """Two 224 px pairs sharing one satellite image, with valid labels."""

    def __init__(self, n: int = 2, size: int = 224) -> None:
        g = torch.Generator().manual_seed(0)
        self.uav = torch.rand(n, 3, size, size, generator=g)
        self.sat = torch.rand(3, size, size, generator=g)
        self.R = torch.from_numpy(Rotation.random(n, random_state=0).as_matrix()).float()
        self.T = torch.randn(n, 3, generator=g) * 100

    def __len__(self) -> int:
        return len(self.uav)

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        return {"uav": self.uav[i], "sat": self.sat, "sat_id": torch.tensor(0), "R": self.R[i],
                "T": self.T[i], "index": torch.tensor(i)}  # fmt: skip


def test_paper_profile_runs_a_training_step_on_cpu(tmp_path):
    profile = PROFILES["paper"]
    assert profile.width == 1.0
    assert (profile.optim.name, profile.optim.lr, profile.optim.batch_size) == ("sgd", 1e-3, 20)
    assert profile.optim.momentum == 0.9  # the paper's SGDM (Sec. 3.3)
    # The heaviest model of the paper profile: Pd/Re-Net with AGTFM (Table 5).
    job = next(j for j in load_specs(only=["table5"])[0].jobs() if j.row.get("variant") == "a-f")
    cfg = train_config(job, profile, 0, Path("unused"), ["standard/train", "standard/val"])
    cfg = dataclasses.replace(cfg, optim=dataclasses.replace(cfg.optim, epochs=1, batch_size=2))
    result = train(cfg, model_factory(cfg, 224), TinyPairs(), None, tmp_path, progress=False)
    (record,) = result.history
    assert torch.isfinite(torch.tensor(record["train_loss_total"]))
    assert record["pairs_per_s"] > 0
    assert result.model.config.width == 1.0 and result.model.config.input_size == 224
