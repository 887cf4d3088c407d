"""Synthetic pair labels and ``context`` with the quick dataset's geometry, for ``bench train`` and
``model-info`` (which time random pixels, but a pair encoder's work depends on the geometry).

The matching encoder reads each pair's ``context`` (``benchmark.models.pair_encoder``): the
camera's field of view, the satellite footprint and height, and the sensor priors (pitch, roll,
height). Where the bird's-eye templates land, how many of their cells are valid and which
positions are masked follow from them, so a benchmark draws them from the real ranges, measured
on ``data/quick-s0`` standard/train (2026-12-02, 2,400 pairs):

- yaw uniform over the circle, pitch -50..0 deg, roll -10..10 deg;
- height above the ground 80-120 m; the UAV within 380 m (E and N) of the satellite image's
  centre; ``T = (dE, dN, dU)`` with ``dU`` = height - satellite height (``-920..-880`` m);
- satellite footprint 2000 x 1000 m (E x N) at 1000 m, field of view 60 deg;
- priors = truth + Gaussian noise of :data:`PRIOR_SIGMA` (1 deg, 1 deg, 2 m: the dataset's
  ``benchmark.data.dataset.PRIOR_SIGMA``, copied because models may not import data; a test
  checks they agree).

``R`` is the label ``R_uav^sat = R_uav^n (R_sat^n)^T`` of Eq. 2 (``SAT_R_N``), ``R_uav^n =
Rz(yaw) Rx(pitch) Ry(roll)``, as ``PairDataset`` gives it.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from benchmark.geometry import SAT_R_N, euler_to_rotmat

__all__ = ["PRIOR_SIGMA", "synthetic_labels"]

PRIOR_SIGMA = (math.radians(1.0), math.radians(1.0), 2.0)  # pitch, roll rad; height m
FOV_DEG = 60.0
FOOTPRINT_M = (2000.0, 1000.0)
SAT_HEIGHT_M = 1000.0


def synthetic_labels(
    batch: int, generator: torch.Generator | None = None
) -> tuple[Tensor, Tensor, dict[str, Tensor]]:
    """``(R (B, 3, 3), T (B, 3), context)`` float32 for ``batch`` pairs (module docstring);
    ``context`` as ``PairDataset`` collates it: ``fov (B,)`` rad, ``sat_footprint_m (B, 2)``,
    ``sat_height_m (B,)``, ``prior_attitude (B, 2)`` (pitch, roll rad), ``prior_altitude_m
    (B,)``. The same numbers for the same generator state."""
    g = generator if generator is not None else torch.Generator().manual_seed(0)
    u = torch.rand(batch, 6, generator=g, dtype=torch.float64)
    yaw = (2 * u[:, 0] - 1) * math.pi
    pitch = -math.radians(50.0) * u[:, 1]
    roll = math.radians(10.0) * (2 * u[:, 2] - 1)
    height = 80.0 + 40.0 * u[:, 3]
    east, north = 380.0 * (2 * u[:, 4] - 1), 380.0 * (2 * u[:, 5] - 1)
    R = euler_to_rotmat(yaw, pitch, roll) @ SAT_R_N.transpose(0, 1)
    T = torch.stack([east, north, height - SAT_HEIGHT_M], dim=1)
    noise = torch.randn(batch, 3, generator=g, dtype=torch.float64) * torch.tensor(PRIOR_SIGMA)
    context = {
        "fov": torch.full((batch,), math.radians(FOV_DEG)),
        "sat_footprint_m": torch.tensor([FOOTPRINT_M]).expand(batch, 2).clone(),
        "sat_height_m": torch.full((batch,), SAT_HEIGHT_M),
        "prior_attitude": torch.stack([pitch, roll], 1) + noise[:, :2],
        "prior_altitude_m": height + noise[:, 2],
    }
    return R.float(), T.float(), {k: v.float() for k, v in context.items()}
