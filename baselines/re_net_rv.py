"""Re-Net-Rv: regress the rotation vector (paper Eq. 7, Table 1).

Label: ``rotmat_to_rotvec(R_uav^sat)``, angle in [0, pi]; the vector flips to its antipode when the
angle crosses pi, the discontinuity the paper discusses. Loss: squared Euclidean distance (rad^2).
Decoding: Rodrigues (``rotvec_to_rotmat``), a rotation for any output.

Discontinuities: the label jumps from ``pi n`` to ``-pi n`` (2 pi apart) where the rotation angle
crosses pi; inherent in the rotation vector with angles in [0, pi], kept. None introduced: the
label goes through the canonical quaternion (accurate at both ends of [0, pi]) and decoding is
smooth everywhere, including the Taylor series at zero angle.
"""

from __future__ import annotations

from torch import Tensor

from benchmark.geometry import rotmat_to_rotvec, rotvec_to_rotmat
from benchmark.models import RegressionAttitudeHead, register_head


@register_head("re_net_rv")
class ReNetRv(RegressionAttitudeHead):
    """Args: in_features; hidden (1024). Raw: (B, 3) rotation vectors (radians)."""

    paper_name = "Re-Net-Rv"
    raw_shape = (3,)

    def encode(self, R: Tensor) -> Tensor:
        return rotmat_to_rotvec(R)

    def to_label(self, v: Tensor) -> Tensor:
        return rotvec_to_rotmat(v)
