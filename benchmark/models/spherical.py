"""Building blocks of the lattice-distribution heads (DirectionNet's spherical decoder, Eq. 9-15).

A lattice head predicts logits over ``n`` equal-area lattice points per direction; the predicted
distribution is their softmax (probabilities summing to 1, the same normalisation as the target
``discrete_vmf``). DirectionNet maps its outputs through softplus and divides by the area-weighted
sum instead; both give a probability vector, and Eq. 14 compares probabilities, so the choice of the
positive map does not change what alpha means (that is fixed by ``distribution_loss_scale``). The
softmax makes the vMF target exactly representable (its log is linear in the lattice coordinates)
and gives ``log_prob`` without a division.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

from benchmark.models.heads import distribution_loss_scale, mlp, sphere_volume


class LatticeDecoder(nn.Module):
    """``features (B, F) -> logits (B, channels, n)`` through a ``hidden``-wide bottleneck.

    A dense 2-layer map, not DirectionNet's upsampling conv decoder: the Fibonacci lattice has no
    image structure. The bottleneck keeps the parameter count near the paper's (Table 6).
    """

    def __init__(self, in_features: int, channels: int, n_points: int, hidden: int) -> None:
        super().__init__()
        self.channels, self.n_points = channels, n_points
        self.net = mlp(in_features, hidden, channels * n_points)

    def forward(self, features: Tensor) -> Tensor:
        return self.net(features).view(-1, self.channels, self.n_points)


def cosine_loss(v: Tensor, target: Tensor) -> Tensor:
    """Eq. 13 for one direction: ``1 - v.t / (|v| |t|)``. v, target: ``(..., d)`` -> ``(...)``.

    ``v`` is the unnormalised expectation ``sum_k p_k x_k``; its norm is clamped at 1e-12, so a
    uniform prediction (resultant ~ 0) gives a finite loss and gradient.
    """
    cos = (v * target).sum(-1) / (
        torch.linalg.vector_norm(v, dim=-1).clamp_min(1e-12)
        * torch.linalg.vector_norm(target, dim=-1).clamp_min(1e-12)
    )
    return 1 - cos


def directionnet_loss(
    p: Tensor, p_target: Tensor, resultant: Tensor, direction: Tensor, alpha: float, dim: int
) -> Tensor:
    """Per-sample ``sum_c [L_dir_c + alpha * s * ||p_c - p*_c||^2]`` (Eq. 13 + alpha Eq. 14).

    Args:
        p, p_target: ``(B, C, n)`` predicted / target probabilities.
        resultant: ``(B, C, d)`` predicted ``sum_k p_k x_k`` (Eq. 9 before normalisation).
        direction: ``(B, C, d)`` label unit vectors.
        alpha: distribution weight in DirectionNet's units (8e7 in the paper).
        dim: ambient dimension d (3 for S^2, 4 for S^3), for ``distribution_loss_scale``.
    Returns:
        ``(B,)``.
    """
    scale = distribution_loss_scale(p.shape[-1], dim)
    l_dir = cosine_loss(resultant, direction).sum(-1)
    l_dis = ((p - p_target) ** 2).sum(dim=(-1, -2))
    return l_dir + alpha * scale * l_dis


def lattice_log_density(log_p: Tensor, x: Tensor, grid: Tensor) -> Tensor:
    """Log density (w.r.t. the sphere's surface measure) of the lattice distribution at ``x``.

    The probability of the lattice point nearest ``x`` spread evenly over its cell (measure
    ``V / n``). log_p: ``(..., n)``; x: ``(..., d)`` unit; grid: ``(n, d)`` -> ``(...)``.
    """
    n, d = grid.shape
    index = (x @ grid.to(x.dtype).T).argmax(-1, keepdim=True)
    return log_p.gather(-1, index).squeeze(-1) - math.log(sphere_volume(d) / n)


def resultant_length(p: Tensor, grid: Tensor) -> Tensor:
    """``|sum_k p_k x_k|`` in [0, 1]: 1 for a point mass, ~0 for a uniform distribution.

    p: ``(..., n)``; grid: ``(n, d)`` -> ``(...)``. ``1 - resultant_length`` is the spherical
    variance used as the uncertainty of the direction heads.
    """
    return torch.linalg.vector_norm(p @ grid.to(p.dtype), dim=-1)
