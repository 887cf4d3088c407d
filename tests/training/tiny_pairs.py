"""A tiny in-memory dataset in ``PairDataset``'s item format, and a tiny train config.

(A helper module, not a conftest: ``tests/*/conftest.py`` files would share one module name.)
"""

from __future__ import annotations

import math

import torch
from torch.utils.data import Dataset

from benchmark.config import apply_overrides
from benchmark.training import TrainConfig


class TinyPairs(Dataset):
    """``n`` pairs of 32 px images whose UAV image brightness pattern encodes the yaw, so a model
    can learn something; labels are real rotations ``R_uav^sat`` (built with the geometry core)."""

    def __init__(self, n: int, seed: int = 0, n_sat: int = 2) -> None:
        from benchmark.geometry import SAT_R_N, euler_to_rotmat, relative_rotation

        g = torch.Generator().manual_seed(seed)
        self.yaw = (torch.rand(n, generator=g, dtype=torch.float64) * 2 - 1) * math.pi
        pitch = -torch.rand(n, generator=g, dtype=torch.float64) * math.radians(50)
        roll = (torch.rand(n, generator=g, dtype=torch.float64) * 2 - 1) * math.radians(10)
        R_uav = euler_to_rotmat(self.yaw, pitch, roll)
        self.R = relative_rotation(R_uav, SAT_R_N.expand_as(R_uav)).float()
        self.euler = torch.stack([self.yaw, pitch, roll], 1).float()
        self.T = (torch.randn(n, 3, generator=g) * torch.tensor([50.0, 50.0, 10.0])).float()
        base = torch.rand(n_sat, 3, 32, 32, generator=g)
        self.sat = base
        self.sat_id = torch.arange(n) % n_sat
        xs = torch.linspace(-1, 1, 32)
        yy, xx = torch.meshgrid(xs, xs, indexing="ij")
        pattern = [
            0.5 + 0.4 * torch.cos(xx * math.cos(y) * 3 + yy * math.sin(y) * 3)
            for y in self.yaw.tolist()
        ]
        noise = torch.rand(n, 3, 32, 32, generator=g) * 0.1
        self.uav = torch.stack(pattern)[:, None].expand(n, 3, 32, 32) * 0.9 + noise

    def __len__(self) -> int:
        return len(self.yaw)

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        return {
            "uav": self.uav[i].clone(),
            "sat": self.sat[self.sat_id[i]].clone(),
            "sat_id": self.sat_id[i].clone(),
            "R": self.R[i].clone(),
            "T": self.T[i].clone(),
            "uav_euler": self.euler[i].clone(),
            "index": torch.tensor(i),
        }


def tiny_config(*overrides: str) -> TrainConfig:
    """A 32 px, width 0.25 model, 2 epochs of batch 4, one thread: seconds on a CPU."""
    return apply_overrides(
        TrainConfig(),
        [
            "model.width=0.25",
            "model.variant=a-f",
            "optim.batch_size=4",
            "optim.epochs=2",
            "threads=1",
            *overrides,
        ],
    )
