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

import torch
from torch import Tensor

from benchmark.geometry import quat_to_rotmat, rotmat_to_quat, super_fibonacci
from benchmark.models import LatticeHead, register_head


@register_head("pd_net_q_sym")
class PdNetQSym(LatticeHead):
    """Options: n_points (4096), kappa (10), alpha (8e7), hidden (160). Raw: logits (B, n).

    Pd-Net-Q's lattice (S^3) with another label, target, Eq. 13 resultant, decoding and
    uncertainty; decoder, distribution, ``log_prob`` and the loss's wiring are ``LatticeHead``'s.
    """

    paper_name = "Pd-Net-Q-sym"
    version = 1
    min_points = 8
    lattice = staticmethod(super_fibonacci)

    def target(self, q: Tensor, grid: Tensor) -> Tensor:
        """The antipodal vMF mixture ``softmax_k log(exp(kappa q.x_k) + exp(-kappa q.x_k))``."""
        dots = self.kappa * (q @ grid.T)
        return torch.softmax(torch.logaddexp(dots, -dots), dim=-1)

    def encode(self, R: Tensor) -> Tensor:
        """(B, 3, 3) -> (B, 4) a unit quaternion of R, either sign."""
        return rotmat_to_quat(R)

    def loss_resultant(self, p: Tensor, q: Tensor, grid: Tensor) -> Tensor:
        """``sum_k p_k sign(q.x_k) x_k``: every lattice point folded onto the label's hemisphere."""
        signs = torch.where(q @ grid.T < 0, -1.0, 1.0).to(p.dtype)
        return (p * signs) @ grid

    def _scatter(self, p: Tensor) -> Tensor:
        grid = self.grid.to(p.dtype)
        return torch.einsum("bk,ki,kj->bij", p, grid, grid)  # (B, 4, 4), trace 1

    def decode_distribution(self, p: Tensor) -> Tensor:
        """(B, n) -> (B, 3, 3): the principal eigenvector of ``M = sum_k p_k x_k x_k^T``."""
        _, vectors = torch.linalg.eigh(self._scatter(p))  # ascending eigenvalues
        return quat_to_rotmat(vectors[..., -1])

    def uncertainty(self, raw: Tensor) -> Tensor:
        """(B,) ``(4 / 3) (1 - lambda_max(M))`` in [0, 1]."""
        lam = torch.linalg.eigvalsh(self._scatter(self.distribution(raw)))[..., -1]
        return (4 / 3) * (1 - lam)
