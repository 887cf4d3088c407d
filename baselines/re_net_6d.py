"""Re-Net-6D: the continuous 6D representation with Gram-Schmidt (Zhou et al., CVPR 2019).

Representation: the network regresses two 3-vectors ``a, b`` (raw ``(B, 3, 2)``), read as the
first two COLUMNS of R, as in Zhou et al. (their ``f_GS`` maps ``[a1 a2]`` to the columns
``[b1 b2 b3]``). Decoding: ``gram_schmidt(a, b)`` = ``[a/|a|, b', a/|a| x b']`` with ``b'`` the
part of ``b`` orthogonal to ``a``, normalised (det +1). The inverse map, R -> its first two
columns, is continuous: this is the representation's point.

Loss: squared Frobenius distance ``||decode(raw) - R_gt||_F^2`` (= ``4 (1 - cos(angle))``), as in
Zhou et al., plus ``raw_weight * ||raw - [r1 r2]||^2`` (``r1, r2`` the label's first two columns),
mean over the batch. The second term is not Zhou et al.'s (``raw_weight=0`` is their loss exactly)
and it does not bias the rotation: both terms are minimised by the same raw, ``[r1 r2]``. It
removes the three directions along which Gram-Schmidt's loss is flat (the lengths of ``a`` and of
``b``'s orthogonal part, and ``b``'s component along ``a``): without it they drift in training,
and a raw with ``b`` nearly parallel to ``a`` decodes a small output error into a large rotation
error. Measured on the registry's boundary test (Adam on the raw, then 0.005 noise on it): with
``raw_weight=0`` the smallest orthogonal part reached 0.08 and noise moved the decoded rotation by
up to 13.8 deg; with 0.01 (default) 0.18 and 3.0 deg; with 0.1, 0.60 and 1.2 deg.

Numerics (degenerate inputs): ``gram_schmidt`` refuses ``|a| < 1e-8`` and ``b`` parallel to
``a``. Training must not crash on them, so before it ``a`` with ``|a| < EPS`` (1e-6) is replaced
by ``e_x``, and ``b`` whose part orthogonal to ``a`` is shorter than ``EPS`` by
``a/|a| x e_k`` (``e_k`` the axis least aligned with ``a``, so its length is >= sqrt(2/3)). The
replacement goes through ``torch.where`` and both branches have finite gradients (the norms in
the test are clamped at ``EPS``), so the gradient is zero on a replaced vector and finite
elsewhere: at most ~``1/EPS`` times the upstream gradient (the derivative of ``a/|a|`` is
``1/|a|``). Decode is therefore defined for every raw output.

Discontinuities: none in the representation (the label map R -> [r1 r2] is continuous and
injective). Decoding is discontinuous only on the degenerate set where the first column is (near)
zero or the second is (near) parallel to it: there Gram-Schmidt is undefined and the fallback
above picks a value. This set has measure zero and is never a label's own raw.
"""

from __future__ import annotations

import torch
from torch import Tensor

from benchmark.geometry import gram_schmidt
from benchmark.models import RegressionAttitudeHead, register_head
from benchmark.models.heads import check_option

EPS = 1e-6  # below this, a vector counts as degenerate (gram_schmidt itself refuses < 1e-8)


def _orthogonal_part(a: Tensor, b: Tensor) -> Tensor:
    """Part of ``b`` orthogonal to ``a`` (``(..., 3)``; ``a`` with ``|a| >= EPS``)."""
    e1 = a / torch.linalg.vector_norm(a, dim=-1, keepdim=True).clamp_min(EPS)
    return b - (e1 * b).sum(-1, keepdim=True) * e1


def safe_gram_schmidt(a: Tensor, b: Tensor) -> Tensor:
    """``gram_schmidt(a, b)`` defined everywhere: degenerate ``a`` / ``b`` replaced (see module).

    a, b: ``(..., 3)`` -> ``(..., 3, 3)`` rotations, columns ``a/|a|``, ``b'``, their cross.
    """
    eye = torch.eye(3, dtype=a.dtype, device=a.device)
    a_ok = torch.linalg.vector_norm(a, dim=-1, keepdim=True) >= EPS
    a = torch.where(a_ok, a, eye[0])
    # Axis least aligned with a: cross(a/|a|, e_k) has length >= sqrt(2/3), never degenerate.
    axis = eye[(a.detach().abs()).argmin(-1)]
    fallback_b = torch.linalg.cross(a / torch.linalg.vector_norm(a, dim=-1, keepdim=True), axis)
    b_ok = torch.linalg.vector_norm(_orthogonal_part(a, b), dim=-1, keepdim=True) >= EPS
    return gram_schmidt(a, torch.where(b_ok, b, fallback_b))


@register_head("re_net_6d")
class ReNet6D(RegressionAttitudeHead):
    """Args: in_features; hidden (1024), the width of the 2-layer MLP; raw_weight (0.01, >= 0),
    the weight of the conditioning term of the loss (module docstring).

    ``forward``: features ``(B, F)`` -> raw ``(B, 3, 2)``, column 0 is ``a``, column 1 is ``b``.
    ``decode``: ``(B, 3, 3)`` det +1. ``loss``: scalar, batch mean.
    """

    paper_name = "Re-Net-6D (Zhou et al. 2019)"
    raw_shape = (3, 2)

    def __init__(self, in_features: int, hidden: int = 1024, raw_weight: float = 0.01) -> None:
        super().__init__(in_features, hidden)
        self.raw_weight = check_option(raw_weight, "raw_weight", "ReNet6D", inclusive=True)

    def normalize(self, raw: Tensor) -> Tensor:
        return safe_gram_schmidt(raw[..., 0], raw[..., 1])

    def encode(self, R: Tensor) -> Tensor:
        return R

    def to_label(self, R: Tensor) -> Tensor:
        return R

    def loss(self, raw: Tensor, R_gt: Tensor) -> Tensor:
        conditioning = ((raw - R_gt[..., :2]) ** 2).sum(dim=(-1, -2)).mean()
        return super().loss(raw, R_gt) + self.raw_weight * conditioning
