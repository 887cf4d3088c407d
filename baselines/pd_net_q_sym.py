"""Pd-Net-Q-sym: the q / -q symmetric variant of Pd-Net-Q (not a row of the paper's tables).

The paper's Pd-Net-Q (``pd_net_q``) uses the Eq. 3-5 label, whose sign jumps at the case switches.
This variant removes that jump: it treats ``q`` and ``-q`` as the one rotation they are. It belongs
in the extended comparison, as "Pd-Net-Q (antipodally symmetric)", beside the paper's row.

Grid: ``super_fibonacci(4096)``, nearly uniform on all of S^3 (every rotation appears twice).

Target: the antipodal vMF mixture ``p*_k ∝ exp(kappa q*.x_k) + exp(-kappa q*.x_k)`` (sum 1), the
same for ``q*`` and ``-q*`` (``q* = rotmat_to_quat(R)``, any sign), so the label's sign cannot
matter. Decoding: the principal eigenvector of the scatter matrix ``M = sum_k p_k x_k x_k^T`` (the
axis of a Bingham-like distribution); its sign is irrelevant. Loss: ``L_dir + alpha * s * L_dis``
(Eq. 13 + Eq. 14, ``s = distribution_loss_scale(n, dim=4)``), where the Eq. 13 analogue folds the
prediction onto the label's hemisphere, ``m = sum_k p_k sign(q*.x_k) x_k``, and uses
``1 - cos(m, q*)``: it needs no eigen-decomposition, whose gradient blows up for the nearly
isotropic ``M`` of an untrained network. The fold is sign-invariant (``-q*`` gives ``-m``).

Uncertainty: ``(4 / 3) (1 - lambda_max(M))`` in [0, 1] (0: point mass at +-q; 1: ``M = I / 4``,
the uniform distribution).

``log_prob``: log density of R w.r.t. the normalised Haar measure on SO(3): ``log(p(q) + p(-q)) +
log(n / 2)`` with each probability read at the nearest lattice point (a density g on S^3 w.r.t.
surface measure, total 2 pi^2, gives the rotation density ``pi^2 (g(q) + g(-q))``; each lattice
point's probability is spread over its cell ``2 pi^2 / n``). A uniform prediction scores 0.

Discontinuities: none in the target (it is a continuous function of the rotation). The eigenvector
decoding is discontinuous only where the two largest eigenvalues of M are equal (an ambiguous
prediction, not a label).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from benchmark.geometry import quat_to_rotmat, rotmat_to_quat, super_fibonacci
from benchmark.models import AttitudeHead, register_head
from benchmark.models.heads import check_lattice_options
from benchmark.models.spherical import LatticeDecoder, directionnet_loss


@register_head("pd_net_q_sym")
class PdNetQSym(AttitudeHead):
    """Options: n_points (4096), kappa (10), alpha (8e7), hidden (160)."""

    paper_name = "Pd-Net-Q-sym"
    is_probabilistic = True
    version = 1

    def __init__(
        self,
        in_features: int,
        n_points: int = 4096,
        kappa: float = 10.0,
        alpha: float = 8e7,
        hidden: int = 160,
    ) -> None:
        super().__init__(in_features)
        self.kappa, self.alpha = check_lattice_options(
            "pd_net_q_sym", n_points, kappa, alpha, min_points=8
        )
        self.register_buffer("grid", super_fibonacci(n_points), persistent=False)
        self.decoder = LatticeDecoder(in_features, 1, n_points, hidden)

    def forward(self, features: Tensor) -> Tensor:
        """(B, F) -> logits (B, n) over the S^3 lattice."""
        return self.decoder(features)[:, 0]

    def distribution(self, raw: Tensor) -> Tensor:
        """(B, n) probabilities over the lattice quaternions."""
        return torch.softmax(raw, dim=-1)

    def _target(self, q: Tensor, grid: Tensor) -> Tensor:
        dots = self.kappa * (q @ grid.T)
        return torch.softmax(torch.logaddexp(dots, -dots), dim=-1)

    def target_distribution(self, R: Tensor) -> Tensor:
        return self._target(rotmat_to_quat(R), self.grid.to(R.dtype))

    def _scatter(self, p: Tensor) -> Tensor:
        grid = self.grid.to(p.dtype)
        return torch.einsum("bk,ki,kj->bij", p, grid, grid)  # (B, 4, 4), trace 1

    def decode_distribution(self, p: Tensor) -> Tensor:
        _, vectors = torch.linalg.eigh(self._scatter(p))  # ascending eigenvalues
        return quat_to_rotmat(vectors[..., -1])

    def decode(self, raw: Tensor) -> Tensor:
        return self.decode_distribution(self.distribution(raw))

    def loss(self, raw: Tensor, R_gt: Tensor) -> Tensor:
        p = self.distribution(raw)
        grid = self.grid.to(p.dtype)
        q = rotmat_to_quat(R_gt)
        target = self._target(q, grid)
        # Fold every lattice point onto the label's hemisphere before taking the mean.
        signs = torch.where(q @ grid.T < 0, -1.0, 1.0).to(p.dtype)
        resultant = (p * signs) @ grid
        return directionnet_loss(
            p[:, None], target[:, None], resultant[:, None], q[:, None], self.alpha, 4
        ).mean()

    def log_prob(self, raw: Tensor, R: Tensor) -> Tensor:
        """(B,) log density of R w.r.t. the normalised Haar measure on SO(3) (0 for uniform):
        ``log(p(q) + p(-q)) + log(n / 2)``."""
        log_p = torch.log_softmax(raw, dim=-1)
        q = rotmat_to_quat(R).to(log_p.dtype)
        dots = q @ self.grid.to(q.dtype).T
        near_pos = log_p.gather(-1, dots.argmax(-1, keepdim=True)).squeeze(-1)
        near_neg = log_p.gather(-1, dots.argmin(-1, keepdim=True)).squeeze(-1)
        return torch.logaddexp(near_pos, near_neg) + math.log(self.grid.shape[0] / 2)

    def uncertainty(self, raw: Tensor) -> Tensor:
        """(B,) ``(4 / 3) (1 - lambda_max(M))`` in [0, 1]."""
        lam = torch.linalg.eigvalsh(self._scatter(self.distribution(raw)))[..., -1]
        return (4 / 3) * (1 - lam)
