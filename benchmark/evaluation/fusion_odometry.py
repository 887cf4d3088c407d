"""Odometry noise for the flight fusion (issue 39, item 3): a simulator for tests and the
transition noise the grid filters use.

**Model.** Odometry increment ``k`` is the motion from sample ``k`` to ``k + 1`` (a flight of K
samples has K - 1 increments; a per-sample column "motion since the previous sample" is
``column[:, 1:]``). As a consumer IMU plus visual odometry gives it:

- yaw: ``dpsi_meas = wrap(dpsi_true + b dt + n_k)``, a per-flight gyro bias
  ``b ~ N(0, gyro_bias_sigma^2)`` rad/s and an angle random walk ``n_k ~ N(0, yaw_walk_sigma^2)``
  rad per step;
- position: ``d_meas = (1 + s) d_true + m_k``, ``d`` = (dE, dN) metres in the navigation frame, a
  per-flight scale error ``s ~ N(0, scale_sigma^2)`` and ``m_k ~ N(0, position_step_sigma^2 I)``.
  Body-frame visual odometry rotated by an estimated yaw adds a cross-track ``|d| sigma_psi``,
  which a user folds into ``position_step_sigma``.

Defaults are the yardstick of issue 39 (0.2 deg/s bias, 0.2 deg per step, 3 % scale) and 0.5 m
per step (our choice: visual odometry over 2 s steps at ~10 m/s). ``OdometryNoise`` itself lives
with the dataset's odometry columns in ``benchmark.sim.odometry`` (issue 39, item 1), reached
through ``benchmark.data`` (evaluation does not import the simulator) and re-exported here.

**Transition noise.** The bias and the scale error are constant over a flight, so their error
grows with the square of the number of steps bridged (``n^2 (sigma_b dt)^2``), which a one-state
grid cannot carry. The filters use a white noise per step whose variance matches the true drift
over ``horizon`` steps: ``sigma^2 = yaw_walk^2 + horizon (sigma_b dt)^2`` (over n steps the white
model gives ``n sigma^2``; the truth ``n yaw_walk^2 + n^2 (sigma_b dt)^2``: equal at
``n = horizon``, larger below, smaller above). Default ``horizon = 4``: with a belief at every
sample and ~30 % wrong matches the filter rarely bridges more than a few samples on odometry
alone. Not chosen: the exact marginal from the start of the flight (a per-step variance growing
as ``2k - 1``), which makes the blur depend on absolute time and over-diffuses every late step of
a long flight although the measurements keep the filter's memory short.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from benchmark.data import OdometryNoise
from benchmark.geometry import angle_difference


@dataclass(frozen=True)
class SimulatedOdometry:
    """Noisy odometry of ``B`` flights of ``K`` samples (numpy, float64).

    ``dyaw (B, K-1)`` rad in (-pi, pi], ``displacement (B, K-1, 2)`` (dE, dN) m, and the drawn
    per-flight ``gyro_bias (B,)`` rad/s and ``scale_error (B,)`` (fraction)."""

    dyaw: np.ndarray
    displacement: np.ndarray
    gyro_bias: np.ndarray
    scale_error: np.ndarray


def _wrap(angle: np.ndarray) -> np.ndarray:
    zero = torch.zeros((), dtype=torch.float64)
    return angle_difference(torch.as_tensor(angle, dtype=torch.float64), zero).numpy()


def simulate_odometry(
    yaw: np.ndarray,
    position: np.ndarray,
    dt: float,
    noise: OdometryNoise,
    rng: np.random.Generator,
) -> SimulatedOdometry:
    """Noisy odometry from the true ``yaw (B, K)`` rad and ``position (B, K, 2)`` (E, N) m.

    ``dt`` seconds between samples. The true yaw increment is the wrapped difference (a flight
    turns less than 180 deg per step). Draws, in this order, from ``rng``: gyro bias ``(B,)``,
    scale error ``(B,)``, angle random walk ``(B, K-1)``, translation noise ``(B, K-1, 2)``; the
    same generator state gives the same odometry.
    """
    yaw = np.asarray(yaw, dtype=np.float64)
    position = np.asarray(position, dtype=np.float64)
    if yaw.ndim != 2 or yaw.shape[1] < 2 or position.shape != (*yaw.shape, 2):
        raise ValueError(
            f"need yaw (B, K>=2), position (B, K, 2); got {yaw.shape}, {position.shape}"
        )
    if not (dt > 0 and math.isfinite(dt)):
        raise ValueError(f"dt must be positive, got {dt!r}")
    B, K = yaw.shape
    bias = rng.normal(0.0, noise.gyro_bias_sigma, B)
    scale = rng.normal(0.0, noise.scale_sigma, B)
    walk = rng.normal(0.0, noise.yaw_walk_sigma, (B, K - 1))
    step = rng.normal(0.0, noise.position_step_sigma, (B, K - 1, 2))
    dyaw_true = _wrap(np.diff(yaw, axis=1))
    dyaw = _wrap(dyaw_true + bias[:, None] * dt + walk)
    displacement = (1.0 + scale[:, None, None]) * np.diff(position, axis=1) + step
    return SimulatedOdometry(dyaw, displacement, bias, scale)


def yaw_transition_sigma(noise: OdometryNoise, dt: float, horizon: float = 4.0) -> float:
    """Standard deviation (rad) of the yaw transition per step:
    ``sqrt(yaw_walk_sigma^2 + horizon (gyro_bias_sigma dt)^2)`` (module docstring)."""
    if not horizon >= 0:
        raise ValueError(f"horizon must be >= 0, got {horizon!r}")
    return math.sqrt(noise.yaw_walk_sigma**2 + horizon * (noise.gyro_bias_sigma * dt) ** 2)


def position_transition_covariance(
    displacement: Tensor, noise: OdometryNoise, horizon: float = 4.0
) -> Tensor:
    """Covariance (m^2) of the position transition per step, ``(..., 2) -> (..., 2, 2)``:
    ``position_step_sigma^2 I + horizon scale_sigma^2 d d^T``. The scale error lies along the
    displacement ``d``, so the blur is elongated along track; its standard deviation grows with
    the step length (``sqrt(horizon) scale_sigma |d|``)."""
    if not horizon >= 0:
        raise ValueError(f"horizon must be >= 0, got {horizon!r}")
    d = displacement
    eye = torch.eye(2, dtype=d.dtype, device=d.device)
    along = d[..., :, None] * d[..., None, :]
    return noise.position_step_sigma**2 * eye + horizon * noise.scale_sigma**2 * along
