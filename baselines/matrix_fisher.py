"""Matrix Fisher distribution on SO(3) (Mohlin, Sullivan and Bianchi, NeurIPS 2020).

Representation: the network outputs 9 unconstrained numbers ``A (B, 3, 3)`` (the raw) and
``F = output_scale * A`` (default 30). The predicted density w.r.t. the normalised Haar measure on
SO(3) (total mass 1) is::

    p(R | F) = exp(tr(F^T R)) / c(F)

Why the scale: the NLL has no finite minimiser (it keeps falling as F grows along the label), and
the concentrations a few-degree prediction needs are ~1e2 (angular std ~ 1/sqrt(s_i + s_j)), far
from the unit scale of a linear layer's output. Adam, which steps every coordinate by ~lr, first
grows F along ``sign(R_gt)`` and only slowly turns it to ``R_gt``; measured with the boundary
tests' Adam on the raw (300 steps, lr 0.05, tests/baselines/test_head_boundaries.py) the mode
ends max 2.2 deg from the label with scale 1, 0.48 with 10, 0.25 with 30.

Proper SVD: ``F = U diag(s1, s2, s3) V^T`` with ``U, V`` rotations, ``s1 >= s2 >= |s3|`` and
``s3`` carrying the sign of ``det F``. Since ``det U det V = sign(det F)``, the proper singular
values are ``svdvals(F)`` with the last multiplied by ``sign(det F)``; ``svdvals`` has a backward
without the ``1 / (s_i^2 - s_j^2)`` terms of the full SVD, so gradients stay finite at repeated
singular values (e.g. ``F = k I``).

Normaliser (Mohlin et al.'s 1-D integral, w.r.t. the normalised Haar measure, ``c(0) = 1``)::

    c(F) = c(S) = int_{-1}^{1} 1/2 I0((s1 - s2)(1 - u) / 2) I0((s1 + s2)(1 + u) / 2) exp(s3 u) du

With ``I0(x) = i0e(x) e^x`` the exponents add up to ``s1 + (s2 + s3) u``, so
``log c = s1 + s2 + s3 + log int 1/2 i0e(.) i0e(.) exp(-(s2 + s3)(1 - u)) du``: nothing overflows,
and the remaining integrand is at most 1/2. For large concentrations it lives in boundary layers
of width ``1 / (s2 + s3)`` at ``u = 1`` and ``1 / (s1 + s2)`` at ``u = -1``, which a fixed
Gauss-Legendre rule on [-1, 1] cannot resolve. We use tanh-sinh (double exponential) quadrature
instead, ``u = tanh(pi/2 sinh x)``, trapezoid in x with step 1/32 on [-3.5, 3.5] (225 nodes),
which clusters nodes doubly exponentially at both ends (``1 - u`` down to 1e-18, computed directly,
not as ``1 - tanh``), in float64 whatever the input dtype. Measured against scipy ``quad`` of the
same integral with ``scipy.special.ive`` (tolerance 1e-13), the error of ``log c`` is below 1e-15
for singular values ~1e-4, below 1e-12 for (1, 0.5, 0.2) ... (1e3, 1e3, 1e3), (1e3, 0, 0),
(1e3, 500, -499), and 4e-12 at (1e4, 1e4, 1e4); with step 1/16 it would be 2e-7 there (step 1/8:
3e-3). ``tests/baselines/test_matrix_fisher.py`` checks it against scipy and against Monte Carlo
integration over SO(3).

Loss: the negative log-likelihood ``log c(F) - tr(F^T R_gt)``, mean over the batch.

Decoding: the mode ``U V^T`` with the determinant fix (``special_orthogonalize(F)``), the maximiser
of ``tr(F^T R)``.

Uncertainty (``gives_uncertainty``): ``E[sin^2(theta / 2)]``, theta the angle between R and the
mode, in [0, 1]: 0 for a point mass, 3/4 for the uniform distribution (F = 0), decreasing with the
concentration. Because ``E[R] = U diag(d log c / ds) V^T``, ``E[cos theta] = (sum_i d log c / ds_i
- 1) / 2``, and the derivatives are quadratures of the same integral with
``d/ds I0(x) = I1(x) dx/ds``. For a concentrated distribution it is ~``(1/4) sum_{i<j} 1 / (s_i +
s_j)``, a quarter of the expected squared angle. ``log_prob`` (``gives_log_prob``) is the log
density above. ``is_probabilistic`` stays False: there is no grid distribution.

Discontinuities: none in the density or the loss (smooth in F; the NLL is convex in F). The mode is
not unique where ``s2 + s3 = 0`` (e.g. F = 0, or rank-1 F); there the decode is arbitrary among the
maximisers, exactly as SVD orthogonalisation (``re_net_r``).
"""

from __future__ import annotations

import math
from functools import lru_cache

import torch
from torch import Tensor

from benchmark.geometry import special_orthogonalize
from benchmark.models import AttitudeHead, mlp, register_head
from benchmark.models.heads import check_option

QUADRATURE_STEP = 1 / 32  # tanh-sinh step in x; error of log c measured above
QUADRATURE_RANGE = 3.5  # x in [-3.5, 3.5]: 1 - u down to ~1e-18, weights beyond < 1e-18


@lru_cache(maxsize=1)
def tanh_sinh_nodes() -> tuple[Tensor, Tensor, Tensor]:
    """``(1 - u, 1 + u, weight)``, each ``(K,)`` float64, of the tanh-sinh rule on [-1, 1].

    ``u = tanh(y)``, ``y = pi/2 sinh(x)``; ``1 -+ u = 2 e^(-+y) / (e^y + e^-y)`` exactly, so the
    nodes next to the ends keep their relative precision; ``weight = h pi/2 cosh x / cosh^2 y``.
    """
    h = QUADRATURE_STEP
    n = round(QUADRATURE_RANGE / h)
    x = torch.arange(-n, n + 1, dtype=torch.float64) * h
    y = math.pi / 2 * torch.sinh(x)
    total = torch.exp(y) + torch.exp(-y)
    weight = h * math.pi / 2 * torch.cosh(x) / torch.cosh(y) ** 2
    return 2 * torch.exp(-y) / total, 2 * torch.exp(y) / total, weight


def proper_singular_values(F: Tensor) -> Tensor:
    """``(..., 3, 3) -> (..., 3)``: ``(s1, s2, s3)`` of the proper SVD ``F = U S V^T``, ``U, V``
    rotations: ``s1 >= s2 >= |s3|``, ``sign(s3) = sign(det F)`` (+ where ``det F = 0``)."""
    s = torch.linalg.svdvals(F)
    sign = torch.where(torch.linalg.det(F.detach()) < 0, -1.0, 1.0).to(F.dtype)
    return torch.cat([s[..., :2], s[..., 2:] * sign[..., None]], dim=-1)


def _log_integrand_parts(s: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Shared pieces for ``log c`` and its derivatives, at the quadrature nodes (float64).

    Returns ``(a, b, log_rest, one_plus)``: the Bessel arguments ``a = (s1 - s2)(1 - u)/2``,
    ``b = (s1 + s2)(1 + u)/2`` ``(..., K)``, ``log_rest = log(w/2) - (s2 + s3)(1 - u)``, and
    ``1 + u`` ``(K,)``.
    """
    one_minus, one_plus, weight = (t.to(s.device) for t in tanh_sinh_nodes())
    s1, s2, s3 = s[..., 0:1], s[..., 1:2], s[..., 2:3]
    a = 0.5 * (s1 - s2) * one_minus
    b = 0.5 * (s1 + s2) * one_plus
    log_rest = torch.log(0.5 * weight) - (s2 + s3) * one_minus
    return a, b, log_rest, one_plus


def log_normaliser(s: Tensor) -> Tensor:
    """``log c(S)`` of the matrix Fisher distribution (normalised Haar measure, ``log c(0) = 0``).

    Args:
        s: ``(..., 3)`` proper singular values (``proper_singular_values``), any float dtype.
    Returns:
        ``(...)`` in the dtype of ``s``; computed in float64 by tanh-sinh quadrature (module
        docstring for the accuracy), differentiable (autograd through ``i0e``).
    """
    s64 = s.double()
    a, b, log_rest, _ = _log_integrand_parts(s64)
    log_terms = torch.log(torch.special.i0e(a)) + torch.log(torch.special.i0e(b)) + log_rest
    return (s64.sum(-1) + torch.logsumexp(log_terms, dim=-1)).to(s.dtype)


def mean_trace(s: Tensor) -> Tensor:
    """``E[tr(M^T R)] = sum_i d log c / d s_i`` in [-1, 3], M the mode (``(..., 3) -> (...)``).

    ``sum_i d/ds_i`` of the integrand is ``1/2 I0(a) I1(b) (1 + u) e^(s3 u) + u f(u)``: the
    ``s1 - s2`` argument cancels. Evaluated with the same nodes, exponentially scaled like
    ``log_normaliser``, in float64.
    """
    s64 = s.double()
    a, b, log_rest, one_plus = _log_integrand_parts(s64)
    log_f = torch.log(torch.special.i0e(a)) + torch.log(torch.special.i0e(b)) + log_rest
    # I1(b)/I0(b) = i1e(b)/i0e(b); u = (1 + u) - 1.
    ratio = torch.special.i1e(b) / torch.special.i0e(b)
    weight = torch.softmax(log_f, dim=-1)  # f(u_k) w_k / c, the posterior over the nodes
    return (weight * (ratio * one_plus + one_plus - 1)).sum(-1).to(s.dtype)


@register_head("matrix_fisher")
class MatrixFisher(AttitudeHead):
    """Matrix Fisher density head. Args: in_features; hidden (1024, the regression heads' width);
    output_scale (30, > 0): ``F = output_scale * raw``.

    raw: ``A (B, 3, 3)``. ``log_prob``, ``uncertainty`` as in the module docstring.
    """

    paper_name = "Matrix Fisher (Mohlin et al. 2020)"
    gives_log_prob = True
    gives_uncertainty = True

    def __init__(self, in_features: int, hidden: int = 1024, output_scale: float = 30.0) -> None:
        super().__init__(in_features)
        if isinstance(hidden, bool) or not isinstance(hidden, int) or hidden <= 0:
            raise ValueError(f"matrix_fisher: hidden must be a positive int, got {hidden!r}")
        self.output_scale = check_option(output_scale, "output_scale", "matrix_fisher")
        self.net = mlp(in_features, hidden, 9)

    def forward(self, features: Tensor) -> Tensor:
        """(B, F) -> raw ``A (B, 3, 3)``, unconstrained; ``F = output_scale * A``."""
        return self.net(features).view(-1, 3, 3)

    def parameter(self, raw: Tensor) -> Tensor:
        """(B, 3, 3) raw -> the matrix Fisher parameter ``F = output_scale * raw``."""
        return self.output_scale * raw

    def decode(self, raw: Tensor) -> Tensor:
        """(B, 3, 3) -> (B, 3, 3): the mode ``U V^T`` (det +1) of ``F`` (the same as of raw)."""
        return special_orthogonalize(raw)

    def log_prob(self, raw: Tensor, R: Tensor) -> Tensor:
        """(B,) ``tr(F^T R) - log c(F)``, nats w.r.t. the normalised Haar measure."""
        F = self.parameter(raw)
        trace = (F * R.to(F.dtype)).sum(dim=(-1, -2))
        return trace - log_normaliser(proper_singular_values(F))

    def log_prob_many(self, raw: Tensor, R: Tensor) -> Tensor:
        """``log_prob`` of ``R (B, K, 3, 3)``, K rotations per sample -> ``(B, K)``: the
        normaliser's quadrature (and its SVD) once per sample, not once per rotation."""
        F = self.parameter(raw)
        trace = (F[:, None] * R.to(F.dtype)).sum(dim=(-1, -2))
        return trace - log_normaliser(proper_singular_values(F))[:, None]

    def loss(self, raw: Tensor, R_gt: Tensor) -> Tensor:
        """Negative log-likelihood of ``R_gt (B, 3, 3)``, mean over the batch."""
        return -self.log_prob(raw, R_gt).mean()

    def uncertainty(self, raw: Tensor) -> Tensor:
        """(B,) ``E[sin^2(theta/2)] = (3 - E[tr(M^T R)]) / 4`` in [0, 1] (3/4 when uniform)."""
        return ((3 - mean_trace(proper_singular_values(self.parameter(raw)))) / 4).clamp(0, 1)
