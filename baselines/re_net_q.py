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
from benchmark.models import RegressionAttitudeHead, register_head


@register_head("re_net_q")
class ReNetQ(RegressionAttitudeHead):
    """Args: in_features; hidden (1024). Raw: (B, 4) unnormalised quaternions (w, x, y, z)."""

    paper_name = "Re-Net-Q"
    raw_shape = (4,)

    def normalize(self, raw: Tensor) -> Tensor:
        return raw / torch.linalg.vector_norm(raw, dim=-1, keepdim=True).clamp_min(1e-12)

    def encode(self, R: Tensor) -> Tensor:
        return rotmat_to_quat_paper(R)

    def to_label(self, q: Tensor) -> Tensor:
        return quat_to_rotmat(q)
