"""Projection onto SO(3), Gram-Schmidt, and distances (paper Sec. 2.2.2 and Eq. 16).

Why not roma (BSD-3; ``roma.special_procrustes`` is this projection, with a backward of its own):
it is not installed, and it requires torch, so a plain ``pip install`` in a fresh environment may
pull a CUDA torch (it would have to be ``pip install --no-deps roma``); the projection and its
backward below are ~60 lines, gradchecked in float64 and tested where singular values coincide
(every near-rotation input), and every trained weight passes through them: another
implementation rounds differently and changes the numbers of every Pd/Re-Net model.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from benchmark.geometry._checks import check_finite, check_last_dims, check_tensor

__all__ = ["angle_difference", "geodesic_distance", "gram_schmidt", "special_orthogonalize"]

# Denominators s_i + s_j of the SVD backward are kept at least this far from zero (see below).
_SVD_GRAD_EPS = 1e-8


class _SpecialOrthogonalize(torch.autograd.Function):
    """Polar factor with determinant fix, with an analytic backward.

    Write ``M = U S' V'^T`` with ``S' = diag(s1, s2, d s3)``, ``V' = V diag(1, 1, d)`` and
    ``d = det(U V^T)``; the result is ``R = U V'^T``. Differentiating gives
    ``dR = U W V'^T`` with ``W_ij = (X_ij - X_ji) / (s'_i + s'_j)``, ``X = U^T dM V'``.
    The backward therefore only divides by ``s'_i + s'_j``, never by ``s_i^2 - s_j^2`` as torch's
    generic SVD backward does: it stays finite when singular values are equal or close (a common
    case: any near-rotation input has s1 = s2 = s3 = 1). It is singular only where the projection
    itself is not unique (``s'_i + s'_j = 0``, e.g. ``d = -1`` and ``s2 = s3``); there the
    denominator is clamped to 1e-8 in magnitude.
    """

    @staticmethod
    def forward(ctx, M: Tensor) -> Tensor:  # type: ignore[override]
        U, S, Vh = torch.linalg.svd(M)
        d = torch.sign(torch.linalg.det(U @ Vh))
        d = torch.where(d == 0, torch.ones_like(d), d)
        flip = torch.ones_like(S)
        flip[..., 2] = d
        V_signed = Vh.transpose(-1, -2) * flip[..., None, :]  # V diag(1, 1, d)
        R = U @ V_signed.transpose(-1, -2)
        ctx.save_for_backward(U, S * flip, V_signed)
        return R

    @staticmethod
    def backward(ctx, grad_R: Tensor) -> Tensor:  # type: ignore[override]
        U, S_signed, V_signed = ctx.saved_tensors
        A = U.transpose(-1, -2) @ grad_R @ V_signed
        denom = S_signed[..., :, None] + S_signed[..., None, :]
        denom = torch.where(
            denom.abs() < _SVD_GRAD_EPS,
            torch.where(denom < 0, -_SVD_GRAD_EPS, _SVD_GRAD_EPS).to(denom.dtype),
            denom,
        )
        grad_X = (A - A.transpose(-1, -2)) / denom
        return U @ grad_X @ V_signed.transpose(-1, -2)


def special_orthogonalize(M: Tensor) -> Tensor:
    """Closest rotation in Frobenius norm (SVD orthogonalisation with determinant fix).

    Args:
        M: ``(..., 3, 3)`` any real matrices (e.g. 9 regressed numbers, or the three expected
        column directions of a distribution head).
    Returns:
        ``(..., 3, 3)`` with ``R^T R = I`` and ``det R = +1``.

    The gradient is analytic and finite when singular values coincide; see
    :class:`_SpecialOrthogonalize`. For rank-deficient ``M`` (two zero singular values) the
    projection is not unique and the result is arbitrary among the minimisers.
    """
    M = check_last_dims(M, (3, 3), "M")
    return _SpecialOrthogonalize.apply(M)


def gram_schmidt(a: Tensor, b: Tensor) -> Tensor:
    """Rotation whose first two columns are ``a`` and ``b`` orthonormalised (Zhou et al. 6D).

    Args:
        a, b: ``(..., 3)``, broadcastable.
    Returns:
        ``(..., 3, 3)`` with columns ``a/|a|``, ``b'`` (``b`` minus its component along ``a``,
        normalised) and ``a' x b'``.
    Raises:
        ValueError: if ``a`` is (near) zero or ``b`` is (near) parallel to ``a``: the result would
        not be defined.
    """
    a = check_last_dims(a, (3,), "a")
    b = check_last_dims(b, (3,), "b")
    a, b = torch.broadcast_tensors(a, b)
    a_norm = torch.linalg.vector_norm(a, dim=-1, keepdim=True)
    if bool((a_norm < 1e-8).any()):
        raise ValueError(f"gram_schmidt: a has (near) zero length, shape {tuple(a.shape)}")
    e1 = a / a_norm
    b_perp = b - (e1 * b).sum(-1, keepdim=True) * e1
    b_norm = torch.linalg.vector_norm(b_perp, dim=-1, keepdim=True)
    if bool((b_norm < 1e-8).any()):
        raise ValueError(f"gram_schmidt: b is (near) parallel to a, shape {tuple(b.shape)}")
    e2 = b_perp / b_norm
    e3 = torch.linalg.cross(e1, e2, dim=-1)
    return torch.stack([e1, e2, e3], dim=-1)


def geodesic_distance(R1: Tensor, R2: Tensor) -> Tensor:
    """Angle of ``R1 R2^T`` in radians, in [0, pi] (paper Eq. 16).

    Eq. 16 writes ``arccos((tr(R1 R2^T) - 1) / 2)``, whose derivative is infinite at 0 and pi and
    which loses half the digits near 0. We evaluate the same angle as
    ``atan2(|vee(R1 R2^T - R2 R1^T)| / 2, (tr - 1) / 2)``: accurate everywhere, and its gradient is
    finite at 0 and pi (0 is a subgradient there).

    Args:
        R1, R2: ``(..., 3, 3)``, broadcastable.
    Returns:
        ``(...)`` radians.
    """
    R1 = check_last_dims(R1, (3, 3), "R1")
    R2 = check_last_dims(R2, (3, 3), "R2")
    Rr = R1 @ R2.transpose(-1, -2)
    cos = (Rr[..., 0, 0] + Rr[..., 1, 1] + Rr[..., 2, 2] - 1) / 2
    axis = torch.stack(
        [
            Rr[..., 2, 1] - Rr[..., 1, 2],
            Rr[..., 0, 2] - Rr[..., 2, 0],
            Rr[..., 1, 0] - Rr[..., 0, 1],
        ],
        dim=-1,
    )
    # vector_norm's backward at exactly 0 is 0 in torch; the sum-of-squares + sqrt formulation
    # would give NaN there.
    sin = torch.linalg.vector_norm(axis, dim=-1) / 2
    return torch.atan2(sin, cos)


def angle_difference(a: Tensor, b: Tensor) -> Tensor:
    """``a - b`` wrapped to (-pi, pi]. ``(...)`` radians, broadcastable.

    Uses ``pi - remainder(pi - (a - b), 2 pi)``; torch's ``remainder`` has the sign of the divisor,
    so the result lies in (-pi, pi] exactly, including ``a - b = -pi -> pi``.
    """
    a = check_tensor(a, "a")
    b = check_tensor(b, "b")
    check_finite(a, "a")
    check_finite(b, "b")
    return math.pi - torch.remainder(math.pi - (a - b), 2 * math.pi)
