"""Heading and position fused jointly along a flight: a Bayes filter and smoother over
(heading, east, north) for beliefs that are joint, such as a pose volume (issue 39, item 3).

The marginal filters of :mod:`benchmark.evaluation.fusion` fuse the heading and the position
separately. A pose volume says more than its two marginals: a wrong match puts its mass at a
wrong heading *and* a wrong place, and a visual-odometry step turned by a wrong heading carries
the position elsewhere. Fused jointly, a heading survives only if the positions it implies
along the flight agree with the frames' evidence (OrienterNet's sequential localisation).

**State.** ``(delta, e, n)`` on a :class:`JointGrid`: ``delta`` the heading *offset* from the
odometry's integrated heading, ``psi_k = delta + c_k``, ``c_k = sum_{i<k} dyaw_i`` (``c_0 = 0``),
and the position (E, N) metres. In the offset the yaw transition is a pure blur (the odometry's
noise): no sub-bin shift of a sharp density, hence no ringing, and the blur is a small discrete
kernel along ``delta`` (:func:`_heading_blur`).

**Transition** of increment k (sample k to k + 1), forward: each heading row ``delta_j`` shifts its
position plane by the levelled step turned by its own heading, ``d_j = Rz(delta_j + c_k) dxy_k``,
with the covariance :func:`position_transition_covariance` of that ``d_j`` (Fourier multiplier on
the plane, :func:`~benchmark.evaluation.fusion_grid._plane_steps`, one FFT length for the rows of
a flight and step: the largest any row needs, so nothing wraps); then the heading blur. The
adjoint (smoother) applies the adjoints in reverse order. Within a heading bin the step's
direction is uncertain by the bin width ``h``: a cross-track spread of ``|d| h / sqrt(12)``
(0.23 m for a 15 m step at 3 deg bins), far below a plane cell, so not modelled.

**Measurement.** ``l_k = (1 - w) b_k + w u`` on the joint grid (:func:`robust_log_likelihood`),
``b_k`` the frame's joint belief at the headings ``delta + c_k`` normalised on the grid, ``u`` the
joint uniform. Filter, smoother, log-space normalisation and the causal guarantee are those of
:mod:`benchmark.evaluation.fusion` (its ``_forward`` / ``_backward``), one flight at a time (a
flight's bits depend on nothing else).

**Estimates.** The MAPs of the two marginals (heading: ``logsumexp`` over the plane; position:
over the headings), refined by the parabola through the neighbours, as the marginal filters do.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor

from benchmark.evaluation.fusion import (
    PositionPosterior,
    YawPosterior,
    _backward,
    _forward,
    _position_estimates,
    _yaw_estimates,
    robust_log_likelihood,
)
from benchmark.evaluation.fusion_grid import (
    _PAD_SIGMAS,
    CircularGrid,
    PlanarGrid,
    _plane_fft_size,
    _plane_steps,
    _to_log,
    exp_floored_,
    logsumexp_floored,
)
from benchmark.evaluation.fusion_odometry import OdometryNoise, position_transition_covariance
from benchmark.evaluation.volume_beliefs import _linear_weights
from benchmark.geometry import angle_difference

# (sample k, absolute headings (n_heading,) rad) -> the frame's log-density (n_heading, E, N)
JointBelief = Callable[[int, Tensor], Tensor]
# Gaussian tail kept by the sampled heading kernel, in standard deviations.
_KERNEL_SIGMAS = 4.0


@dataclass(frozen=True)
class JointGrid:
    """Heading offsets on ``heading`` x positions on ``plane``: cells ``(n_heading, n_east,
    n_north)``, log-density per radian per square metre."""

    heading: CircularGrid
    plane: PlanarGrid

    @property
    def shape(self) -> tuple[int, int, int]:
        return (self.heading.n_bins, self.plane.n_east, self.plane.n_north)

    @property
    def cell(self) -> float:
        """Measure of one cell, rad m^2."""
        return self.heading.cell * self.plane.cell

    @property
    def log_uniform(self) -> float:
        return self.heading.log_uniform + self.plane.log_uniform


@dataclass(frozen=True)
class JointFlight:
    """One flight of ``K`` samples for :func:`filter_and_smooth_joint`.

    ``belief(k, psi (n_heading,)) -> (n_heading, n_east, n_north)``: sample k's log-density (up
    to a constant) at the absolute headings ``psi`` rad and the plane's cells; ``dyaw (K-1,)``
    rad the measured heading increments; ``steps (K-1, 2)`` m each increment's displacement in
    the levelled heading frame of the sample it starts from (x right, y forward, as a VIO reports
    it); ``yaw_sigma (K-1,)`` rad the heading transition's standard deviation per increment
    (e.g. :func:`~benchmark.evaluation.fusion_odometry.yaw_transition_sigma`)."""

    belief: JointBelief
    dyaw: Tensor
    steps: Tensor
    yaw_sigma: Tensor

    def __post_init__(self) -> None:
        k1 = self.dyaw.shape[0] if self.dyaw.dim() == 1 else -1
        if (
            k1 < 0
            or self.steps.shape != (k1, 2)
            or self.yaw_sigma.shape != (k1,)
            or not bool(torch.isfinite(self.dyaw).all() & torch.isfinite(self.steps).all())
            or not bool(torch.isfinite(self.yaw_sigma).all() & (self.yaw_sigma >= 0).all())
        ):
            raise ValueError(
                f"JointFlight: dyaw (K-1,), steps (K-1, 2) and yaw_sigma (K-1,) >= 0, all finite, "
                f"expected; got {tuple(self.dyaw.shape)}, {tuple(self.steps.shape)}, "
                f"{tuple(self.yaw_sigma.shape)}"
            )

    @property
    def n_samples(self) -> int:
        return int(self.dyaw.shape[0]) + 1

    def integrated_heading(self) -> Tensor:
        """``c (K,)`` rad: the odometry's heading at each sample relative to sample 0."""
        zero = self.dyaw.new_zeros(1)
        return torch.cat([zero, torch.cumsum(self.dyaw.to(torch.float64), 0)])


def heading_kernel(sigma: float, spacing: float) -> Tensor:
    """Discrete circular blur of standard deviation ``sigma`` rad on bins of ``spacing`` rad:
    symmetric, non-negative, summing to 1, ``(2 r + 1,)`` float64.

    ``s = sigma / spacing <= 1``: the three taps ``[a, 1 - 2 a, a]``, ``a = s^2 / 2`` (non-negative
    up to ``s = 1``), whose variance is exactly ``s^2`` bins^2 (a sampled Gaussian that narrow
    has too little: 2 % at ``s = 0.6``, almost all its mass in one bin). Wider: the Gaussian
    sampled at the bin centres out to 4 sigma, normalised; its variance is ``s^2`` to within
    5e-4 relative (the cut tails)."""
    if not (sigma >= 0 and spacing > 0 and math.isfinite(sigma)):
        raise ValueError(
            f"heading_kernel: sigma >= 0 and spacing > 0 expected, got {sigma}, {spacing}"
        )
    s = sigma / spacing
    if s <= 1.0:
        a = 0.5 * s * s
        return torch.tensor([a, 1 - 2 * a, a], dtype=torch.float64)
    r = math.ceil(_KERNEL_SIGMAS * s)
    x = torch.arange(-r, r + 1, dtype=torch.float64)
    k = torch.exp(-0.5 * (x / s) ** 2)
    return k / k.sum()


def _heading_blur(log_f: Tensor, kernel: Tensor) -> Tensor:
    """Circular convolution of ``(n_heading, E, N)`` log-densities along the heading axis with a
    symmetric ``kernel`` (its own adjoint), in linear space below each fibre's peak."""
    r = (kernel.shape[0] - 1) // 2
    if r == 0:
        return log_f
    peak = torch.amax(log_f, dim=0, keepdim=True).clamp_min(torch.finfo(log_f.dtype).min)
    p = exp_floored_(log_f - peak)
    out = torch.zeros_like(p)
    n = p.shape[0]
    for offset in range(-r, r + 1):  # the kernel is tiny: a few shifted, scaled adds
        w = float(kernel[offset + r])
        if not w:
            continue
        # out[i] += w p[(i - offset) mod n], as torch.roll(p, offset) would give, without the
        # rolled copy: the two slices on either side of the wrap (same products, same order)
        o = offset % n
        if o == 0:
            out += w * p
        else:
            out[o:] += w * p[: n - o]
            out[:o] += w * p[n - o :]
    return _to_log(out, peak)


def _carry_factory(
    grid: JointGrid, flight: JointFlight, noise: OdometryNoise, horizon: float
) -> Callable[[Tensor, int, bool], tuple[Tensor, Tensor]]:
    """The transition of every increment, as :func:`benchmark.evaluation.fusion._forward`'s
    ``carry``: ``(log f (1, *grid.shape), k, adjoint) -> (log T f, escaped (1,))``."""
    c = flight.integrated_heading()
    delta = grid.heading.centres(torch.float64)
    steps = flight.steps.to(torch.float64)
    kernels = [heading_kernel(float(s), grid.heading.spacing) for s in flight.yaw_sigma]

    def carry(log_f: Tensor, k: int, adjoint: bool) -> tuple[Tensor, Tensor]:
        psi = delta + c[k]
        cos, sin = torch.cos(psi), torch.sin(psi)
        x, y = steps[k, 0], steps[k, 1]
        d = torch.stack([cos * x - sin * y, sin * x + cos * y], dim=-1)  # Rz(psi) [x, y]
        cov = position_transition_covariance(d, noise, horizon)
        sd = cov.diagonal(dim1=-2, dim2=-1).clamp_min(0).sqrt()
        reach = ((d.abs() + _PAD_SIGMAS * sd) / grid.plane.spacing).amax(dim=0).tolist()
        size = _plane_fft_size(grid.plane, reach)
        rows = log_f[0]
        if adjoint:  # (Y P)^* = P^* Y^*: the blur first
            rows = _heading_blur(rows, kernels[k])
            out, _ = _plane_steps(rows, grid.plane, d, cov, size, adjoint=True)
            return out[None], log_f.new_zeros(1)
        mass = torch.softmax(torch.logsumexp(rows, dim=(1, 2)), dim=0)  # (n_heading,)
        out, escaped = _plane_steps(rows, grid.plane, d, cov, size, adjoint=False)
        out = _heading_blur(out, kernels[k])
        return out[None], (mass * escaped).sum().reshape(1)

    return carry


@dataclass(frozen=True)
class JointEstimates:
    """A flight's fused estimates: ``heading`` a :class:`YawPosterior` of the absolute heading
    ``(K, ...)`` (its ``log_density (K, n_heading)`` over the *offsets*), ``position`` a
    :class:`PositionPosterior` ``(K, ...)`` of the position marginal (``mean`` None)."""

    heading: YawPosterior
    position: PositionPosterior


def _estimates(log_post: Tensor, escaped: Tensor, grid: JointGrid, c: Tensor) -> JointEstimates:
    """Marginal MAPs of ``log_post (K, *grid.shape)``; ``c (K,)`` the integrated heading."""
    heading_marginal = logsumexp_floored(log_post, (-2, -1))[..., 0, 0] + math.log(grid.plane.cell)
    offsets = _yaw_estimates(heading_marginal, grid.heading)
    zero = torch.zeros_like(c)
    heading = YawPosterior(
        offsets.log_density,
        angle_difference(offsets.map + c, zero),
        angle_difference(offsets.mean + c, zero),
        offsets.resultant,
    )
    plane_marginal = logsumexp_floored(log_post, (-3,))[..., 0, :, :] + math.log(grid.heading.cell)
    return JointEstimates(heading, _position_estimates(plane_marginal, escaped, grid.plane, False))


def filter_and_smooth_joint(
    flight: JointFlight,
    grid: JointGrid,
    noise: OdometryNoise,
    outlier_weight: float = 0.3,
    horizon: float = 4.0,
    smooth: bool = True,
) -> tuple[JointEstimates, JointEstimates | None]:
    """Causal filter and forward-backward smoother of one flight over (heading, E, N).

    ``noise`` the odometry's (its translation figures blur the plane; the heading's enter through
    ``flight.yaw_sigma``), ``horizon`` as :func:`position_transition_covariance`. Returns
    ``(filtered, smoothed)`` estimates of the ``K`` samples; sample k of the filter reads samples
    ``<= k`` only (beliefs and odometry). Uniform prior over the grid. ``smooth=False``: the
    filter only, ``smoothed`` None (the backward pass is about half the cost)."""
    K = flight.n_samples
    c = flight.integrated_heading()
    delta = grid.heading.centres(torch.float64)
    log_lik = []
    for k in range(K):
        b = flight.belief(k, delta + c[k]).to(torch.float64)
        if tuple(b.shape) != grid.shape:
            raise ValueError(
                f"JointFlight.belief({k}) returned {tuple(b.shape)}, expected {grid.shape}"
            )
        log_lik.append(robust_log_likelihood(b, grid, outlier_weight))  # type: ignore[arg-type]
    lik = torch.stack(log_lik)[None]  # (1, K, *cells)
    carry = _carry_factory(grid, flight, noise, horizon)
    prior = torch.full(grid.shape, grid.log_uniform, dtype=torch.float64)[None]
    filtered, escaped = _forward(lik, prior, grid, carry)  # type: ignore[arg-type]
    if not smooth:
        return _estimates(filtered[0], escaped[0], grid, c), None
    smoothed = _backward(filtered, lik, grid, carry)  # type: ignore[arg-type]
    return (
        _estimates(filtered[0], escaped[0], grid, c),
        _estimates(smoothed[0], escaped[0], grid, c),
    )


def volume_joint_belief(
    log_volume: Tensor, yaw: Tensor, north: Tensor, east: Tensor, cell_m: float, plane: PlanarGrid
) -> JointBelief:
    """A pose volume as a :data:`JointBelief`: ``log_volume (K, n_yaw, P, Q)`` each sample's
    log-mass per (yaw bin, north cell, east cell), axes ``yaw (n_yaw,)`` rad (equally spaced,
    any start), ``north (P,)``, ``east (Q,)`` m (cell centres), ``cell_m`` the cell side.

    The mass becomes a density (per rad m^2) at the cells' centres, interpolated linearly along
    the yaw (periodic) and bilinearly over the plane, the edge cells' value out to their outer
    edges and zero beyond the searched square (as the marginal beliefs of
    :mod:`benchmark.evaluation.volume_beliefs`); ``log tiny`` where zero."""
    n_yaw = len(yaw)
    width = 2 * math.pi / n_yaw
    start = float(yaw[0])
    order = torch.argsort(torch.remainder(yaw.double() - start, 2 * math.pi))
    east_c, north_c = plane.centres(torch.float64)
    we, ie = _linear_weights(east.double(), east_c)  # (n_east, 2)
    wn, in_ = _linear_weights(north.double(), north_c)  # (n_north, 2)
    # dense interpolation matrices: (n_east, Q), (n_north, P)
    A_e = torch.zeros(len(east_c), len(east), dtype=torch.float64)
    A_n = torch.zeros(len(north_c), len(north), dtype=torch.float64)
    for a in range(2):
        A_e[torch.arange(len(east_c)), ie[:, a]] += we[:, a]
        A_n[torch.arange(len(north_c)), in_[:, a]] += wn[:, a]
    tiny = torch.finfo(torch.float64).tiny

    def belief(k: int, psi: Tensor) -> Tensor:
        density = log_volume[k].double()[order].exp() / (width * cell_m**2)  # (n_yaw, P, Q)
        t = torch.remainder(psi - start, 2 * math.pi) / width
        low = torch.floor(t).long() % n_yaw
        frac = (t - torch.floor(t))[:, None, None]
        at_psi = density[low] * (1 - frac) + density[(low + 1) % n_yaw] * frac  # (n, P, Q)
        out = torch.einsum("eq,jpq,np->jen", A_e, at_psi, A_n)  # (n, n_east, n_north)
        return torch.log(out.clamp_min(tiny))

    return belief


__all__ = [
    "JointBelief",
    "JointEstimates",
    "JointFlight",
    "JointGrid",
    "filter_and_smooth_joint",
    "heading_kernel",
    "volume_joint_belief",
]
