"""Re-Net-SVD: 9D with SVD orthogonalisation inside the loss (Levinson et al., NeurIPS 2020).

Representation: the network regresses a 3x3 matrix M (raw ``(B, 3, 3)``, row-major 9 numbers).
Decoding: ``special_orthogonalize(M)``, the closest rotation in Frobenius norm (SVD with the
determinant fix, det +1).

Loss ("SVD-Train"): the chordal loss AFTER the projection, ``||SVD+(M) - R_gt||_F^2``
(``= 4 (1 - cos(angle))``), mean over the batch. Levinson et al.'s other variant, "SVD-Inf"
(loss on the raw 9 numbers, SVD only at inference), which Geist et al. ("Learning with 3D
rotations, a hitchhiker's guide to SO(3)", ICML 2024) recommend, is exactly ``re_net_r``; it is
not registered twice.

Gradient: ``special_orthogonalize`` has an analytic backward (``benchmark/geometry/so3.py``) that
divides by ``s'_i + s'_j`` (signed singular values), never by ``s_i^2 - s_j^2`` as torch's SVD
backward does. So it is finite and exact when singular values repeat (every near-rotation M has
``s1 = s2 = s3 = 1``). It is unbounded only where the projection itself is not unique
(``s'_i + s'_j = 0``: det M < 0 with ``s2 = s3``, or rank <= 1); there the denominator is clamped
at 1e-8, so the gradient stays finite (at most ~1e8 times the upstream one).
``tests/baselines/test_re_net_svd.py`` checks both.

Discontinuities: none in the representation (the label is R itself). The projection is continuous
except on the non-uniqueness set above (measure zero, never a label's own raw).
"""

from __future__ import annotations

from torch import Tensor

from benchmark.geometry import special_orthogonalize
from benchmark.models import RegressionAttitudeHead, register_head


@register_head("re_net_svd")
class ReNetSVD(RegressionAttitudeHead):
    """Args: in_features; hidden (1024), the width of the 2-layer MLP.

    ``forward``: features ``(B, F)`` -> raw ``(B, 3, 3)`` unconstrained matrices.
    ``decode``: ``(B, 3, 3)`` det +1. ``loss``: scalar squared Frobenius distance after the
    projection, batch mean (the base's distance between ``normalize(raw)`` and ``encode(R)``).
    """

    paper_name = "Re-Net-SVD (Levinson et al. 2020)"
    raw_shape = (3, 3)

    def normalize(self, raw: Tensor) -> Tensor:
        return special_orthogonalize(raw)

    def encode(self, R: Tensor) -> Tensor:
        return R

    def to_label(self, R: Tensor) -> Tensor:
        return R
