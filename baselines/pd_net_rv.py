"""Pd-Net-Rv: a vMF lattice distribution over the rotation axis plus an angle branch (Table 1).

The paper builds it "on the basis of DirectionNet-R by adding a parallel branch to estimate the
two-norm of the equivalent rotation vector" (Sec. 3.3.1).

Label: ``v = rotmat_to_rotvec(R_uav^sat)`` (angle in [0, pi]); axis ``v / |v|`` (``e_z`` when the
angle is below 1e-6, where the axis is undefined) and angle ``|v|``. Near an angle of pi the axis
flips to its antipode, the rotation-vector discontinuity of Eq. 7.

Grid and target: the 4096-point Fibonacci lattice; ``discrete_vmf(axis, kappa)``, sum 1.
Prediction: softmax over the lattice (sum 1) and ``angle = pi * sigmoid(z)`` in (0, pi).
Decoding: Eq. 9 expectation of the axis, times the angle, through ``rotvec_to_rotmat``.
Loss: ``L_dir + alpha * s * L_dis`` for the axis (as in ``pd_re_net``, alpha in DirectionNet's
units) plus ``angle_weight * (angle - angle*)^2`` (rad^2), mean over the batch.

Uncertainty: spherical variance ``1 - |E axis|`` of the axis distribution, in [0, 1]. ``log_prob``:
log density (1/sr) of the axis of R under the axis distribution; the angle branch is a point
estimate and does not contribute.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from benchmark.geometry import discrete_vmf, fibonacci_sphere, rotmat_to_rotvec, rotvec_to_rotmat
from benchmark.models import AttitudeHead, register_head
from benchmark.models.heads import check_lattice_options, check_option, mlp
from benchmark.models.spherical import directionnet_loss, lattice_log_density, resultant_length

_MIN_ANGLE = 1e-6


def rotmat_to_axis_angle(R: Tensor) -> tuple[Tensor, Tensor]:
    """(B, 3, 3) -> unit axis (B, 3) and angle (B,) in [0, pi]; axis e_z for (near) identity."""
    v = rotmat_to_rotvec(R)
    angle = torch.linalg.vector_norm(v, dim=-1)
    small = angle < _MIN_ANGLE
    e_z = torch.zeros_like(v)
    e_z[..., 2] = 1
    axis = torch.where(small[..., None], e_z, v / angle.clamp_min(_MIN_ANGLE)[..., None])
    return axis, angle


@register_head("pd_net_rv")
class PdNetRv(AttitudeHead):
    """Options: n_points (4096), kappa (10), alpha (8e7), hidden (160), angle_weight (1)."""

    paper_name = "Pd-Net-Rv"
    is_probabilistic = True

    def __init__(
        self,
        in_features: int,
        n_points: int = 4096,
        kappa: float = 10.0,
        alpha: float = 8e7,
        hidden: int = 160,
        angle_weight: float = 1.0,
    ) -> None:
        super().__init__(in_features)
        self.kappa, self.alpha = check_lattice_options("pd_net_rv", n_points, kappa, alpha)
        self.angle_weight = check_option(angle_weight, "angle_weight", "pd_net_rv", inclusive=True)
        self.register_buffer("grid", fibonacci_sphere(n_points), persistent=False)
        self.net = mlp(in_features, hidden, n_points + 1)

    def forward(self, features: Tensor) -> dict[str, Tensor]:
        """(B, F) -> {"logits": (B, n) axis logits, "angle": (B,) radians in (0, pi)}."""
        out = self.net(features)
        return {"logits": out[:, :-1], "angle": math.pi * torch.sigmoid(out[:, -1])}

    def distribution(self, raw: dict[str, Tensor]) -> dict[str, Tensor]:
        """{"axis": (B, n) probabilities, "angle": (B,) point estimate}."""
        return {"axis": torch.softmax(raw["logits"], dim=-1), "angle": raw["angle"]}

    def target_distribution(self, R: Tensor) -> dict[str, Tensor]:
        axis, angle = rotmat_to_axis_angle(R)
        return {"axis": discrete_vmf(axis, self.kappa, self.grid.to(R.dtype)), "angle": angle}

    def decode_distribution(self, dist: dict[str, Tensor]) -> Tensor:
        resultant = dist["axis"] @ self.grid.to(dist["axis"].dtype)
        axis = resultant / torch.linalg.vector_norm(resultant, dim=-1, keepdim=True).clamp_min(
            1e-12
        )
        return rotvec_to_rotmat(axis * dist["angle"][..., None])

    def decode(self, raw: dict[str, Tensor]) -> Tensor:
        return self.decode_distribution(self.distribution(raw))

    def loss(self, raw: dict[str, Tensor], R_gt: Tensor) -> Tensor:
        p = torch.softmax(raw["logits"], dim=-1)
        grid = self.grid.to(p.dtype)
        axis, angle = rotmat_to_axis_angle(R_gt)
        target = discrete_vmf(axis, self.kappa, grid)
        l_axis = directionnet_loss(
            p[:, None], target[:, None], (p @ grid)[:, None], axis[:, None], self.alpha, 3
        )
        return (l_axis + self.angle_weight * (raw["angle"] - angle) ** 2).mean()

    def log_prob(self, raw: dict[str, Tensor], R: Tensor) -> Tensor:
        """(B,) log density (1/sr) of R's rotation axis at the nearest lattice point."""
        axis, _ = rotmat_to_axis_angle(R)
        return lattice_log_density(torch.log_softmax(raw["logits"], dim=-1), axis, self.grid)

    def uncertainty(self, raw: dict[str, Tensor]) -> Tensor:
        """(B,) spherical variance of the axis distribution, in [0, 1]."""
        return 1 - resultant_length(torch.softmax(raw["logits"], dim=-1), self.grid)
