"""A belief per frame, for every head (issue 39, item 2): what the flight fusion reads.

The fusion (:mod:`benchmark.evaluation.fusion`) takes per-frame log-densities on grids: yaw on a
:class:`~benchmark.evaluation.fusion_grid.CircularGrid` (log-density per radian), position on a
:class:`~benchmark.evaluation.fusion_grid.PlanarGrid` (log-density per m^2), each up to a constant
per frame. This module makes them from any head, through the head contract only
(``benchmark.models.heads``); nothing here knows which head it is running.

**Yaw, a head with a density** (:func:`gives_density`: ``is_probabilistic`` or ``gives_log_prob``).
The fusion runs on yaw, the heading the satellite image must supply; pitch and roll keep the head's
own per-frame estimate. With ``R_hat`` the decoded ``R_uav^sat`` and ``(yaw_hat, pitch_hat,
roll_hat) = rotmat_to_euler(R_hat SAT_R_N)`` (``R_uav^n = R_uav^sat R_sat^n``, Eq. 2 inverted),
the belief at a grid yaw ``psi_j`` is the head's ``log_prob`` at

    R_uav^sat(psi_j) = Rz(psi_j) Rx(pitch_hat) Ry(roll_hat) SAT_R_N^T     (:func:`yaw_slice`)

a *slice* of the head's density on SO(3) through its own pitch and roll. In Euler coordinates the
normalised Haar measure is ``cos(pitch) dyaw dpitch droll / (8 pi^2)``, whose factor does not
depend on yaw, so the slice is exactly the head's *conditional* density of yaw given pitch =
pitch_hat and roll = roll_hat, per radian, up to a constant per frame. Why the conditional and not
the marginal ``int p dpitch droll``: the marginal needs a 3-D Haar grid per frame (720 x ~100 x
~100 rotations for half-degree yaw against a head whose pitch and roll are sharp); the two are
equal up to a constant when the density factorises into yaw and (pitch, roll), and close when
pitch and roll are sharp around their estimate. Limits: a density whose yaw mode moves with pitch
or roll (correlated errors) is read at the estimate's pitch and roll only; a head whose decoded
estimate is not on its density's ridge (a lattice head's normalised expectation between two
modes) is sliced off the ridge; a piecewise-constant density (nearest lattice point, Euler bins)
gives a piecewise-constant belief, as fine as the head's own cells.

Cost: one ``log_prob`` row per (frame, yaw bin). A head whose ``log_prob`` normalises over a grid
on every call recomputes that normaliser for each of a frame's bins; measured for 600 frames x
720 bins on one CPU thread (chunk 512, untrained heads, another process on the second core):
Pd/Re-Net 422 s (2^15 Haar rotations per row), IPDF 72 s (2^15 logits per row), Bingham 70 s,
Pd-Net-Q / Pd-Net-Q-sym 7 s, matrix Fisher 7 s, Pd-Net-Rv 5 s, Pd-Net-E 0.3 s.

**Yaw, a regression head** (no density). A calibrated density around the estimate, the same for
every regression head (:class:`AttitudeCalibration`): an isotropic matrix Fisher distribution
mixed with the uniform one, w.r.t. the normalised Haar measure,

    p(R) = (1 - w) exp(kappa tr(R_hat^T R)) / c(kappa) + w,

``kappa`` and ``w`` fitted by maximum likelihood on the validation split's geodesic errors. On
the slice, ``tr(R_hat^T R(psi)) = tr(Rz(psi - yaw_hat)) = 1 + 2 cos(psi - yaw_hat)`` exactly (the
pitch and roll factors cancel), so the geodesic angle to the estimate is ``|psi - yaw_hat|``
wrapped and the matrix Fisher part is a von Mises density in yaw with concentration ``2 kappa``.

**Position.** Each translation head's estimate ``(E, N)`` with a calibrated isotropic 2-D
Gaussian mixed with a uniform density over the satellite footprint (:class:`PositionCalibration`).

**Calibration uses the validation split only**: every fit refuses a split whose name does not end
in ``/val`` (:func:`calibrate_from_predictions`, :meth:`AttitudeCalibration.fit`,
:meth:`PositionCalibration.fit`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
import torch
from torch import Tensor

from benchmark.evaluation.fusion_grid import CircularGrid, PlanarGrid, logaddexp_constant
from benchmark.geometry import SAT_R_N, angle_difference, euler_to_rotmat, rotmat_to_euler

if TYPE_CHECKING:  # annotations only: importing the models package costs ~0.2 s
    from benchmark.models.heads import AttitudeHead, Raw

# Rotations per log_prob call: bounds the memory of a head whose log_prob materialises a per-row
# grid (IPDF: 2^15 float32 logits per rotation, 64 MB at 512 rotations). Larger chunks were
# measured no faster (IPDF, Pd/Re-Net; one thread).
DEFAULT_CHUNK = 512
# Rotations per ``log_prob_many`` call (frames x bins): the lattice heads look them up in a k-d
# tree; IPDF's MLP holds (rows, hidden) activations. 8192 rows: 11 frames of 720 bins, a few MB.
MANY_ROWS = 8192
VALIDATION_SUFFIX = "/val"

# Fit bounds. kappa: at 1e-2 the density varies by exp(4 kappa) = 1.04 over SO(3) (uniform, for
# the fusion); at 1e6 the angular std is 1 / sqrt(2 kappa) = 0.04 deg per axis, finer than any
# head here. The outlier weight stays inside (0, 1) so that its logit is finite.
_KAPPA_BOUNDS = (1e-2, 1e6)
_WEIGHT_BOUNDS = (1e-6, 1 - 1e-6)
_SIGMA_MIN_M = 1e-3


def gives_density(head: AttitudeHead | type[AttitudeHead]) -> bool:
    """True when ``head`` (instance or class) gives ``log_prob``: ``is_probabilistic`` (the grid
    contract) or ``gives_log_prob`` (a density without a grid). The one place this is decided."""
    return bool(getattr(head, "is_probabilistic", False) or getattr(head, "gives_log_prob", False))


def check_validation_split(split: str) -> str:
    """``split`` if its name ends in ``/val``; else ``ValueError`` naming it. Calibrations are
    fitted on the validation split only, so the test splits they are used on stay unseen."""
    if not isinstance(split, str) or not split.endswith(VALIDATION_SUFFIX):
        raise ValueError(
            f"calibration uses the validation split only (a name ending in "
            f"{VALIDATION_SUFFIX!r}); refusing split {split!r}"
        )
    return split


# -- Raw batches ---------------------------------------------------------------------------------
def raw_batch_size(raw: Raw) -> int:
    """Batch size of a raw output: a Tensor ``(B, ...)`` or a dict of them, all batch-first."""
    sizes = {int(t.shape[0]) for t in _raw_tensors(raw)}
    if len(sizes) != 1:
        raise ValueError(
            f"raw entries must share their first (batch) dimension, got {sorted(sizes)}"
        )
    return sizes.pop()


def take_raw(raw: Raw, index: Tensor) -> Raw:
    """Rows ``index (M,)`` int64 of a raw batch: ``raw[index]`` for a Tensor, the same for every
    entry of a dict (nested dicts too). Indices may repeat: this is how a frame's raw output is
    repeated for each of its rotations. ``(B, ...)`` -> ``(M, ...)``."""
    if isinstance(raw, Tensor):
        return raw.index_select(0, index.to(raw.device))
    if isinstance(raw, Mapping):
        return {key: take_raw(value, index) for key, value in raw.items()}
    raise TypeError(f"raw must be a Tensor or a dict of Tensors, got {type(raw).__name__}")


def _raw_tensors(raw: Raw) -> list[Tensor]:
    if isinstance(raw, Tensor):
        return [raw]
    if isinstance(raw, Mapping):
        return [t for value in raw.values() for t in _raw_tensors(value)]
    raise TypeError(f"raw must be a Tensor or a dict of Tensors, got {type(raw).__name__}")


def _raw_float_dtype(raw: Raw) -> torch.dtype:
    """The dtype the head computes in: that of the raw's first floating tensor (float64 if none)."""
    return next((t.dtype for t in _raw_tensors(raw) if t.is_floating_point()), torch.float64)


# -- the yaw slice -------------------------------------------------------------------------------
def yaw_slice(R_hat: Tensor, psi: Tensor) -> Tensor:
    """The rotations of the slice through ``R_hat``'s pitch and roll, one per yaw.

    Args:
        R_hat: ``(B, 3, 3)`` estimated ``R_uav^sat``.
        psi: ``(n,)`` UAV yaws, radians (e.g. ``CircularGrid.centres()``).
    Returns:
        ``(B, n, 3, 3)`` float64: ``Rz(psi_j) Rx(pitch_hat) Ry(roll_hat) SAT_R_N^T`` with
        ``(yaw_hat, pitch_hat, roll_hat) = rotmat_to_euler(R_hat SAT_R_N)``. At ``psi_j = yaw_hat``
        it is ``R_hat`` (to rounding). At gimbal lock (pitch_hat = +-90 deg) ``rotmat_to_euler``
        puts the in-plane angle into yaw with roll 0, and the slice still passes through R_hat.
    """
    _, pitch, roll = _uav_euler(R_hat)
    psi64 = psi.detach().to(dtype=torch.float64, device=R_hat.device)
    R_n = euler_to_rotmat(psi64[None, :], pitch[:, None], roll[:, None])  # (B, n, 3, 3)
    # SAT_R_N is a signed permutation: this product only moves and negates entries (exact).
    return R_n @ SAT_R_N.to(device=R_hat.device).T


def _uav_euler(R_hat: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """``(yaw, pitch, roll)`` ``(B,)`` float64 of the UAV attitude ``R_uav^n = R_uav^sat R_sat^n``
    of estimates ``R_hat (B, 3, 3)`` (``R_uav^sat``)."""
    R64 = R_hat.detach().to(torch.float64)
    return rotmat_to_euler(R64 @ SAT_R_N.to(device=R64.device))


# -- calibrated densities ------------------------------------------------------------------------
def isotropic_fisher_log_normaliser(kappa: float) -> float:
    """``log c(kappa)``, the normaliser of ``exp(kappa tr R)`` w.r.t. the normalised Haar measure.

    ``c(kappa) = E_Haar[exp(kappa tr R)] = int_0^pi exp(kappa (1 + 2 cos t)) (1 - cos t) / pi dt``
    (the Haar density of the rotation angle t is ``(1 - cos t) / pi`` on [0, pi], and
    ``tr R = 1 + 2 cos t``). With ``int_0^pi exp(x cos t) dt = pi I0(x)`` and
    ``int_0^pi cos t exp(x cos t) dt = pi I1(x)``, the closed form is

        c(kappa) = e^kappa (I0(2 kappa) - I1(2 kappa)),    c(0) = 1,

    (the matrix Fisher normaliser at ``F = kappa I``). Evaluated with the exponentially scaled
    Bessel functions, ``log c = 3 kappa + log(i0e(2 kappa) - i1e(2 kappa))``: nothing overflows.
    The difference cancels for large arguments (``i0e(x) - i1e(x) ~ i0e(x) / (2 x)``), costing
    ``~2 x eps`` of relative accuracy: an absolute error of ~1e-11 in ``log c`` at kappa = 1e4,
    ~1e-9 at the fit's bound 1e6.
    """
    from scipy.special import i0e, i1e

    kappa = float(kappa)
    if not (kappa >= 0 and math.isfinite(kappa)):
        raise ValueError(f"kappa must be finite and >= 0, got {kappa!r}")
    return 3 * kappa + math.log(float(i0e(2 * kappa)) - float(i1e(2 * kappa)))


def _as_float64(x: np.ndarray | Tensor | float) -> Tensor:
    if isinstance(x, Tensor):
        return x.detach().to(torch.float64)
    return torch.from_numpy(np.array(x, dtype=np.float64))  # a copy: pandas' arrays are read-only


def _attitude_log_density(angle: Tensor, kappa: float, weight: float) -> Tensor:
    """``log((1 - w) exp(kappa (1 + 2 cos a)) / c(kappa) + w)`` of angles ``a`` (any shape)."""
    # kappa (1 + 2 cos a) - log c = -4 kappa sin^2(a / 2) - log(i0e - i1e): no cancellation of
    # two large terms, and 1 - cos a = 2 sin^2(a / 2) keeps its digits near a = 0.
    log_g = isotropic_fisher_log_normaliser(kappa) - 3 * kappa
    fisher = -4 * kappa * torch.sin(angle / 2) ** 2 - log_g
    return logaddexp_constant(fisher + math.log1p(-weight), math.log(weight))


def _position_log_density(d_en: Tensor, sigma: float, weight: float, area: float) -> Tensor:
    """``log((1 - w) N(d; 0, sigma^2 I_2) + w / area)`` of offsets ``d (..., 2)`` metres."""
    r2 = (d_en**2).sum(-1)
    gauss = -r2 / (2 * sigma**2) - math.log(2 * math.pi * sigma**2)
    return logaddexp_constant(gauss + math.log1p(-weight), math.log(weight) - math.log(area))


def _fit_two(
    neg_log_lik: Callable[[float, float], float],
    starts: list[tuple[float, float]],
    log_scale_bounds: tuple[float, float],
) -> tuple[float, float]:
    """Minimise ``neg_log_lik(log scale, logit w)`` by L-BFGS-B from every start (bounded);
    the best end point as ``(scale, w)``. Several starts: the mixture's likelihood can have a
    local optimum that explains the inliers as outliers."""
    from scipy.optimize import minimize

    logit = lambda w: math.log(w) - math.log1p(-w)  # noqa: E731
    bounds = [log_scale_bounds, (logit(_WEIGHT_BOUNDS[0]), logit(_WEIGHT_BOUNDS[1]))]
    best = None
    for scale, w in starts:
        x0 = [
            min(max(math.log(scale), bounds[0][0]), bounds[0][1]),
            min(max(logit(w), bounds[1][0]), bounds[1][1]),
        ]
        result = minimize(lambda x: neg_log_lik(*x), x0, method="L-BFGS-B", bounds=bounds)
        if best is None or result.fun < best.fun:
            best = result
    assert best is not None
    log_scale, logit_w = (float(v) for v in best.x)
    return math.exp(log_scale), 1 / (1 + math.exp(-logit_w))


def _finite_array(values: np.ndarray | Tensor, name: str, width: int | None) -> Tensor:
    """``values`` as float64, ``(N >= 2,)`` (``width`` None) or ``(N >= 2, width)``, finite."""
    x = _as_float64(values)
    shape = "(N >= 2,)" if width is None else f"(N >= 2, {width})"
    wanted = 1 if width is None else 2
    if x.dim() != wanted or (width is not None and x.shape[1] != width) or x.shape[0] < 2:
        raise ValueError(f"{name} must have shape {shape}, got {tuple(x.shape)}")
    if not bool(torch.isfinite(x).all()):
        raise ValueError(f"{name} contains non-finite values")
    return x


def _check_parameters(owner: object, name: str, scale: float, weight: float) -> None:
    """A calibration's scale finite and > 0, its outlier weight in (0, 1) (errors name both)."""
    cls = type(owner).__name__
    if not (scale > 0 and math.isfinite(scale)):
        raise ValueError(f"{cls}: {name} must be finite and > 0, got {scale!r}")
    if not 0 < weight < 1:
        raise ValueError(f"{cls}: outlier_weight must be in (0, 1), got {weight!r}")


@dataclass(frozen=True)
class AttitudeCalibration:
    """Calibrated density of a regression head's attitude (module docstring): concentration
    ``kappa`` (> 0) of the isotropic matrix Fisher part, ``outlier_weight`` ``w`` in (0, 1) of the
    uniform part, and the ``split`` it was fitted on (provenance)."""

    kappa: float
    outlier_weight: float
    split: str

    def __post_init__(self) -> None:
        _check_parameters(self, "kappa", self.kappa, self.outlier_weight)

    @classmethod
    def fit(cls, errors_rad: np.ndarray | Tensor, split: str) -> AttitudeCalibration:
        """Maximum likelihood of the mixture on geodesic errors ``errors_rad (N,)`` (radians, in
        [0, pi]) of the validation frames of ``split`` (must end in ``/val``).

        Only the angles are needed: the density depends on R through ``tr(R_hat^T R) = 1 + 2 cos
        delta``, and the likelihood of R w.r.t. Haar is that of delta up to the Haar Jacobian
        ``(1 - cos delta) / pi``, which does not depend on the parameters. Optimised over
        ``(log kappa, logit w)`` by L-BFGS-B, kappa in [1e-2, 1e6], from several starts (the
        small-angle moment ``E delta^2 = 3 / (2 kappa)`` of the smaller half of the errors, and
        fixed values).
        """
        check_validation_split(split)
        delta = _finite_array(errors_rad, "errors_rad", None)
        if bool(((delta < 0) | (delta > math.pi + 1e-9)).any()):
            raise ValueError("errors_rad must be geodesic angles in [0, pi] radians")

        def neg_log_lik(log_kappa: float, logit_w: float) -> float:
            w = 1 / (1 + math.exp(-logit_w))
            return -float(_attitude_log_density(delta, math.exp(log_kappa), w).sum())

        small = delta[delta <= delta.median()]
        moment = 1.5 / max(float((small**2).mean()), 1e-12)
        starts = [(k, w) for k in (moment, 1.0, 100.0) for w in (0.05, 0.3, 0.7)]
        bounds = (math.log(_KAPPA_BOUNDS[0]), math.log(_KAPPA_BOUNDS[1]))
        kappa, weight = _fit_two(neg_log_lik, starts, bounds)
        return cls(kappa, weight, split)

    def log_density(self, angle_rad: np.ndarray | Tensor | float) -> Tensor:
        """Log density (w.r.t. the normalised Haar measure on SO(3)) of a rotation at geodesic
        angle ``angle_rad (...)`` from the estimate -> ``(...)`` float64 tensor. 0 everywhere
        would be the uniform distribution."""
        return _attitude_log_density(_as_float64(angle_rad), self.kappa, self.outlier_weight)


@dataclass(frozen=True)
class PositionCalibration:
    """Calibrated density of a translation head's horizontal position: an isotropic 2-D Gaussian
    of standard deviation ``sigma_m`` (metres, per axis) around the estimate, mixed with weight
    ``outlier_weight`` with the uniform density ``1 / area_m2`` over the satellite footprint,

        p(x) = (1 - w) N(x; x_hat, sigma^2 I_2) + w / area,    per m^2, x = (E, N),

    fitted on ``split``; ``area_m2`` is the footprint area the fit used (the uniform part's
    support), recorded so that the density is the fitted one unless another area is passed."""

    sigma_m: float
    outlier_weight: float
    split: str
    area_m2: float = math.nan

    def __post_init__(self) -> None:
        _check_parameters(self, "sigma_m", self.sigma_m, self.outlier_weight)

    @classmethod
    def fit(cls, d_en: np.ndarray | Tensor, area_m2: float, split: str) -> PositionCalibration:
        """Maximum likelihood on the validation frames' horizontal errors ``d_en (N, 2)`` (dE, dN
        metres; signs do not matter, the Gaussian is isotropic and centred) with the uniform part
        over ``area_m2`` (the satellite footprint, m^2). Optimised over ``(log sigma, logit w)`` by
        L-BFGS-B, sigma in [1 mm, sqrt(area)], from several starts (the Rayleigh median
        ``sigma sqrt(2 ln 2)`` of the errors, and fixed fractions of the footprint)."""
        check_validation_split(split)
        area = _check_area(area_m2)
        d = _finite_array(d_en, "d_en", 2)

        def neg_log_lik(log_sigma: float, logit_w: float) -> float:
            w = 1 / (1 + math.exp(-logit_w))
            return -float(_position_log_density(d, math.exp(log_sigma), w, area).sum())

        r = torch.linalg.vector_norm(d, dim=-1)
        rayleigh = max(float(r.median()) / math.sqrt(2 * math.log(2)), _SIGMA_MIN_M)
        side = math.sqrt(area)
        starts = [(s, w) for s in (rayleigh, side / 100, side / 10) for w in (0.05, 0.3, 0.7)]
        sigma, weight = _fit_two(neg_log_lik, starts, (math.log(_SIGMA_MIN_M), math.log(side)))
        return cls(sigma, weight, split, area)

    def log_density(self, d_en: np.ndarray | Tensor, area_m2: float | None = None) -> Tensor:
        """Log density per m^2 of offsets ``d_en (..., 2)`` (position minus estimate, E and N
        metres) -> ``(...)`` float64 tensor; the uniform part over ``area_m2`` (default: the
        area of the fit)."""
        area = _check_area(self.area_m2 if area_m2 is None else area_m2)
        return _position_log_density(_as_float64(d_en), self.sigma_m, self.outlier_weight, area)


def _check_area(area_m2: float) -> float:
    area = float(area_m2)
    if not (area > 0 and math.isfinite(area)):
        raise ValueError(
            f"area_m2 must be finite and > 0 (the satellite footprint), got {area_m2!r}"
        )
    return area


def calibrate_from_predictions(
    frame: pd.DataFrame, split: str, area_m2: float
) -> tuple[AttitudeCalibration, PositionCalibration]:
    """Fit both calibrations on a validation split's per-frame predictions table
    (:func:`~benchmark.evaluation.metrics.predictions_frame`: ``dphi_deg`` the geodesic error in
    degrees, ``dE_m`` and ``dN_m`` the horizontal errors in metres). ``split`` must name a
    validation split (``.../val``); any other is refused with a ValueError naming it. ``area_m2``
    is the satellite footprint's area (m^2), the support of the position outlier component.

    Both are fitted for every head: the attitude one is used only by heads without a density
    (:func:`yaw_beliefs`), the position one by every translation head."""
    check_validation_split(split)
    missing = [c for c in ("dphi_deg", "dE_m", "dN_m") if c not in frame.columns]
    if missing:
        raise ValueError(f"the predictions table of {split!r} lacks the columns {missing}")
    errors = np.radians(frame["dphi_deg"].to_numpy(np.float64))
    d_en = frame[["dE_m", "dN_m"]].to_numpy(np.float64)
    return AttitudeCalibration.fit(errors, split), PositionCalibration.fit(d_en, area_m2, split)


# -- beliefs -------------------------------------------------------------------------------------
def calibrated_yaw_beliefs(
    yaw_hat: Tensor, grid: CircularGrid, calibration: AttitudeCalibration
) -> Tensor:
    """The yaw belief of an estimate without a density of its own (a regression head, a
    non-learned reference, the constant predictor): ``yaw_hat (B,)`` radians, the UAV yaw in the
    navigation frame -> ``(B, n_bins)`` float64, the calibrated density at the geodesic angle
    ``|psi_j - yaw_hat|`` (wrapped) between the estimate and each rotation of its yaw slice."""
    psi = grid.centres(torch.float64, yaw_hat.device)
    angle = angle_difference(psi[None, :], yaw_hat.to(torch.float64)[:, None]).abs()
    return calibration.log_density(angle)


@torch.no_grad()
def yaw_beliefs(
    head: AttitudeHead,
    raw: Raw,
    R_hat: Tensor,
    grid: CircularGrid,
    calibration: AttitudeCalibration | None = None,
    chunk: int = DEFAULT_CHUNK,
) -> Tensor:
    """Per-frame yaw beliefs of any attitude head, through the contract (module docstring).

    Args:
        head: the attitude head that produced ``raw``.
        raw: its raw output for ``B`` frames, a Tensor ``(B, ...)`` or a dict of them.
        R_hat: ``(B, 3, 3)`` the decoded ``R_uav^sat`` (``head.decode(raw)``).
        grid: the yaw grid (UAV yaw in the navigation frame, radians).
        calibration: required for a head without a density (:func:`gives_density` False);
            ignored otherwise.
        chunk: at most this many rotations per ``log_prob`` call (bounds memory), in near-equal
            chunks; the result does not depend on it when the head's ``log_prob`` gives a row the
            same bits in any batch of three rows or more (every registered head, measured).
    Returns:
        ``(B, n_bins)`` float64 log-density per radian of the UAV yaw, up to a constant per frame
        (the fusion normalises). A head with a density: its ``log_prob`` along :func:`yaw_slice`
        (the rotations built in float64, handed to the head in its raw's dtype). Otherwise: the
        calibrated mixture at the geodesic angle between ``R_hat`` and each slice rotation,
        ``|psi_j - yaw_hat|`` wrapped.
        Evaluated without autograd.
    """
    if R_hat.dim() != 3 or tuple(R_hat.shape[1:]) != (3, 3):
        raise ValueError(f"R_hat must have shape (B, 3, 3), got {tuple(R_hat.shape)}")
    if isinstance(chunk, bool) or not isinstance(chunk, int) or chunk < 1:
        raise ValueError(f"chunk must be a positive int, got {chunk!r}")
    batch, n = R_hat.shape[0], grid.n_bins
    if not gives_density(head):
        if calibration is None:
            raise ValueError(
                f"{type(head).__name__} ({getattr(head, 'name', '') or 'unregistered'}) gives no "
                f"log_prob: its yaw belief needs an AttitudeCalibration (fitted on the "
                f"validation split, calibrate_from_predictions)"
            )
        # The geodesic angle between R_hat and R(psi) is |psi - yaw_hat| wrapped: tr(R_hat^T
        # R(psi)) = tr(Rz(psi - yaw_hat)) (module docstring). Taken from the identity rather than
        # from the matrices: a float32 estimate is orthonormal to ~1e-7 only, which would move
        # the angle by as much and the log density by ~2 kappa 1e-7 (3e-5 at kappa 150).
        return calibrated_yaw_beliefs(_uav_euler(R_hat)[0], grid, calibration)
    if raw_batch_size(raw) != batch:
        raise ValueError(f"raw has batch size {raw_batch_size(raw)}, R_hat {batch}")
    rotations = yaw_slice(R_hat, grid.centres(torch.float64, R_hat.device))  # (B, n, 3, 3)
    many = getattr(head, "log_prob_many", None)
    if many is not None:  # the head shares its per-frame normaliser over the n rotations
        slices = rotations.to(_raw_float_dtype(raw))
        frames_per_call = max(1, MANY_ROWS // n)
        out = [
            many(take_raw(raw, part), slices[part])
            for part in torch.arange(batch, device=R_hat.device).split(frames_per_call)
        ]
        return torch.cat(out).to(torch.float64)
    flat = rotations.reshape(batch * n, 3, 3).to(_raw_float_dtype(raw))
    frames = torch.arange(batch, device=R_hat.device).repeat_interleave(n)  # row k -> frame k // n
    # Near-equal chunks (sizes differ by at most one), never a remainder of one or two rows: a
    # head's MLP on a 1-2 row batch may take another kernel and round differently (measured on
    # IPDF's score: 1 float32 ulp), which would make the bits depend on ``chunk``.
    rows = torch.arange(batch * n, device=R_hat.device)
    parts = [
        head.log_prob(take_raw(raw, frames[part]), flat[part])
        for part in rows.tensor_split(-(-(batch * n) // chunk))
    ]
    return torch.cat(parts).to(torch.float64).reshape(batch, n)


def position_beliefs(
    T_hat_en: Tensor,
    grid: PlanarGrid,
    calibration: PositionCalibration,
    area_m2: float | None = None,
) -> Tensor:
    """Per-frame position beliefs around a translation head's estimates.

    Args:
        T_hat_en: ``(B, 2)`` estimated ``(dE, dN)`` metres (the first two of ``T = [dE, dN,
            dU]``), in the grid's frame.
        grid: the position grid (cell centres ``(east0 + i h, north0 + j h)``).
        calibration: the fitted :class:`PositionCalibration`.
        area_m2: the uniform part's support (default: the area of the fit, the footprint).
    Returns:
        ``(B, n_east, n_north)`` float64 log-density per m^2 of the calibrated mixture at the
        cell centres (the continuous density, not renormalised on the grid).
    """
    if T_hat_en.dim() != 2 or T_hat_en.shape[1] != 2:
        raise ValueError(f"T_hat_en must have shape (B, 2), got {tuple(T_hat_en.shape)}")
    hat = T_hat_en.detach().to(torch.float64)
    east, north = grid.centres(torch.float64, hat.device)
    cells = torch.stack(torch.meshgrid(east, north, indexing="ij"), dim=-1)  # (n_e, n_n, 2)
    return calibration.log_density(cells - hat[:, None, None, :], area_m2)
