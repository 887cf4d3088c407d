"""Grids, beliefs and the odometry transition of the flight fusion (issue 39, item 3).

**Beliefs.** A belief is a log-density on a regular grid, with respect to the grid's own measure:

- yaw: :class:`CircularGrid` ``(n_bins)``, centres ``psi_j = -pi + j h``, ``h = 2 pi / n_bins``;
  a tensor ``(..., n_bins)`` of log-density per radian. Default 720 bins (0.5 deg).
- position: :class:`PlanarGrid`, centres ``(east0 + i h, north0 + j h)`` metres in the navigation
  frame (ENU); a tensor ``(..., n_east, n_north)`` (E first, as in ``T = [dE, dN, dU]``) of
  log-density per square metre.

A normalised belief has ``exp(L).sum() * cell == 1`` (:func:`normalize_log_density`); the fusion
accepts any log-density up to an additive constant (logits, a head's ``log_prob``).

**Transition** (odometry from sample k-1 to k): shift by the measured increment ``d`` and blur by
the odometry noise, ``p_k(x) = int N(x - x' - d; Sigma) p_{k-1}(x') dx'``, applied as a Fourier
multiplier on the grid: ``P_k(w) = P_{k-1}(w) exp(-i w.d - w^T Sigma w / 2)``. On the circle the
frequencies are the integers and the multiplier is the characteristic function of the *wrapped*
normal, so the wrap-around is exact. Chosen over "interpolate, then convolve with a sampled
kernel" because

- the shift is exact at any sub-bin offset: linear interpolation adds a variance ``f (1 - f) h^2``
  per step (f the fractional offset), up to (0.25 deg)^2 at 0.5 deg bins, more than the
  0.2 deg-per-step noise it would be added to; shifting by ``d`` then ``-d`` is the identity up to
  rounding (bar the Nyquist bin of an even grid, scaled by ``cos^2``);
- the zero frequency is untouched, so mass is conserved exactly, and the first circular moment
  ``E exp(i psi)`` (the mean and variance of a Kalman filter) transforms exactly as in the
  continuous model: grid and closed form differ only by the quadrature of the beliefs themselves;
- ``O(n log n)`` per step, batched over flights.

**Numerics.** The convolution is linear, so it runs on ``exp(L - max L)`` and returns to logs.
A belief sharper than the grid (width below ~2 bins) rings (Gibbs): negative lobes are clipped to
zero and the mass rescaled to what it was. The ringing is bounded by the belief's content at the
Nyquist frequency, negligible for resolved beliefs (von Mises ``kappa <= 1 / (2 h)^2``, Gaussian
``sigma >= 2 h``). Values below ``64 eps`` of the peak (1.4e-14 in float64) are FFT rounding and
are set to zero, whose log is floored at ``log(tiny)`` (-708 in float64, plus the peak's log):
finite, and carrying no mass.

**Plane boundary.** The plane is not periodic: the FFT length per axis is the grid plus a zero pad
of ``|d| / h + 8 sigma / h + 2`` cells (the Gaussian beyond 8 sigma holds < 1e-15), computed per
step and per flight from that step's odometry only (a flight's bits depend neither on later
samples nor on the other flights of a batch), so nothing wraps back into the grid; the result is
cropped. Mass that lands outside the grid leaves the model: :func:`carry_position` returns it as
``escaped`` and renormalises the rest (conditioning on the UAV being on the grid). Size the grid to
cover the flight plus a few belief widths (:meth:`PlanarGrid.around`): then only the uniform
share of a robust posterior reaches the edge, and about ``|d| / width`` of that share escapes per
step (the filters report it). That share ends in a step at the edge, which a sub-cell shift with
less than a cell of blur rings (Gibbs; measured at 5 m cells, 1.3 m blur: up to 13 % of the floor
in the edge cells, 1.3 % ten cells in): it changes the low outlier floor by a bounded factor, not
the mass (another FFT length, hence another ringing pattern, moved the posterior means of the
synthetic test flights by at most 3e-4 m).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from scipy.fft import next_fast_len
from torch import Tensor

# Gaussian tails kept inside the zero pad of the plane, in standard deviations.
_PAD_SIGMAS = 8.0
# Relative level below which an FFT output is rounding, in units of the dtype's eps.
_ROUNDING_EPS = 64.0


@dataclass(frozen=True)
class CircularGrid:
    """Yaw grid: ``n_bins`` centres ``-pi + j 2 pi / n_bins`` (radians), log-density per radian."""

    n_bins: int = 720

    def __post_init__(self) -> None:
        if not isinstance(self.n_bins, int) or self.n_bins < 8:
            raise ValueError(f"n_bins must be an int >= 8, got {self.n_bins!r}")

    @property
    def shape(self) -> tuple[int, ...]:
        return (self.n_bins,)

    @property
    def spacing(self) -> float:
        """Bin width in radians."""
        return 2 * math.pi / self.n_bins

    @property
    def cell(self) -> float:
        """Measure of one cell (radians)."""
        return self.spacing

    @property
    def log_uniform(self) -> float:
        """Log-density of the uniform belief, ``-log(2 pi)``."""
        return -math.log(2 * math.pi)

    def centres(
        self, dtype: torch.dtype = torch.float64, device: torch.device | None = None
    ) -> Tensor:
        """``(n_bins,)`` bin centres in [-pi, pi), radians."""
        j = torch.arange(self.n_bins, dtype=torch.float64)
        return (j * self.spacing - math.pi).to(dtype=dtype, device=device)


@dataclass(frozen=True)
class PlanarGrid:
    """Position grid: ``n_east x n_north`` square cells of ``spacing`` metres; centres
    ``(east0 + i spacing, north0 + j spacing)``; log-density per square metre, axes (E, N)."""

    east0: float
    north0: float
    spacing: float
    n_east: int
    n_north: int

    def __post_init__(self) -> None:
        if not (self.spacing > 0 and math.isfinite(self.spacing)):
            raise ValueError(f"spacing must be positive and finite, got {self.spacing!r}")
        for name in ("n_east", "n_north"):
            n = getattr(self, name)
            if not isinstance(n, int) or n < 3:
                raise ValueError(f"{name} must be an int >= 3, got {n!r}")

    @classmethod
    def around(cls, points: Tensor | np.ndarray, spacing: float, margin: float) -> PlanarGrid:
        """The grid covering ``points (..., 2)`` (E, N metres) plus ``margin`` metres each side."""
        xy = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        low = xy.min(axis=0) - margin
        n = np.ceil((xy.max(axis=0) + margin - low) / spacing).astype(int) + 1
        return cls(float(low[0]), float(low[1]), float(spacing), int(n[0]), int(n[1]))

    @property
    def shape(self) -> tuple[int, ...]:
        return (self.n_east, self.n_north)

    @property
    def cell(self) -> float:
        """Area of one cell, square metres."""
        return self.spacing**2

    @property
    def log_uniform(self) -> float:
        """Log-density of the uniform belief over the grid, ``-log(area)``."""
        return -math.log(self.cell * self.n_east * self.n_north)

    def centres(
        self, dtype: torch.dtype = torch.float64, device: torch.device | None = None
    ) -> tuple[Tensor, Tensor]:
        """``(n_east,)`` east and ``(n_north,)`` north cell centres, metres."""
        east = self.east0 + self.spacing * torch.arange(self.n_east, dtype=torch.float64)
        north = self.north0 + self.spacing * torch.arange(self.n_north, dtype=torch.float64)
        return east.to(dtype=dtype, device=device), north.to(dtype=dtype, device=device)


Grid = CircularGrid | PlanarGrid


def _grid_dims(grid: Grid) -> tuple[int, ...]:
    return tuple(range(-len(grid.shape), 0))


def check_belief(log_density: Tensor, grid: Grid, name: str = "log_density") -> Tensor:
    """Check that ``log_density`` is a float tensor ``(..., *grid.shape)`` without NaN or +inf."""
    if not isinstance(log_density, Tensor) or not log_density.is_floating_point():
        raise ValueError(f"{name} must be a floating point torch.Tensor")
    n = len(grid.shape)
    if tuple(log_density.shape[-n:]) != grid.shape:
        raise ValueError(f"{name} must end in {grid.shape}, got {tuple(log_density.shape)}")
    if bool(torch.isnan(log_density).any() | (log_density == math.inf).any()):
        raise ValueError(f"{name} contains NaN or +inf")
    return log_density


def normalize_log_density(log_density: Tensor, grid: Grid) -> Tensor:
    """Shift ``(..., *grid.shape)`` log-densities so that ``exp(L).sum() * cell == 1`` each."""
    dims = _grid_dims(grid)
    return log_density - (
        torch.logsumexp(log_density, dim=dims, keepdim=True) + math.log(grid.cell)
    )


def von_mises_belief(grid: CircularGrid, mean: float | Tensor, kappa: float | Tensor) -> Tensor:
    """Von Mises belief ``kappa cos(psi - mean)``, normalised on the grid.

    ``mean (...)`` radians, ``kappa`` float or ``(...)`` (1 / kappa ~ variance in rad^2) ->
    ``(..., n_bins)``. Normalised by the grid sum, which equals ``-log(2 pi I0(kappa))`` up to the
    quadrature error (spectrally small for a resolved belief).
    """
    mean = torch.as_tensor(mean, dtype=torch.float64) if not isinstance(mean, Tensor) else mean
    kappa = torch.as_tensor(kappa, dtype=mean.dtype, device=mean.device)
    psi = grid.centres(mean.dtype, mean.device)
    # kappa (cos - 1) <= 0: a large kappa would otherwise cost kappa * eps of the normalisation.
    return normalize_log_density(kappa[..., None] * (torch.cos(psi - mean[..., None]) - 1), grid)


def gaussian_belief(grid: PlanarGrid, mean: Tensor, sigma: float | Tensor) -> Tensor:
    """Isotropic Gaussian belief, normalised on the grid.

    ``mean (..., 2)`` (E, N) metres, ``sigma`` float or ``(...)`` metres ->
    ``(..., n_east, n_north)``.
    """
    sigma = torch.as_tensor(sigma, dtype=mean.dtype, device=mean.device)[..., None, None]
    east, north = grid.centres(mean.dtype, mean.device)
    d2 = (east[:, None] - mean[..., 0, None, None]) ** 2 + (north - mean[..., 1, None, None]) ** 2
    return normalize_log_density(-0.5 * d2 / sigma**2, grid)


def _spectral_apply(
    log_f: Tensor, H: Tensor, size: tuple[int, ...], conserve: bool
) -> tuple[Tensor, Tensor]:
    """Apply the rfft-domain multiplier ``H`` to ``exp(log_f - peak)`` over the last
    ``len(size)`` axes (zero-padded to ``size``): ``(linear result, uncropped, rounding set to
    zero; peak)``."""
    dims = tuple(range(-len(size), 0))
    peak = torch.amax(log_f, dim=dims, keepdim=True).clamp_min(torch.finfo(log_f.dtype).min)
    p = torch.exp(log_f - peak)
    q = torch.fft.irfftn(torch.fft.rfftn(p, s=size, dim=dims) * H, s=size, dim=dims)
    floor = _ROUNDING_EPS * torch.finfo(q.dtype).eps * torch.amax(q, dim=dims, keepdim=True)
    q = torch.where(q > floor, q, torch.zeros_like(q))
    if conserve:  # put back the mass of the clipped negative lobes
        q = q * (p.sum(dim=dims, keepdim=True) / q.sum(dim=dims, keepdim=True))
    return q, peak


def _to_log(q: Tensor, peak: Tensor) -> Tensor:
    return torch.log(q.clamp_min(torch.finfo(q.dtype).tiny)) + peak


def _yaw_transition(
    log_f: Tensor, grid: CircularGrid, shift: Tensor, sigma: Tensor, adjoint: bool
) -> Tensor:
    """Forward (density, mass-conserving) or adjoint (function, ``x -> sum_x' T(x'|x) f(x')``)."""
    m = torch.arange(grid.n_bins // 2 + 1, dtype=log_f.dtype, device=log_f.device)
    phase = m * shift[..., None]
    H = torch.polar(torch.exp(-0.5 * (m * sigma[..., None]) ** 2), phase if adjoint else -phase)
    q, peak = _spectral_apply(log_f, H, grid.shape, conserve=not adjoint)
    return _to_log(q, peak)


def _plane_step(
    log_f: Tensor, grid: PlanarGrid, shift: Tensor, cov: Tensor, adjoint: bool
) -> tuple[Tensor, Tensor]:
    """One flight: ``(n_east, n_north)``, ``shift (2,)``, ``cov (2, 2)``; its own FFT length, so
    that a flight's bits never depend on the other flights of a batch."""
    h = grid.spacing
    reach = (shift.abs() + _PAD_SIGMAS * cov.diagonal().clamp_min(0).sqrt()) / h
    size = tuple(
        next_fast_len(n + math.ceil(float(r)) + 2, real=True)
        for n, r in zip(grid.shape, reach, strict=True)
    )
    kwargs = {"dtype": log_f.dtype, "device": log_f.device}
    we = 2 * math.pi * torch.fft.fftfreq(size[0], d=h, **kwargs)[:, None]
    wn = 2 * math.pi * torch.fft.rfftfreq(size[1], d=h, **kwargs)
    phase = we * shift[0] + wn * shift[1]
    quad = cov[0, 0] * we**2 + 2 * cov[0, 1] * we * wn + cov[1, 1] * wn**2
    H = torch.polar(torch.exp(-0.5 * quad), phase if adjoint else -phase)
    q, peak = _spectral_apply(log_f, H, size, conserve=not adjoint)
    inside = q[: grid.n_east, : grid.n_north]
    total, kept = q.sum(), inside.sum()
    escaped = (1 - kept / total).clamp(0, 1) if total > 0 else torch.zeros_like(total)
    return _to_log(inside, peak), escaped


def _position_transition(
    log_f: Tensor, grid: PlanarGrid, shift: Tensor, cov: Tensor, adjoint: bool
) -> tuple[Tensor, Tensor]:
    """Plane analogue of :func:`_yaw_transition` over ``(..., n_east, n_north)``, ``shift
    (..., 2)``, ``cov (..., 2, 2)``; also the mass fraction that left the grid ``(...)``."""
    batch = log_f.shape[:-2]
    rows = log_f.reshape(-1, *grid.shape)
    shifts, covs = shift.reshape(-1, 2), cov.reshape(-1, 2, 2)
    steps = [
        _plane_step(row, grid, s, c, adjoint) for row, s, c in zip(rows, shifts, covs, strict=True)
    ]
    out = torch.stack([o for o, _ in steps]).reshape(log_f.shape)
    return out, torch.stack([e for _, e in steps]).reshape(batch)


def carry_yaw(
    log_density: Tensor, grid: CircularGrid, shift: float | Tensor, sigma: float | Tensor
) -> Tensor:
    """Carry a yaw belief one odometry step: shift by ``shift`` and blur by a wrapped normal.

    ``log_density (..., n_bins)``; ``shift`` (measured yaw increment) and ``sigma`` (its standard
    deviation, e.g. :func:`~benchmark.evaluation.fusion_odometry.yaw_transition_sigma`), radians,
    float or ``(...)`` -> ``(..., n_bins)``. Mass is conserved.
    """
    check_belief(log_density, grid)
    like = {"dtype": log_density.dtype, "device": log_density.device}
    shift, sigma = torch.as_tensor(shift, **like), torch.as_tensor(sigma, **like)
    if bool((sigma < 0).any()):
        raise ValueError("sigma must be >= 0")
    batch = log_density.shape[:-1]
    return _yaw_transition(
        log_density, grid, shift.expand(batch), sigma.expand(batch), adjoint=False
    )


def carry_position(
    log_density: Tensor, grid: PlanarGrid, displacement: Tensor, covariance: Tensor
) -> tuple[Tensor, Tensor]:
    """Carry a position belief one odometry step: shift by ``displacement``, Gaussian blur.

    ``log_density (..., n_east, n_north)``, ``displacement (..., 2)`` (dE, dN) metres in the
    navigation frame, ``covariance (..., 2, 2)`` m^2 (e.g.
    :func:`~benchmark.evaluation.fusion_odometry.position_transition_covariance`) ->
    ``(log_density (..., n_east, n_north), escaped (...))``: the belief renormalised on the grid
    and the fraction of its mass that left the grid.
    """
    check_belief(log_density, grid)
    batch = log_density.shape[:-2]
    shift = displacement.to(log_density.dtype).expand(*batch, 2)
    cov = covariance.to(log_density.dtype).expand(*batch, 2, 2)
    if not bool(torch.isfinite(shift).all() & torch.isfinite(cov).all()):
        raise ValueError("displacement and covariance must be finite")
    if bool((cov.diagonal(dim1=-2, dim2=-1) < 0).any()):
        raise ValueError("covariance must have a non-negative diagonal")
    out, escaped = _position_transition(log_density, grid, shift, cov, adjoint=False)
    return normalize_log_density(out, grid), escaped
