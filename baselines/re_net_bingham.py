"""Re-Net-A: a symmetric 4x4 matrix A, the rotation its smallest eigenvector (Peretroukhin et
al., "A Smooth Representation of Belief over SO(3)", RSS 2020).

Representation: the network regresses 10 numbers (raw ``(B, 10)``), the upper triangle of a
symmetric ``A (B, 4, 4)`` row by row (``torch.triu_indices(4, 4)`` order), mirrored below the
diagonal. ``A`` is unconstrained (not PSD): only its eigenvectors and eigenvalue gaps matter.

Decoding: the unit quaternion ``q = (w, x, y, z)`` (project convention, w first) that minimises
``q^T A q`` on S^3, i.e. the eigenvector of the SMALLEST eigenvalue of A (``torch.linalg.eigh``);
``q`` and ``-q`` are the same rotation, so the eigenvector's arbitrary sign does not matter.

Loss: Peretroukhin's antipodally symmetric quaternion chordal loss
``min(|q - q*|^2, |q + q*|^2) = 2 (1 - |q.q*|)``, ``q* = rotmat_to_quat(R_gt)``, batch mean.
Chosen over the equivalent-at-the-optimum ``1 - (q.q*)^2`` (= ``||R - R*||_F^2 / 8``) because it is
the paper's and because its gradient does not vanish at the worst prediction (``q.q* = 0``,
180 deg away), where ``1 - (q.q*)^2`` is stationary. Both are invariant to the signs of q, q*.

Gradient at near-equal eigenvalues: the derivative of the smallest eigenvector is
``dq = sum_{j>1} v_j (v_j^T dA q) / (lambda_1 - lambda_j)``: only the gaps to lambda_1 enter.
torch's generic ``eigh`` backward divides by every difference ``lambda_i - lambda_j`` and returns
NaN when two of the OTHER eigenvalues coincide (e.g. an untrained, nearly diagonal A), although q is
perfectly smooth there. ``_SmallestEigenpair`` therefore has its own backward with only the three
gaps to lambda_1, each clamped at ``GAP_EPS`` (1e-6): at a true tie ``lambda_1 = lambda_2`` (where
the decoded rotation itself is not unique) the gradient is finite, at most ~1e6 times the upstream
one.

Uncertainty (``gives_uncertainty``): ``1 / (1 + gap)`` with ``gap = lambda_2 - lambda_1 >= 0``, in
(0, 1]: 1 when the minimiser is not unique (no information), -> 0 as the Bingham density
concentrates. A strictly decreasing function of the eigen-gap, so rank correlations with the error
are those of ``-gap``; unlike ``1 / gap`` it is finite at a tie.

Log density (``gives_log_prob``): A defines the Bingham density ``p(q) ∝ exp(-q^T A q)`` on S^3,
antipodally symmetric, hence a density on SO(3). ``log_prob(raw, R)`` is its log w.r.t. the
normalised Haar measure (a uniform prediction, ``A = c I``, scores 0)::

    log p(R) = -(q^T A q - lambda_1) - log E_{u ~ S^3}[exp(-(u^T A u - lambda_1))]

Subtracting lambda_1 makes every exponent <= 0 (no overflow for any scale of A). The normaliser
uses the eigenbasis: with gaps ``g_j = lambda_j - lambda_1`` (j = 2, 3, 4) and ``u = (cos psi,
sin psi s)``, ``s`` on S^2, the psi-integral is closed form,
``int_0^pi sin^2(psi) exp(-k sin^2 psi) dpsi = (pi / 2) (i0e(k/2) - i1e(k/2))``, ``k = sum_j g_j
s_j^2``, so ``E[...] = mean over s on S^2 of (i0e(k/2) - i1e(k/2))``, in float64 (the difference
cancels ~log10(k) digits). That smooth 2-D integral is done by a 48 x 48 Gauss-Legendre rule on one
octant whose nodes cluster at the integrand's peak (``log_mean_bingham``). Measured error against
adaptive quadrature (scipy): < 1e-9 nats for gaps up to 1e3, < 3e-5 for gap ratios up to 1e6
(e.g. gaps (1, 1e6, 1e6) or (0, 1, 1e6)), 2e-6 for (0, 0, 1e5), 1e-3 for (1e-8, 1e-8, 1e8). A
quadrature on a Haar-uniform grid (as ``column_product_log_density`` does for the lattice heads,
and as the tests do as a reference for broad A) must resolve a peak of width ~``1 / sqrt(gap)``:
with 2^15 super-Fibonacci rotations it is within 0.001 nats up to gaps of 100, off by 0.01 at 300,
0.6 at 1e3 and up to 15 at 1e4 (measured at isotropic gaps), and the chordal loss leaves A's scale
free, so such gaps occur. Note that the loss trains only the
eigenvector: the scale of A (hence the log-likelihood's calibration and the uncertainty's scale) is
whatever training leaves, as in Peretroukhin et al.

Discontinuities: none in the representation (the label map is continuous on S^3/{+-1}; any A with
that smallest eigenvector encodes R). Decoding is discontinuous only where lambda_1 = lambda_2 (the
minimiser is not unique: a prediction of no information, never a label's own raw).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
import torch
from torch import Tensor

from benchmark.geometry import quat_to_rotmat, rotmat_to_quat
from benchmark.models import RegressionAttitudeHead, register_head

GAP_EPS = 1e-6  # eigenvalue gaps below this are clamped in the eigenvector's backward
# The normaliser's remaining 2-D integral: m x m Gauss-Legendre nodes after the substitution
# t = v^3, phi = (pi/2) w^3, which clusters them at the integrand's peak (see log_mean_bingham).
NORMALISER_RULE = (48, 3)
_ROWS, _COLS = torch.triu_indices(4, 4)


def symmetric_matrix(raw: Tensor) -> Tensor:
    """``(..., 10)`` upper-triangle entries (row by row) -> ``(..., 4, 4)`` symmetric A."""
    A = raw.new_zeros(*raw.shape[:-1], 4, 4)
    A[..., _ROWS, _COLS] = raw
    A[..., _COLS, _ROWS] = raw
    return A


class _SmallestEigenpair(torch.autograd.Function):
    """``A (..., 4, 4)`` symmetric -> (eigenvalues ``(..., 4)`` ascending, eigenvector of the
    smallest ``(..., 4)``), with a backward that only divides by the gaps to lambda_1 (module
    docstring). The returned input gradient is symmetrised (A is symmetric)."""

    @staticmethod
    def forward(ctx, A: Tensor) -> tuple[Tensor, Tensor]:  # type: ignore[override]
        L, V = torch.linalg.eigh(A)
        ctx.save_for_backward(L, V)
        return L, V[..., 0].clone()

    @staticmethod
    def backward(ctx, grad_L: Tensor, grad_q: Tensor) -> Tensor:  # type: ignore[override]
        L, V = ctx.saved_tensors
        G = (V * grad_L[..., None, :]) @ V.transpose(-1, -2)  # sum_i gL_i v_i v_i^T
        gaps = (L[..., 1:] - L[..., :1]).clamp_min(GAP_EPS)  # lambda_j - lambda_1, j > 1
        others = V[..., 1:]  # (..., 4, 3)
        coef = -(others.transpose(-1, -2) @ grad_q[..., None]).squeeze(-1) / gaps
        G = G + (others @ coef[..., None]) @ V[..., :1].transpose(-1, -2)  # sum_j c_j v_j v_1^T
        return (G + G.transpose(-1, -2)) / 2


def smallest_eigenpair(A: Tensor) -> tuple[Tensor, Tensor]:
    """Eigenvalues ``(..., 4)`` ascending and the unit eigenvector ``(..., 4)`` of the smallest."""
    return _SmallestEigenpair.apply(A)


@lru_cache(maxsize=2)
def _normaliser_nodes(m: int, power: int) -> tuple[Tensor, Tensor, Tensor]:
    """Product Gauss-Legendre rule on the octant ``t = cos(theta) in [0, 1]``, ``phi in [0, pi/2]``
    after ``t = v^power``, ``phi = (pi/2) w^power``: nodes ``t``, ``phi`` ``(m, 1)``, ``(1, m)`` and
    weights ``(m, m)`` summing to 1 (float64)."""
    x, w = np.polynomial.legendre.leggauss(m)
    v, wv = (x + 1) / 2, w / 2  # Gauss-Legendre on [0, 1]
    nodes, weights = v**power, wv * power * v ** (power - 1)  # the same after v -> v^power
    weights = np.outer(weights, weights)
    t, phi = torch.from_numpy(nodes)[:, None], torch.from_numpy(nodes * math.pi / 2)[None, :]
    return t, phi, torch.from_numpy(weights / weights.sum())


def log_mean_bingham(gaps: Tensor) -> Tensor:
    """``log E_{u ~ uniform S^3}[exp(-sum_j g_j u_j^2)]`` for ascending gaps ``(..., 3) >= 0``.

    Returns ``(...)`` in the dtype of ``gaps``, computed in float64: the Bingham normaliser relative
    to the uniform density, 0 for zero gaps, ``-log(pi g1 g2 g3) / 2`` asymptotically (Laplace).
    See the module docstring for the reduction to ``mean over s on S^2 of i0e(k/2) - i1e(k/2)``;
    by symmetry the mean is over one octant, ``s = (sqrt(1 - t^2) cos phi, sqrt(1 - t^2) sin phi,
    t)`` (uniform in t and phi). The integrand peaks where k is smallest, at t = phi = 0 for
    ascending gaps, with widths ~``sqrt(g1 / g3)``, ``sqrt(g1 / g2)``; the rule's nodes cluster
    there (``NORMALISER_POWER``).
    """
    g = gaps.double()[..., None, None, :]  # (..., 1, 1, 3)
    t, phi, weights = (x.to(gaps.device) for x in _normaliser_nodes(*NORMALISER_RULE))
    sin2 = 1 - t * t
    k = (
        sin2 * (g[..., 0] * torch.cos(phi) ** 2 + g[..., 1] * torch.sin(phi) ** 2)
        + g[..., 2] * t * t
    )
    integrand = torch.special.i0e(k / 2) - torch.special.i1e(k / 2)  # (..., m, m)
    return torch.log((integrand * weights).sum((-1, -2))).to(gaps.dtype)


@register_head("re_net_bingham")
class ReNetBingham(RegressionAttitudeHead):
    """Args: in_features; hidden (1024), the width of the 2-layer MLP.

    ``forward``: features ``(B, F)`` -> raw ``(B, 10)``, the upper triangle of A.
    ``decode``: ``(B, 3, 3)`` det +1. ``loss``: scalar chordal quaternion loss, batch mean.
    ``uncertainty``: ``(B,)`` in (0, 1]. ``log_prob(raw, R (B, 3, 3))``: ``(B,)`` nats.
    """

    paper_name = "Re-Net-A (Peretroukhin et al. 2020)"
    gives_log_prob = True
    gives_uncertainty = True
    raw_shape = (10,)

    def normalize(self, raw: Tensor) -> Tensor:
        """(B, 10) -> (B, 4) unit quaternion (w, x, y, z) minimising q^T A q (sign arbitrary)."""
        return smallest_eigenpair(symmetric_matrix(raw))[1]

    def encode(self, R: Tensor) -> Tensor:
        return rotmat_to_quat(R)

    def to_label(self, q: Tensor) -> Tensor:
        return quat_to_rotmat(q)

    def distance(self, q: Tensor, q_gt: Tensor) -> Tensor:
        """(B,) Peretroukhin's chordal ``min(|q - q*|^2, |q + q*|^2)``."""
        return torch.minimum(((q - q_gt) ** 2).sum(-1), ((q + q_gt) ** 2).sum(-1))

    def uncertainty(self, raw: Tensor) -> Tensor:
        L = smallest_eigenpair(symmetric_matrix(raw))[0]
        return 1 / (1 + (L[..., 1] - L[..., 0]))

    def log_prob(self, raw: Tensor, R: Tensor) -> Tensor:
        A = symmetric_matrix(raw)
        L = smallest_eigenpair(A)[0]
        q = rotmat_to_quat(R).to(raw.dtype)
        energy = (q[..., None, :] @ A @ q[..., :, None]).squeeze(-1).squeeze(-1) - L[..., 0]
        return -energy - log_mean_bingham(L[..., 1:] - L[..., :1])

    def log_prob_many(self, raw: Tensor, R: Tensor) -> Tensor:
        """``log_prob`` of ``R (B, K, 3, 3)``, K rotations per sample -> ``(B, K)``: the
        eigendecomposition and the normaliser's quadrature once per sample."""
        A = symmetric_matrix(raw)
        L = smallest_eigenpair(A)[0]
        q = rotmat_to_quat(R).to(raw.dtype)  # (B, K, 4)
        energy = torch.einsum("bki,bij,bkj->bk", q, A, q) - L[..., :1]
        return -energy - log_mean_bingham(L[..., 1:] - L[..., :1])[:, None]
