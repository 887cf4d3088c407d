"""Sphere lattices and the von Mises-Fisher distribution (paper Sec. 2.2.2, Eq. 8-10).

The paper samples "64 x 64" points on S^2 with a Fibonacci lattice (its ref. 33); we use the
equal-area spherical Fibonacci lattice with n = 4096 points. For quaternion heads (Pd-Net-Q,
"16^3 over the 4D unit sphere") we provide the super-Fibonacci spiral on S^3 (Alexa, CVPR 2022).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from benchmark.geometry._checks import check_finite, check_last_dims, check_positive, check_tensor

__all__ = [
    "discrete_vmf",
    "fibonacci_sphere",
    "spherical_mean",
    "super_fibonacci",
    "vmf_density",
    "vmf_log_density",
]

_GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))
# Real root of psi^4 = psi + 4 (Alexa 2022): with phi = sqrt(2) the two spiral frequencies whose
# ratio is "most irrational", giving the most uniform super-Fibonacci lattice.
_SUPER_FIB_PSI = 1.533751168755204288118041


def _check_count(n: int, name: str = "n") -> None:
    if not isinstance(n, int) or isinstance(n, bool) or n < 1:
        raise ValueError(f"{name} must be a positive int, got {n!r}")


def fibonacci_sphere(
    n: int = 4096, dtype: torch.dtype = torch.float32, device: torch.device | str | None = None
) -> Tensor:
    """Equal-area spherical Fibonacci lattice: ``n`` nearly uniform unit vectors.

    Point i sits at height ``z_i = 1 - (2 i + 1) / n`` (equal-area bands) and longitude
    ``i * golden_angle``. Computed in float64, then cast, so every dtype gets the same points.

    Returns:
        ``(n, 3)`` unit vectors.
    """
    _check_count(n)
    i = torch.arange(n, dtype=torch.float64)
    z = 1.0 - (2.0 * i + 1.0) / n
    r = torch.sqrt((1.0 - z * z).clamp_min(0.0))
    lon = i * _GOLDEN_ANGLE
    pts = torch.stack([r * torch.cos(lon), r * torch.sin(lon), z], dim=-1)
    return pts.to(dtype=dtype, device=device)


def super_fibonacci(
    n: int = 4096, dtype: torch.dtype = torch.float32, device: torch.device | str | None = None
) -> Tensor:
    """Super-Fibonacci spiral: ``n`` nearly uniform unit quaternions on S^3 (Alexa 2022).

    Point i: ``s = i + 1/2``, ``r = sqrt(s/n)``, ``R = sqrt(1 - s/n)``,
    ``alpha = 2 pi s / sqrt(2)``, ``beta = 2 pi s / psi``; ``q = (r sin alpha, r cos alpha,
    R sin beta, R cos beta)`` read as ``(w, x, y, z)``. Covers all of S^3, i.e. every rotation twice
    (``q`` and ``-q``).

    Returns:
        ``(n, 4)`` unit quaternions ``(w, x, y, z)``.
    """
    _check_count(n)
    s = torch.arange(n, dtype=torch.float64) + 0.5
    r = torch.sqrt(s / n)
    big_r = torch.sqrt(1.0 - s / n)
    alpha = 2.0 * math.pi * s / math.sqrt(2.0)
    beta = 2.0 * math.pi * s / _SUPER_FIB_PSI
    q = torch.stack(
        [
            r * torch.sin(alpha),
            r * torch.cos(alpha),
            big_r * torch.sin(beta),
            big_r * torch.cos(beta),
        ],
        dim=-1,
    )
    return q.to(dtype=dtype, device=device)


def _log_normaliser(kappa: Tensor, dim: int) -> Tensor:
    """``log C_d(kappa) + kappa`` for the vMF density on S^{d-1}, stable for kappa up to 1e4+.

    Eq. 8: ``C_d = kappa^{d/2-1} / ((2 pi)^{d/2} I_{d/2-1}(kappa))``. We return it shifted by
    ``+kappa`` so that the density is evaluated as ``exp(shifted + kappa (mu.x - 1))``: no
    ``exp(kappa)`` ever overflows.
      d = 3: ``C_3 = kappa / (4 pi sinh kappa)``, so
             ``log C_3 + kappa = log kappa - log(2 pi) - log1p(-exp(-2 kappa))``.
      d = 4: ``C_4 = kappa / (4 pi^2 I_1(kappa))`` and ``I_1(k) = i1e(k) e^k``, so
             ``log C_4 + kappa = log kappa - log(4 pi^2) - log i1e(kappa)``.
    """
    if dim == 3:
        return torch.log(kappa) - math.log(2 * math.pi) - torch.log1p(-torch.exp(-2 * kappa))
    if dim == 4:
        return torch.log(kappa) - math.log(4 * math.pi**2) - torch.log(torch.special.i1e(kappa))
    raise ValueError(
        f"vMF density implemented for S^2 and S^3 (last dim 3 or 4), got last dim {dim}"
    )


def _check_points(x: Tensor, name: str) -> Tensor:
    x = check_tensor(x, name)
    if x.dim() < 1 or x.shape[-1] not in (3, 4):
        raise ValueError(f"{name} must have shape (..., 3) or (..., 4), got {tuple(x.shape)}")
    check_finite(x, name)
    return x


def _check_grid(grid: Tensor) -> Tensor:
    grid = _check_points(grid, "grid")
    if grid.dim() != 2:
        raise ValueError(f"grid must have shape (n, d), got {tuple(grid.shape)}")
    return grid


def _check_unit(x: Tensor, name: str) -> None:
    norm = torch.linalg.vector_norm(x.detach(), dim=-1)
    tol = 1e-3 if x.dtype in (torch.float16, torch.bfloat16, torch.float32) else 1e-6
    if bool(((norm - 1).abs() > tol).any()):
        worst = float(norm.flatten()[(norm - 1).abs().flatten().argmax()])
        raise ValueError(
            f"{name} must contain unit vectors, found norm {worst:.6g}, shape {tuple(x.shape)}"
        )


def vmf_log_density(x: Tensor, mu: Tensor, kappa: float | Tensor) -> Tensor:
    """Log of the von Mises-Fisher density (paper Eq. 8) on S^2 or S^3 w.r.t. surface measure.

    Args:
        x: ``(..., d)`` unit vectors, d in {3, 4}.
        mu: ``(..., d)`` unit mean directions, broadcastable against ``x``.
        kappa: concentration > 0, a float or a tensor broadcastable against ``(...)``.
    Returns:
        ``(...)``. Stable for kappa up to at least 1e4 in float32 (no ``exp(kappa)`` is formed).
    """
    x = _check_points(x, "x")
    mu = check_last_dims(mu, (x.shape[-1],), "mu")
    _check_unit(x, "x")
    _check_unit(mu, "mu")
    check_positive(kappa, "kappa")
    k = torch.as_tensor(kappa, dtype=x.dtype, device=x.device)
    return _log_normaliser(k, x.shape[-1]) + k * ((mu * x).sum(-1) - 1)


def vmf_density(x: Tensor, mu: Tensor, kappa: float | Tensor) -> Tensor:
    """von Mises-Fisher density (paper Eq. 8); see :func:`vmf_log_density`. Returns ``(...)``."""
    return torch.exp(vmf_log_density(x, mu, kappa))


def discrete_vmf(mu: Tensor, kappa: float | Tensor, grid: Tensor) -> Tensor:
    """The vMF around ``mu`` evaluated on a lattice and normalised to sum 1 (paper Eq. 10 target).

    ``p_i = exp(kappa mu.x_i) / sum_j exp(kappa mu.x_j)``: the normaliser of Eq. 8 cancels, so this
    is a softmax, exact for any kappa. On an equal-area lattice of n points, ``p_i * n / (4 pi)``
    approximates the continuous density (for kappa small enough that the lattice resolves it).

    Args:
        mu: ``(..., d)`` unit mean directions.
        kappa: > 0, float or tensor broadcastable against ``(...)`` (use ``kappa[..., None]``
            shapes are handled: a tensor kappa of shape ``(...)`` is broadcast over the grid).
        grid: ``(n, d)`` lattice.
    Returns:
        ``(..., n)`` probabilities.
    """
    grid = _check_grid(grid)
    mu = check_last_dims(mu, (grid.shape[-1],), "mu")
    _check_unit(mu, "mu")
    check_positive(kappa, "kappa")
    k = torch.as_tensor(kappa, dtype=mu.dtype, device=mu.device)
    if k.dim() > 0:
        k = k[..., None]
    logits = k * (mu @ grid.to(mu.dtype).transpose(0, 1))
    return torch.softmax(logits, dim=-1)


def spherical_mean(p: Tensor, grid: Tensor) -> Tensor:
    """Mean direction of a distribution on a lattice (paper Eq. 9): ``sum p_i x_i / |sum p_i x_i|``.

    Args:
        p: ``(..., n)`` non-negative weights (need not sum to 1: the normalisation cancels).
        grid: ``(n, d)`` lattice.
    Returns:
        ``(..., d)`` unit vectors. Undefined when the resultant vanishes (e.g. a uniform ``p``);
        the norm is clamped at 1e-12 so the result stays finite but arbitrary there.
    """
    grid = _check_grid(grid)
    p = check_last_dims(p, (grid.shape[0],), "p")
    resultant = p @ grid.to(p.dtype)
    return resultant / torch.linalg.vector_norm(resultant, dim=-1, keepdim=True).clamp_min(1e-12)
