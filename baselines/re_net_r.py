"""Re-Net-R: regress the 9 entries of R, project with SVD (paper Sec. 3.3.1, Table 1).

Loss: squared Euclidean (Frobenius) distance between the 9 raw numbers and ``R_uav^sat``, the
plain regression the paper compares against. Decoding: ``special_orthogonalize`` (det +1), the
closest rotation in Frobenius norm.

Discontinuities: none in the representation (the label is R itself). The SVD projection is
continuous except at degenerate inputs, matrices whose two smallest singular values (after the
determinant sign fix) coincide, e.g. rank <= 1 outputs, where the closest rotation is not unique.

This head is exactly "SVD-Inf" of Levinson et al. (NeurIPS 2020), the variant recommended by
Geist et al., "Learning with 3D rotations, a hitchhiker's guide to SO(3)" (ICML 2024): the loss
sees the raw 9 numbers and SVD orthogonalisation is applied only at inference. Levinson et al.'s
"SVD-Train" variant, with the chordal (squared Frobenius) loss after the SVD, is ``re_net_svd``
(``baselines/re_net_svd.py``); there is deliberately no separate SVD-Inf head.
"""

from __future__ import annotations

from torch import Tensor

from benchmark.geometry import special_orthogonalize
from benchmark.models import RegressionAttitudeHead, register_head


@register_head("re_net_r")
class ReNetR(RegressionAttitudeHead):
    """Args: in_features; hidden (1024). Raw: (B, 3, 3) unconstrained matrices."""

    paper_name = "Re-Net-R"
    raw_shape = (3, 3)

    def encode(self, R: Tensor) -> Tensor:
        return R

    def to_label(self, x: Tensor) -> Tensor:
        return special_orthogonalize(x)
