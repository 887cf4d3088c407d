"""Pd-Net-Q: a lattice distribution over unit quaternions on S^3 (paper Sec. 3.3.1, "16^3").

Grid: ``super_fibonacci(4096)``, nearly uniform on all of S^3, so every rotation appears twice
(``q`` and ``-q``).

q / -q symmetry (default ``symmetric=True``): the target is the antipodal vMF mixture
``p*_k ∝ exp(kappa q*.x_k) + exp(-kappa q*.x_k)`` (normalised to sum 1), which is the same for
``q*`` and ``-q*``, so the label's sign (the Eq. 3 case split) cannot matter. Decoding takes the
principal eigenvector of the scatter matrix ``M = sum_k p_k x_k x_k^T`` (the axis of a Bingham-like
distribution); its sign is irrelevant. The Eq. 13 analogue in the loss folds the predicted
distribution onto the label's hemisphere, ``m = sum_k p_k sign(q*.x_k) x_k``, and uses
``1 - cos(m, q*)``: it needs no eigen-decomposition, whose gradient blows up for the nearly
isotropic ``M`` of an untrained network.

``symmetric=False`` reproduces the paper literally: a vMF target around the Eq. 3 label
``rotmat_to_quat_paper(R)`` (whose sign jumps between cases), decoded by the normalised
expectation (Eq. 9), loss ``1 - cos(sum p x, q*)``.

Prediction: softmax over the lattice (sum 1). Loss: ``L_dir + alpha * s * L_dis`` with alpha = 8e7
in DirectionNet's units, ``s = distribution_loss_scale(n, dim=4)`` (the same density-L2 argument
as ``pd_re_net`` with the S^3 volume 2 pi^2), mean over the batch.

Uncertainty: ``1 - lambda_max(M)`` (symmetric; in [0, 3/4], 0 = point mass at +-q) or
``1 - |sum p x|`` (literal). ``log_prob``: log density of the rotation on S^3 / {+-1} (total measure
pi^2): ``log(p(q) + p(-q)) - log(2 pi^2 / n)`` with each probability read at the nearest lattice
point.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from benchmark.geometry import (
    quat_to_rotmat,
    rotmat_to_quat,
    rotmat_to_quat_paper,
    super_fibonacci,
)
from benchmark.models import AttitudeHead, register_head
from benchmark.models.heads import check_lattice_options
from benchmark.models.spherical import LatticeDecoder, directionnet_loss, resultant_length


@register_head("pd_net_q")
class PdNetQ(AttitudeHead):
    """Options: n_points (4096), kappa (10), alpha (8e7), hidden (160), symmetric (True)."""

    paper_name = "Pd-Net-Q"
    is_probabilistic = True

    def __init__(
        self,
        in_features: int,
        n_points: int = 4096,
        kappa: float = 10.0,
        alpha: float = 8e7,
        hidden: int = 160,
        symmetric: bool = True,
    ) -> None:
        super().__init__(in_features)
        self.kappa, self.alpha = check_lattice_options(
            "pd_net_q", n_points, kappa, alpha, min_points=8
        )
        self.symmetric = bool(symmetric)
        self.register_buffer("grid", super_fibonacci(n_points), persistent=False)
        self.decoder = LatticeDecoder(in_features, 1, n_points, hidden)

    def forward(self, features: Tensor) -> Tensor:
        """(B, F) -> logits (B, n) over the S^3 lattice."""
        return self.decoder(features)[:, 0]

    def distribution(self, raw: Tensor) -> Tensor:
        """(B, n) probabilities over the lattice quaternions."""
        return torch.softmax(raw, dim=-1)

    def _label(self, R: Tensor) -> Tensor:
        return rotmat_to_quat(R) if self.symmetric else rotmat_to_quat_paper(R)

    def _target(self, q: Tensor, grid: Tensor) -> Tensor:
        dots = self.kappa * (q @ grid.T)
        logits = torch.logaddexp(dots, -dots) if self.symmetric else dots
        return torch.softmax(logits, dim=-1)

    def target_distribution(self, R: Tensor) -> Tensor:
        return self._target(self._label(R), self.grid.to(R.dtype))

    def _scatter(self, p: Tensor) -> Tensor:
        grid = self.grid.to(p.dtype)
        return torch.einsum("bk,ki,kj->bij", p, grid, grid)  # (B, 4, 4), trace 1

    def decode_distribution(self, p: Tensor) -> Tensor:
        if self.symmetric:
            _, vectors = torch.linalg.eigh(self._scatter(p))  # ascending eigenvalues
            return quat_to_rotmat(vectors[..., -1])
        resultant = p @ self.grid.to(p.dtype)
        return quat_to_rotmat(
            resultant / torch.linalg.vector_norm(resultant, dim=-1, keepdim=True).clamp_min(1e-12)
        )

    def decode(self, raw: Tensor) -> Tensor:
        return self.decode_distribution(self.distribution(raw))

    def loss(self, raw: Tensor, R_gt: Tensor) -> Tensor:
        p = self.distribution(raw)
        grid = self.grid.to(p.dtype)
        q = self._label(R_gt)
        target = self._target(q, grid)
        if self.symmetric:
            # Fold every lattice point onto the label's hemisphere before taking the mean.
            signs = torch.where(q @ grid.T < 0, -1.0, 1.0).to(p.dtype)
            resultant = (p * signs) @ grid
        else:
            resultant = p @ grid
        return directionnet_loss(
            p[:, None], target[:, None], resultant[:, None], q[:, None], self.alpha, 4
        ).mean()

    def log_prob(self, raw: Tensor, R: Tensor) -> Tensor:
        """(B,) log density of R on S^3/{+-1}: ``log(p(q) + p(-q)) - log(2 pi^2 / n)``."""
        q = rotmat_to_quat(R)
        log_p = torch.log_softmax(raw, dim=-1)
        dots = q @ self.grid.to(q.dtype).T
        near_pos = log_p.gather(-1, dots.argmax(-1, keepdim=True)).squeeze(-1)
        near_neg = log_p.gather(-1, dots.argmin(-1, keepdim=True)).squeeze(-1)
        return torch.logaddexp(near_pos, near_neg) - math.log(2 * math.pi**2 / self.grid.shape[0])

    def uncertainty(self, raw: Tensor) -> Tensor:
        """(B,) ``1 - lambda_max(M)`` (symmetric) or ``1 - |E q|`` (literal)."""
        p = self.distribution(raw)
        if self.symmetric:
            return 1 - torch.linalg.eigvalsh(self._scatter(p))[..., -1]
        return 1 - resultant_length(p, self.grid)
