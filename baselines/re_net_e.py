"""Re-Net-E: regress (yaw, pitch, roll) of ``R_uav^sat`` plainly (paper Table 1).

Label: ``rotmat_to_euler`` (yaw, roll in (-pi, pi], pitch in [-pi/2, pi/2]); loss: squared error in
radians *without* wrapping, so a label near yaw = +-pi is a discontinuity for the network. That is
deliberate: it is the effect of the representation that the paper measures. Note that the relative
rotation to a nadir satellite camera has pitch near +pi/2 for level flight (UAV pitch 0 -> relative
pitch 90 deg), i.e. close to gimbal lock, where yaw and roll are ill-defined.
Decoding: ``euler_to_rotmat`` (Eq. 1).

Discontinuities, all inherent in regressing Euler angles (what the comparison measures), none
introduced: (1) the +-pi wrap of yaw and roll: rotations a fraction of a degree apart across yaw
(or roll) = +-180 deg have labels ~2 pi apart; (2) gimbal lock at pitch +-90 deg: there only
``yaw +- roll`` is defined, and near it the labels are ill-conditioned (level flight, UAV pitch
+0.25 and -0.25 deg, are 0.5 deg apart but their relative yaw and roll labels differ by ~180 deg).
Decoding is smooth everywhere (any three numbers give a rotation, Lipschitz in them), so a label
perturbed by d radians decodes within ~3d of the rotation, also near gimbal lock and the wrap.
"""

from __future__ import annotations

import torch
from torch import Tensor

from benchmark.geometry import euler_to_rotmat, rotmat_to_euler
from benchmark.models import RegressionAttitudeHead, register_head


@register_head("re_net_e")
class ReNetE(RegressionAttitudeHead):
    """Args: in_features; hidden (1024). Raw: (B, 3) (yaw, pitch, roll) radians."""

    paper_name = "Re-Net-E"
    raw_shape = (3,)

    def encode(self, R: Tensor) -> Tensor:
        """(B, 3, 3) -> (B, 3) (yaw, pitch, roll), unwrapped."""
        return torch.stack(rotmat_to_euler(R), dim=-1)

    def to_label(self, x: Tensor) -> Tensor:
        return euler_to_rotmat(*x.unbind(-1))
