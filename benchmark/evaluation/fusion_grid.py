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
# exp of anything below is < 1e-304: zero beside any peak (the rounding floor is 64 eps, 1.4e-14
# of it in float64). Clamped first because the CPU's vectorised exp takes a slow path, measured
# 50x slower on the fusion's (201, 101) float64 grids, when an input's result underflows, and
# floored beliefs (log(tiny) below their peak) are full of such inputs.
_EXP_FLOOR = -700.0


def exp_floored(x: Tensor) -> Tensor:
    """``exp(x)`` with every ``x < -700`` set to exactly 0 (same shape): the fast path of the
    CPU's exp for beliefs whose floor lies below the underflow threshold."""
    return exp_floored_(x.clone())


def exp_floored_(x: Tensor) -> Tensor:
    """:func:`exp_floored` in place on ``x`` (a temporary of the caller's), returned: the same
    elementwise operations on one buffer, so the same bits without two more tensors to fill."""
    below = x < _EXP_FLOOR
    return x.clamp_min_(_EXP_FLOOR).exp_().masked_fill_(below, 0.0)


def logaddexp_constant(x: Tensor, c: float) -> Tensor:
    """``log(exp(x) + exp(c))`` of ``x (...)`` and a finite constant ``c``, same shape. ``x`` is
    clamped at ``c - 700`` first: below it ``exp(x - c) < 1e-304``, so the result moves by at
    most ``log1p(e^-700) ~ 1e-304`` (absolute), and the clamp keeps ``logaddexp``'s exp on its
    fast path (:func:`exp_floored`)."""
    if not math.isfinite(c):
        raise ValueError(f"logaddexp_constant: c must be finite, got {c!r}")
    constant = torch.tensor(c, dtype=x.dtype, device=x.device)
    return torch.logaddexp(x.clamp_min(c + _EXP_FLOOR), constant)


def logsumexp_floored(x: Tensor, dim: tuple[int, ...]) -> Tensor:
    """``log(sum(exp(x)))`` over ``dim``, kept; the terms below ``-700`` of the maximum dropped
    (relative ``< 1e-304``, :func:`exp_floored`). ``-inf`` where every term is ``-inf``."""
    peak = torch.amax(x, dim=dim, keepdim=True).clamp_min(torch.finfo(x.dtype).min)
    return torch.log(exp_floored_(x - peak).sum(dim=dim, keepdim=True)) + peak


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
    return log_density - (logsumexp_floored(log_density, dims) + math.log(grid.cell))


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
    p = exp_floored_(log_f - peak)
    q = torch.fft.irfftn(torch.fft.rfftn(p, s=size, dim=dims) * H, s=size, dim=dims)
    floor = _ROUNDING_EPS * torch.finfo(q.dtype).eps * torch.amax(q, dim=dims, keepdim=True)
    q.masked_fill_(~(q > floor), 0.0)  # q is this function's own; NaN -> 0 as where() did
    if conserve:  # put back the mass of the clipped negative lobes
        q = q * (p.sum(dim=dims, keepdim=True) / q.sum(dim=dims, keepdim=True))
    return q, peak


def _to_log(q: Tensor, peak: Tensor) -> Tensor:
    """``log(max(q, tiny)) + peak``, ``q``'s shape (``peak`` broadcasts into it; ``q`` is left
    as it was)."""
    return q.clamp_min(torch.finfo(q.dtype).tiny).log_().add_(peak)


def _yaw_transition(
    log_f: Tensor, grid: CircularGrid, shift: Tensor, sigma: Tensor, adjoint: bool
) -> Tensor:
    """Forward (density, mass-conserving) or adjoint (function, ``x -> sum_x' T(x'|x) f(x')``)."""
    m = torch.arange(grid.n_bins // 2 + 1, dtype=log_f.dtype, device=log_f.device)
    phase = m * shift[..., None]
    H = torch.polar(torch.exp(-0.5 * (m * sigma[..., None]) ** 2), phase if adjoint else -phase)
    q, peak = _spectral_apply(log_f, H, grid.shape, conserve=not adjoint)
    return _to_log(q, peak)


def _plane_fft_size(grid: PlanarGrid, reach: list[float]) -> tuple[int, int]:
    """FFT length per axis for a step reaching ``reach`` cells (E, N): the grid plus the pad
    that keeps the blurred, shifted mass from wrapping back into it."""
    return tuple(  # type: ignore[return-value]
        next_fast_len(n + math.ceil(r) + 2, real=True)
        for n, r in zip(grid.shape, reach, strict=True)
    )


def _plane_steps(
    log_f: Tensor,
    grid: PlanarGrid,
    shift: Tensor,
    cov: Tensor,
    size: tuple[int, int],
    adjoint: bool,
) -> tuple[Tensor, Tensor]:
    """Rows ``(R, n_east, n_north)``, ``shift (R, 2)``, ``cov (R, 2, 2)`` at one FFT ``size``:
    ``(log T f (R, n_east, n_north), escaped (R,))``."""
    h = grid.spacing
    kwargs = {"dtype": log_f.dtype, "device": log_f.device}
    we = 2 * math.pi * torch.fft.fftfreq(size[0], d=h, **kwargs)[:, None]
    wn = 2 * math.pi * torch.fft.rfftfreq(size[1], d=h, **kwargs)
    s, c = shift[:, :, None, None], cov[:, :, :, None, None]
    phase = we * s[:, 0] + wn * s[:, 1]
    quad = c[:, 0, 0] * we**2 + 2 * c[:, 0, 1] * we * wn + c[:, 1, 1] * wn**2
    H = torch.polar(torch.exp(-0.5 * quad), phase if adjoint else -phase)
    q, peak = _spectral_apply(log_f, H, size, conserve=not adjoint)
    inside = q[..., : grid.n_east, : grid.n_north]
    total, kept = q.sum(dim=(-2, -1)), inside.sum(dim=(-2, -1))
    escaped = torch.where(
        total > 0, (1 - kept / total.clamp_min(torch.finfo(q.dtype).tiny)).clamp(0, 1), 0.0
    )
    return _to_log(inside, peak), escaped


def _position_transition(
    log_f: Tensor, grid: PlanarGrid, shift: Tensor, cov: Tensor, adjoint: bool
) -> tuple[Tensor, Tensor]:
    """Plane analogue of :func:`_yaw_transition` over ``(..., n_east, n_north)``, ``shift
    (..., 2)``, ``cov (..., 2, 2)``; also the mass fraction that left the grid ``(...)``.

    Each row gets the FFT length its own step needs (:func:`_plane_fft_size`) and an FFT of
    its own: batched transforms round differently from single ones (measured), so a row's bits
    would depend on which other rows share its length."""
    batch = log_f.shape[:-2]
    rows = log_f.reshape(-1, *grid.shape)
    shifts, covs = shift.reshape(-1, 2), cov.reshape(-1, 2, 2)
    sd = covs.diagonal(dim1=-2, dim2=-1).clamp_min(0).sqrt()
    reach = ((shifts.abs() + _PAD_SIGMAS * sd) / grid.spacing).tolist()
    out, escaped = torch.empty_like(rows), rows.new_empty(rows.shape[0])
    for i, r in enumerate(reach):
        one = slice(i, i + 1)
        out[one], escaped[one] = _plane_steps(
            rows[one], grid, shifts[one], covs[one], _plane_fft_size(grid, r), adjoint
        )
    return out.reshape(log_f.shape), escaped.reshape(batch)


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
