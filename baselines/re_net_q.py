"""Re-Net-Q: regress a unit quaternion against the paper's Eq. 3 label (Table 1).

Label: ``rotmat_to_quat_paper(R_uav^sat)``, the four-case conversion of Eq. 3 whose sign convention
jumps between cases (the discontinuity of Eq. 6). The 4 outputs are normalised, and the loss is the
squared Euclidean distance between the normalised prediction and the label (no q/-q folding, as in
the paper). Decoding: ``quat_to_rotmat`` of the normalised prediction.

Discontinuities: the label's sign jumps (to ``-q`` or near it) where Eq. 3 switches case, e.g.
along the level-flight yaw sweep at relative pitch 89 deg; inherent in the paper's target (its
Eq. 6 argument), kept on purpose. The loss does not fold q and -q for the same reason. Decoding is
continuous for every non-zero output (the zero quaternion is a degenerate input and raises in
``quat_to_rotmat``; the normalisation here clamps its norm at 1e-12 first).
"""

from __future__ import annotations

import torch
from torch import Tensor

from benchmark.geometry import quat_to_rotmat, rotmat_to_quat_paper
from benchmark.models import AttitudeHead, mlp, register_head


def _normalize(q: Tensor) -> Tensor:
    return q / torch.linalg.vector_norm(q, dim=-1, keepdim=True).clamp_min(1e-12)


@register_head("re_net_q")
class ReNetQ(AttitudeHead):
    """Args: in_features; hidden (1024)."""

    paper_name = "Re-Net-Q"

    def __init__(self, in_features: int, hidden: int = 1024) -> None:
        super().__init__(in_features)
        self.net = mlp(in_features, hidden, 4)

    def forward(self, features: Tensor) -> Tensor:
        """(B, F) -> (B, 4) unnormalised quaternions (w, x, y, z)."""
        return self.net(features)

    def decode(self, raw: Tensor) -> Tensor:
        return quat_to_rotmat(_normalize(raw))

    def loss(self, raw: Tensor, R_gt: Tensor) -> Tensor:
        return ((_normalize(raw) - rotmat_to_quat_paper(R_gt)) ** 2).sum(-1).mean()
