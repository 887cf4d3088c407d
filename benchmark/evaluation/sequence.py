"""Fuse a split's per-frame beliefs along its flights: the evaluation step of issue 39.

Input (:class:`SplitFrames`): one row per pair of a split, in any order, with its flight and time,
the head's per-frame yaw belief (``benchmark.evaluation.beliefs``), its per-frame estimates, the
odometry that arrived with the frame and the truth (for the errors only: nothing the filters read
comes from the truth). Output (:func:`fuse_split`): one row per pair and fusion mode,

- ``frame``: the head's own per-frame estimate (what every other table scores);
- ``filter``: the causal filter, sample k fused from samples ``<= k`` (what a UAV has online);
- ``smooth``: the forward-backward smoother over the whole flight,

with the fused yaw, position and their errors (``dpsi_deg``, ``dphi_deg``, ``horizontal_m``).

**What is fused.** The heading is what the satellite image must supply (a UAV's gravity sensor
gives pitch and roll), so the attitude fusion runs on yaw: the fused attitude is
``Rz(psi_fused) Rx(pitch_hat) Ry(roll_hat)`` with the head's own per-frame pitch and roll, and
``dphi`` is its geodesic error. Position is fused in the horizontal plane, on a grid covering the
satellite image's footprint around its capture point (the translation label's origin): known
before the flight, so the grid reads nothing of later samples.

**Odometry** (dataset columns ``odo_dyaw``, ``odo_dx``, ``odo_dy``; NaN on a flight's first
sample): the heading increment since the previous sample and the displacement in the levelled
heading frame of the previous sample (x right, y forward), as a VIO reports a step. A step is
carried into the navigation frame with the fused heading of the sample it starts from,
``d_nav = Rz(psi) d`` (the causal filter's estimate, for the filter and the smoother alike: one
forward pass serves both, and the filter may read nothing later), and
the heading's uncertainty adds a cross-track variance ``|d|^2 sigma_psi^2`` with ``sigma_psi =
sqrt(-2 ln R)``, ``R`` the posterior's mean resultant length (the circular standard deviation;
capped at 1 rad, beyond which a heading carries no direction).

**Transition noise** is the profile's stated odometry noise (``OdometryNoise``), turned into a
per-step white noise by ``yaw_transition_sigma`` / ``position_transition_covariance`` with the
step's own ``dt`` (``fusion_odometry`` explains the horizon). The robust outlier weight is the
same for every head (``FusionSettings.outlier_weight``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
import torch
from torch import Tensor

from benchmark.evaluation.fusion import (
    CircularGrid,
    OdometryNoise,
    PlanarGrid,
    PositionFlights,
    YawFlights,
    filter_and_smooth_position,
    filter_and_smooth_yaw,
    position_transition_covariance,
)
from benchmark.evaluation.fusion_joint import (
    JointBelief,
    JointFlight,
    JointGrid,
    filter_and_smooth_joint,
)
from benchmark.geometry import angle_difference, euler_to_rotmat, geodesic_distance

MODES = ("frame", "filter", "smooth")
_MAX_HEADING_SIGMA = 1.0  # rad: beyond it a heading says nothing about a step's direction


@dataclass(frozen=True)
class FusionSettings:
    """Grids and the robust weight of the flight fusion.

    ``yaw_bins`` cells over the circle (720: 0.5 deg); ``position_spacing_m`` the plane's cell
    (10 m: a 2 km x 1 km footprint is 201 x 101 cells; the MAP is refined between cells);
    ``outlier_weight`` the uniform share of every frame's likelihood; ``horizon`` the steps over
    which the white transition noise matches the odometry's drift (``fusion_odometry``);
    ``flights_per_batch`` bounds the memory of the position grid (a batch holds
    ``flights x samples x cells`` float64). The joint fusion (:func:`fuse_split_joint`) runs on
    ``joint_heading_bins`` heading offsets (120: 3 deg, beside a pose volume's 10 deg bins; the
    MAP is refined between bins) x a plane of ``joint_spacing_m`` cells (20 m: a pose volume's
    20.8 m cells), sized for its cost: ``K x bins x cells`` float64 per flight (1.3 M cells on a
    2 km x 1 km footprint, about 4 s for a 32-sample flight on one core)."""

    yaw_bins: int = 720
    position_spacing_m: float = 10.0
    outlier_weight: float = 0.3
    horizon: float = 4.0
    flights_per_batch: int = 8
    joint_heading_bins: int = 120
    joint_spacing_m: float = 20.0

    def __post_init__(self) -> None:
        if not (self.position_spacing_m > 0 and 0 <= self.outlier_weight <= 1):
            raise ValueError(
                f"FusionSettings: position_spacing_m > 0 and outlier_weight in [0, 1] expected, "
                f"got {self.position_spacing_m!r}, {self.outlier_weight!r}"
            )
        if self.flights_per_batch < 1 or self.horizon < 0:
            raise ValueError("FusionSettings: flights_per_batch >= 1 and horizon >= 0 expected")
        if self.joint_heading_bins < 8 or not self.joint_spacing_m > 0:
            raise ValueError(
                "FusionSettings: joint_heading_bins >= 8 and joint_spacing_m > 0 expected"
            )


@dataclass(frozen=True)
class SplitFrames:
    """A split's pairs, ``N`` rows aligned across every array (numpy float64 unless said).

    ``flight (N,)`` int, ``time_s (N,)`` s; ``yaw_beliefs (N, n_bins)`` torch log-density per
    radian on ``CircularGrid(n_bins)``; estimates ``yaw_hat``, ``pitch_hat``, ``roll_hat (N,)``
    rad (navigation frame, UAV), ``position_hat (N, 2)`` (dE, dN) m; ``position_log_belief``: a
    function ``(rows (M,) int64 tensor, grid) -> (M, n_east, n_north)`` log-density of the
    frames at those rows of the arrays (-1: a flight's padding, any finite belief will do): a
    head's calibrated belief around ``position_hat``, or a pose volume's own; odometry ``odo_dyaw
    (N,)`` rad and ``odo_dxy (N, 2)`` m (levelled frame of the previous sample; NaN on a flight's
    first sample); ``footprint_m (N, 2)`` the satellite image's E x N extent, m; truth ``yaw``,
    ``pitch``, ``roll (N,)`` rad and ``position (N, 2)`` m, used for the errors only."""

    flight: np.ndarray
    time_s: np.ndarray
    yaw_beliefs: Tensor
    yaw_hat: np.ndarray
    pitch_hat: np.ndarray
    roll_hat: np.ndarray
    position_hat: np.ndarray
    position_log_belief: object
    odo_dyaw: np.ndarray
    odo_dxy: np.ndarray
    footprint_m: np.ndarray
    yaw: np.ndarray
    pitch: np.ndarray
    roll: np.ndarray
    position: np.ndarray
    index: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    def __post_init__(self) -> None:
        n = len(self.flight)
        for name in ("time_s", "yaw_hat", "pitch_hat", "roll_hat", "odo_dyaw", "yaw", "pitch",
                     "roll"):  # fmt: skip
            if np.shape(getattr(self, name)) != (n,):
                raise ValueError(f"SplitFrames.{name}: expected shape ({n},)")
        for name in ("position_hat", "odo_dxy", "footprint_m", "position"):
            if np.shape(getattr(self, name)) != (n, 2):
                raise ValueError(f"SplitFrames.{name}: expected shape ({n}, 2)")
        if self.yaw_beliefs.dim() != 2 or self.yaw_beliefs.shape[0] != n:
            raise ValueError(f"SplitFrames.yaw_beliefs: expected (N={n}, n_bins)")


def flight_rows(flight: np.ndarray, time_s: np.ndarray) -> list[np.ndarray]:
    """Row indices of each flight in time order, flights in order of their id: ``[(K_f,)]``."""
    order = np.lexsort((np.asarray(time_s), np.asarray(flight)))
    ids = np.asarray(flight)[order]
    cuts = np.flatnonzero(np.diff(ids)) + 1
    return np.split(order, cuts)


def _padded(values: np.ndarray | Tensor, rows: list[np.ndarray], fill: float) -> Tensor:
    """Rows ``(N, ...)`` -> ``(B, K, ...)`` by flight, short flights padded with ``fill``."""
    # (a copy: pandas hands out read-only arrays, which torch will not wrap)
    x = values if isinstance(values, Tensor) else torch.from_numpy(np.array(values, np.float64))
    x = x.to(torch.float64)
    K = max(len(r) for r in rows)
    out = torch.full((len(rows), K, *x.shape[1:]), fill, dtype=torch.float64)
    for b, r in enumerate(rows):
        out[b, : len(r)] = x[torch.as_tensor(r)]
    return out


def _observed(rows: list[np.ndarray]) -> Tensor:
    K = max(len(r) for r in rows)
    lengths = torch.as_tensor([len(r) for r in rows])
    return torch.arange(K)[None, :] < lengths[:, None]


def _steps(frames: SplitFrames, rows: list[np.ndarray]) -> tuple[Tensor, Tensor, Tensor]:
    """Odometry per increment ``(B, K-1)``: yaw step, levelled displacement ``(B, K-1, 2)``, dt;
    zero beyond a flight's end (the identity transition: padded samples stay put)."""
    obs = _observed(rows)[:, 1:]
    dyaw = _padded(frames.odo_dyaw, rows, 0.0)[:, 1:]
    dxy = _padded(frames.odo_dxy, rows, 0.0)[:, 1:]
    t = _padded(frames.time_s, rows, 0.0)
    dt = torch.where(obs, t[:, 1:] - t[:, :-1], torch.zeros_like(dyaw))
    bad = obs & ~(torch.isfinite(dyaw) & torch.isfinite(dxy).all(-1) & (dt > 0))
    if bool(bad.any()):
        b, k = (int(i) for i in torch.nonzero(bad)[0])
        raise ValueError(
            f"odometry of flight {int(frames.flight[rows[b][0]])}, sample {k + 1}: odo_dyaw, "
            f"odo_dx, odo_dy must be finite and time_s must increase (got dyaw "
            f"{float(dyaw[b, k])!r}, dxy {dxy[b, k].tolist()}, dt {float(dt[b, k])!r})"
        )
    zero = ~obs
    return dyaw.masked_fill(zero, 0.0), dxy.masked_fill(zero[..., None], 0.0), dt


def _yaw_sigma(noise: OdometryNoise, dt: Tensor, horizon: float) -> Tensor:
    """Per-step transition standard deviation (rad), ``yaw_transition_sigma`` at each ``dt``."""
    sd = torch.sqrt(noise.yaw_walk_sigma**2 + horizon * (noise.gyro_bias_sigma * dt) ** 2)
    return torch.where(dt > 0, sd, torch.zeros_like(sd))


def _navigation_steps(
    dxy: Tensor, heading: Tensor, resultant: Tensor, noise: OdometryNoise, horizon: float
) -> tuple[Tensor, Tensor]:
    """Levelled steps ``(B, K-1, 2)`` -> navigation-frame displacement and covariance, rotated by
    the heading of the sample each step starts from (``heading (B, K-1)``, its resultant
    length ``resultant (B, K-1)``)."""
    c, s = torch.cos(heading), torch.sin(heading)
    east = c * dxy[..., 0] - s * dxy[..., 1]  # Rz(psi) [x, y]: yaw 0 looks north, +90 west
    north = s * dxy[..., 0] + c * dxy[..., 1]
    d = torch.stack([east, north], dim=-1)
    cov = position_transition_covariance(d, noise, horizon)
    sigma = torch.sqrt(-2 * torch.log(resultant.clamp(1e-12, 1.0))).clamp(max=_MAX_HEADING_SIGMA)
    length2 = (d**2).sum(-1)
    across = (
        torch.stack([-d[..., 1], d[..., 0]], dim=-1) / length2.clamp_min(1e-12).sqrt()[..., None]
    )
    cov = cov + (length2 * sigma**2)[..., None, None] * across[..., :, None] * across[..., None, :]
    return d, cov


def _position_grid(footprint: np.ndarray, spacing: float) -> PlanarGrid:
    """The satellite footprint around its capture point (the translation's origin)."""
    half = np.asarray(footprint, np.float64) / 2
    n = np.ceil(2 * half / spacing).astype(int) + 1
    return PlanarGrid(float(-half[0]), float(-half[1]), spacing, int(n[0]), int(n[1]))


def fuse_split(
    frames: SplitFrames,
    noise: OdometryNoise,
    settings: FusionSettings | None = None,
    position: bool = True,
) -> pd.DataFrame:
    """Per-frame, filtered and smoothed estimates and errors of every pair of ``frames``.

    Returns one row per (pair, mode), columns ``index, flight, sample, t_s, mode, yaw_hat_deg,
    E_hat_m, N_hat_m, dpsi_deg, dphi_deg, horizontal_m`` (``sample`` the position in its flight,
    ``t_s`` seconds since its first sample), rows ordered by mode, then flight and time.
    ``position=False`` fuses the heading only: the filtered and smoothed rows' ``E_hat_m``,
    ``N_hat_m`` and ``horizontal_m`` are NaN (the position grid is most of the cost, and the
    heading's columns are bit-identical either way: its fusion never reads a position)."""
    settings = settings or FusionSettings()
    grid = CircularGrid(settings.yaw_bins)
    if frames.yaw_beliefs.shape[1] != grid.n_bins:
        raise ValueError(
            f"yaw_beliefs have {frames.yaw_beliefs.shape[1]} bins, settings.yaw_bins is "
            f"{grid.n_bins}"
        )
    rows = flight_rows(frames.flight, frames.time_s)
    observed = _observed(rows)
    K = observed.shape[1]
    dyaw, dxy, dt = _steps(frames, rows)
    beliefs = _padded(frames.yaw_beliefs, rows, 0.0)
    yaw_in = YawFlights(beliefs, dyaw, _yaw_sigma(noise, dt, settings.horizon), observed)
    w = settings.outlier_weight
    yaw_filter, yaw_smooth = filter_and_smooth_yaw(yaw_in, grid, w)
    # The steps are turned by the causal filter's heading for both position estimates: the
    # filter may read nothing later, and one forward pass then serves the smoother too.
    d, cov = _navigation_steps(
        dxy, yaw_filter.map[:, :-1], yaw_filter.resultant[:, :-1], noise, settings.horizon
    )
    if position:
        position_filter, position_smooth = _fuse_positions(frames, rows, observed, d, cov, settings)
    else:
        position_filter = position_smooth = torch.full_like(d[:, :1].expand(-1, K, -1), math.nan)
    estimates = {
        "frame": (_padded(frames.yaw_hat, rows, 0.0), _padded(frames.position_hat, rows, 0.0)),
        "filter": (yaw_filter.map, position_filter),
        "smooth": (yaw_smooth.map, position_smooth),
    }
    return _error_table(frames, rows, estimates)


def fuse_split_joint(
    frames: SplitFrames,
    joint_belief: Callable[[np.ndarray, PlanarGrid], JointBelief],
    noise: OdometryNoise,
    settings: FusionSettings | None = None,
    progress: Callable[[int, int], None] | None = None,
    smooth: bool = True,
) -> pd.DataFrame:
    """:func:`fuse_split` with beliefs that are joint over (heading, E, N): each flight fused
    by :func:`~benchmark.evaluation.fusion_joint.filter_and_smooth_joint` on the satellite
    footprint's plane (``settings.joint_*``). ``joint_belief(rows (K_f,), plane)`` gives the
    :data:`~benchmark.evaluation.fusion_joint.JointBelief` of a flight's frames (rows of
    ``frames`` in time order); ``frames.yaw_beliefs`` and ``position_log_belief`` are not read.
    The "frame" rows are ``frames``' own estimates; same table as :func:`fuse_split`
    (``smooth=False``: without the "smooth" rows, the filter only). ``progress(done, total)``
    after each flight."""
    settings = settings or FusionSettings()
    rows = flight_rows(frames.flight, frames.time_s)
    dyaw, dxy, dt = _steps(frames, rows)
    sigma = _yaw_sigma(noise, dt, settings.horizon)
    K = _observed(rows).shape[1]
    yaw = torch.zeros(2, len(rows), K, dtype=torch.float64)
    position = torch.zeros(2, len(rows), K, 2, dtype=torch.float64)
    heading = CircularGrid(settings.joint_heading_bins)
    for b, r in enumerate(rows):
        n = len(r)
        plane = _position_grid(frames.footprint_m[r[0]], settings.joint_spacing_m)
        flight = JointFlight(joint_belief(r, plane), dyaw[b, : n - 1], dxy[b, : n - 1],
                             sigma[b, : n - 1])  # fmt: skip
        fused = filter_and_smooth_joint(
            flight, JointGrid(heading, plane), noise, settings.outlier_weight, settings.horizon,
            smooth=smooth,
        )  # fmt: skip
        for m, est in enumerate(fused):
            if est is not None:
                yaw[m, b, :n] = est.heading.map
                position[m, b, :n] = est.position.map
        if progress is not None:
            progress(b + 1, len(rows))
    estimates = {
        "frame": (_padded(frames.yaw_hat, rows, 0.0), _padded(frames.position_hat, rows, 0.0)),
        "filter": (yaw[0], position[0]),
    }
    if smooth:
        estimates["smooth"] = (yaw[1], position[1])
    return _error_table(frames, rows, estimates)


def _fuse_positions(
    frames: SplitFrames,
    rows: list[np.ndarray],
    observed: Tensor,
    d: Tensor,
    cov: Tensor,
    settings: FusionSettings,
) -> tuple[Tensor, Tensor]:
    """Filtered and smoothed positions ``(B, K, 2)`` (MAP), flights batched by footprint."""
    out = torch.zeros(2, len(rows), observed.shape[1], 2, dtype=torch.float64)
    footprints = [tuple(np.round(frames.footprint_m[r[0]], 6)) for r in rows]
    for fp in dict.fromkeys(footprints):
        grid = _position_grid(np.asarray(fp), settings.position_spacing_m)
        members = [b for b, f in enumerate(footprints) if f == fp]
        for start in range(0, len(members), settings.flights_per_batch):
            batch = members[start : start + settings.flights_per_batch]
            index = _padded(np.arange(len(frames.flight)), [rows[b] for b in batch], -1.0)
            K = index.shape[1]
            log_b = frames.position_log_belief(index.reshape(-1).long(), grid)  # type: ignore[operator]
            flights = PositionFlights(
                log_b.reshape(len(batch), K, *grid.shape),
                d[batch, : K - 1],
                cov[batch, : K - 1],
                observed[batch, :K],
            )
            # the MAP is the estimate; the posterior mean (an exp of every cell) is not read
            posteriors = filter_and_smooth_position(
                flights, grid, settings.outlier_weight, mean=False
            )
            for m, post in enumerate(posteriors):
                out[m, batch, :K] = post.map
    return out[0], out[1]


def _error_table(
    frames: SplitFrames, rows: list[np.ndarray], estimates: dict[str, tuple[Tensor, Tensor]]
) -> pd.DataFrame:
    """Long table of estimates and errors per (mode, pair), for the modes of ``estimates`` (in
    ``MODES`` order)."""
    order = np.concatenate(rows)
    sample = np.concatenate([np.arange(len(r)) for r in rows])
    start = np.concatenate([np.full(len(r), frames.time_s[r[0]]) for r in rows])
    mask = _observed(rows)
    f64 = torch.float64
    truth_R = euler_to_rotmat(*(torch.as_tensor(getattr(frames, k)[order], dtype=f64)
                                for k in ("yaw", "pitch", "roll")))  # fmt: skip
    pitch_hat = torch.as_tensor(frames.pitch_hat[order], dtype=f64)
    roll_hat = torch.as_tensor(frames.roll_hat[order], dtype=f64)
    truth_yaw = torch.as_tensor(frames.yaw[order], dtype=f64)
    truth_pos = torch.as_tensor(frames.position[order], dtype=f64)
    index = frames.index[order] if len(frames.index) else order
    parts = []
    deg = 180.0 / math.pi
    for mode in (m for m in MODES if m in estimates):
        yaw_all, pos_all = estimates[mode]
        yaw_hat, pos_hat = yaw_all[mask], pos_all[mask]
        R_hat = euler_to_rotmat(yaw_hat, pitch_hat, roll_hat)
        parts.append(
            pd.DataFrame(
                {
                    "index": index,
                    "flight": frames.flight[order],
                    "sample": sample,
                    "t_s": frames.time_s[order] - start,
                    "mode": mode,
                    "yaw_hat_deg": (yaw_hat * deg).numpy(),
                    "E_hat_m": pos_hat[:, 0].numpy(),
                    "N_hat_m": pos_hat[:, 1].numpy(),
                    "dpsi_deg": (angle_difference(yaw_hat, truth_yaw).abs() * deg).numpy(),
                    "dphi_deg": (geodesic_distance(R_hat, truth_R) * deg).numpy(),
                    "horizontal_m": torch.linalg.vector_norm(pos_hat - truth_pos, dim=-1).numpy(),
                }
            )
        )
    return pd.concat(parts, ignore_index=True)


def summarize_sequence(table: pd.DataFrame) -> dict[str, float]:
    """``seq_<mode>_<metric>`` over a :func:`fuse_split` table: mean and median ``dpsi_deg`` and
    ``dphi_deg``, ``acc10`` (fraction of frames with ``dphi <= 10`` deg), median horizontal."""
    out: dict[str, float] = {}
    for mode, part in table.groupby("mode", sort=False):
        for col in ("dpsi_deg", "dphi_deg"):
            out[f"seq_{mode}_{col}"] = float(part[col].mean())
            out[f"seq_{mode}_median_{col}"] = float(part[col].median())
        out[f"seq_{mode}_acc10"] = float((part["dphi_deg"] <= 10.0).mean())
        out[f"seq_{mode}_median_horizontal_m"] = float(part["horizontal_m"].median())
    return out
