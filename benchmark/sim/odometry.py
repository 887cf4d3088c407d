"""Odometry in the data (issue 39, item 1): each UAV sample carries the motion since the previous
sample of its flight, as a consumer IMU plus visual odometry (VIO) would report it.

**Columns** (:data:`ODOMETRY_COLUMNS`, float64, on every row of ``uav.parquet`` and
``pairs.parquet``; NaN on the first sample of every flight):

- ``odo_dyaw`` (rad, wrapped to (-pi, pi]): the measured heading increment from the previous
  sample of the same flight to this one;
- ``odo_dx``, ``odo_dy``, ``odo_dz`` (m): the measured displacement from the previous sample to
  this one, in the *levelled heading frame of the previous sample*: x right, y forward, z up, i.e.
  the body frame with pitch and roll removed, ``d = Rz(yaw_prev)^T d_nav`` (``d_nav`` = (dE, dN,
  dU) in ENU). So a UAV flying north at yaw 0 has ``odo_dy > 0``, ``odo_dx ~ 0``; one at yaw
  +90 deg flying west the same.

Why this frame: a VIO cannot observe its heading globally (no compass in the loop), but gravity
makes pitch and roll observable, so it reports each step in its own gravity-aligned frame. A
consumer of the columns carries a step into ENU with its own heading estimate,
``d_nav = Rz(psi) d`` (``benchmark.evaluation.sequence``), which is where the cross-view heading
comes in. Pitch and roll are not in the columns: the UAV's gravity sensor gives them per sample.

**Noise model** (:class:`OdometryNoise`, one flight of K samples, K - 1 increments):

- ``dyaw_meas = wrap(dyaw_true + b dt_k + n_k)``, ``dyaw_true = wrap(yaw_k - yaw_{k-1})``: a
  per-flight gyro bias ``b ~ N(0, gyro_bias_sigma^2)`` rad/s integrated over the step's
  ``dt_k`` (``time_s`` difference) and an angle random walk ``n_k ~ N(0, yaw_walk_sigma^2)`` rad
  per step;
- ``d_meas = (1 + s) d_true + m_k``: a per-flight scale error ``s ~ N(0, scale_sigma^2)`` (VIO
  scale drift) and ``m_k ~ N(0, position_step_sigma^2 I_3)`` m per step and axis.

Draws per flight, in this order: ``b``, ``s``, ``n`` (K - 1), ``m`` (K - 1, 3), from one
generator per flight (:func:`odometry_rng`: ``SeedSequence(seed, spawn_key=(ODOMETRY_STREAM,
flight))``), so the odometry is independent of rendering, of the order of the plan and of every
other flight. ``sin``/``cos`` go through ``benchmark.sim.detmath``, like the labels, so the
columns are the same on every CPU.

The noise figures live in the data profile in degrees (``benchmark.data.profiles.Profile``,
``odometry_*`` fields; which figures and why: there); :func:`odometry_noise` turns them into an
:class:`OdometryNoise` in SI units.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from benchmark.sim import detmath
from benchmark.sim.flights import wrap_angle

ODOMETRY_STREAM = 0x4F  # "O": spawn-key tag of the per-flight odometry generators
ODOMETRY_COLUMNS = ("odo_dyaw", "odo_dx", "odo_dy", "odo_dz")
# Profile fields (degrees and fractions, the config edge) -> OdometryNoise fields (SI).
PROFILE_FIELDS = (
    "odometry_gyro_bias_dps",
    "odometry_yaw_walk_deg",
    "odometry_scale_sigma",
    "odometry_step_sigma_m",
)


@dataclass(frozen=True)
class OdometryNoise:
    """Odometry noise figures, SI units: standard deviations of the per-flight gyro bias (rad/s),
    the angle random walk per step (rad), the per-flight translation scale error (fraction) and
    the per-step translation noise per axis (m).

    Defaults are the yardstick of issue 39 (0.2 deg/s bias, 0.2 deg per step, 3 % scale) and
    0.5 m per step (visual odometry over ~2 s steps at ~10 m/s)."""

    gyro_bias_sigma: float = math.radians(0.2)
    yaw_walk_sigma: float = math.radians(0.2)
    scale_sigma: float = 0.03
    position_step_sigma: float = 0.5

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if not (value >= 0 and math.isfinite(value)):
                raise ValueError(f"{name} must be finite and >= 0, got {value!r}")


def odometry_noise(profile: Mapping[str, Any] | Any) -> OdometryNoise:
    """The :class:`OdometryNoise` of a data profile: a ``benchmark.data.profiles.Profile`` or its
    dict (a manifest's ``"profile"``), whose ``odometry_*`` fields are in degrees (converted to
    radians here). ValueError naming the fields a dict lacks (a dataset of older code)."""
    if isinstance(profile, Mapping):
        missing = [k for k in PROFILE_FIELDS if k not in profile]
        if missing:
            raise ValueError(
                f"profile has no odometry noise fields {missing} (a dataset from before issue "
                f"39: re-simulate it)"
            )
        values = [float(profile[k]) for k in PROFILE_FIELDS]
    else:
        values = [float(getattr(profile, k)) for k in PROFILE_FIELDS]
    bias_dps, walk_deg, scale, step_m = values
    return OdometryNoise(math.radians(bias_dps), math.radians(walk_deg), scale, step_m)


def odometry_rng(seed: int, flight: int) -> np.random.Generator:
    """The generator of flight ``flight``'s odometry noise in a dataset of ``seed``: depends on
    nothing else (not on rendering, on the plan's order or on other flights)."""
    ss = np.random.SeedSequence(int(seed), spawn_key=(ODOMETRY_STREAM, int(flight)))
    return np.random.default_rng(ss)


def _as_flight(name: str, x: Any, k: int | None) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim != 1 or (k is not None and a.shape[0] != k) or a.shape[0] < 1:
        raise ValueError(f"flight_odometry: {name} must be 1-D of length K >= 1, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"flight_odometry: {name} must be finite")
    return a


def flight_odometry(
    E: np.ndarray,
    N: np.ndarray,
    U: np.ndarray,
    yaw: np.ndarray,
    time_s: np.ndarray,
    *,
    noise: OdometryNoise,
    rng: np.random.Generator,
) -> np.ndarray:
    """Measured odometry of one flight of K samples in time order: ``(K, 4)`` float64, the
    columns of :data:`ODOMETRY_COLUMNS` (``odo_dyaw`` rad, ``odo_dx, odo_dy, odo_dz`` m in the
    levelled heading frame of the previous sample), row 0 NaN.

    ``E, N, U`` (K,) metres ENU, ``yaw`` (K,) radians, ``time_s`` (K,) seconds, strictly
    increasing. Draws from ``rng`` in the order of the module docstring (a flight of one sample
    draws the two per-flight values only).
    """
    yaw = _as_flight("yaw", yaw, None)
    K = yaw.shape[0]
    E, N, U = (_as_flight(n, x, K) for n, x in (("E", E), ("N", N), ("U", U)))
    t = _as_flight("time_s", time_s, K)
    dt = np.diff(t)
    if np.any(dt <= 0):
        raise ValueError("flight_odometry: time_s must increase strictly within a flight")
    bias = rng.normal(0.0, noise.gyro_bias_sigma)
    scale = rng.normal(0.0, noise.scale_sigma)
    walk = rng.normal(0.0, noise.yaw_walk_sigma, K - 1)
    step = rng.normal(0.0, noise.position_step_sigma, (K - 1, 3))

    # Truth: the heading increment (a flight turns far less than 180 deg per step) and the nav
    # displacement seen from the previous sample's levelled frame, Rz(yaw_prev)^T d_nav.
    dyaw_true = wrap_angle(np.diff(yaw))
    c, s = detmath.cos(yaw[:-1]), detmath.sin(yaw[:-1])
    dE, dN, dU = np.diff(E), np.diff(N), np.diff(U)
    level = np.stack([c * dE + s * dN, c * dN - s * dE, dU], axis=1)

    out = np.full((K, len(ODOMETRY_COLUMNS)), np.nan)
    out[1:, 0] = wrap_angle(dyaw_true + bias * dt + walk)
    out[1:, 1:] = (1.0 + scale) * level + step
    return out


def plan_odometry(
    flight: np.ndarray,
    frame: np.ndarray,
    columns: Mapping[str, np.ndarray],
    noise: OdometryNoise,
    seed: int,
) -> np.ndarray:
    """Odometry of every UAV row of a plan: ``(n, 4)`` float64 aligned with the rows.

    ``flight`` (n,) int flight numbers, ``frame`` (n,) video frame numbers; ``columns`` maps
    ``E, N, U, yaw, time_s`` to (n,) arrays (a DataFrame works). Each flight's rows are taken in
    frame order and get :func:`flight_odometry` with :func:`odometry_rng` ``(seed, flight)``.
    """
    flight = np.asarray(flight, dtype=np.int64)
    frame = np.asarray(frame, dtype=np.int64)
    data = {k: np.asarray(columns[k], dtype=np.float64) for k in ("E", "N", "U", "yaw", "time_s")}
    out = np.full((flight.shape[0], len(ODOMETRY_COLUMNS)), np.nan)
    order = np.lexsort((frame, flight))  # by flight, then frame
    bounds = np.flatnonzero(np.diff(flight[order])) + 1
    for rows in np.split(order, bounds):
        if rows.size == 0:
            continue
        out[rows] = flight_odometry(
            *(data[k][rows] for k in ("E", "N", "U", "yaw", "time_s")),
            noise=noise,
            rng=odometry_rng(seed, int(flight[rows[0]])),
        )
    return out


__all__ = [
    "ODOMETRY_COLUMNS",
    "ODOMETRY_STREAM",
    "OdometryNoise",
    "flight_odometry",
    "odometry_noise",
    "odometry_rng",
    "plan_odometry",
]
