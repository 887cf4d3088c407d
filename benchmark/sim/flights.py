"""UAV flight curves around a city's flight centres, sampled like 30 fps video (paper Sec. 3.1).

A flight is a smooth curve around one centre point: the UAV orbits the centre on a wobbling
radius at a constant ground speed, its camera heading is the direction of travel plus a per-flight
offset (so headings cover the full circle, as the paper's psi in [-180, 180] deg), and pitch,
roll and altitude drift slowly inside their ranges. Samples are every ``frame_stride``-th frame of
a ``fps`` video, so consecutive samples of one flight are close but not identical; whole flights,
never single frames, are assigned to splits (see ``benchmark.sim.splits``).

Units: positions in metres ENU, angles in radians, time in seconds. The altitude range is the
height above the ground at the flight's centre (the paper's "flight altitude about 80-120 m"); the
UAV keeps ``clearance_margin_m`` above ``City.clearance`` (the top of any structure near it), and a
flight that would violate this is redrawn with the next attempt's seed.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from benchmark.sim import detmath

FLIGHT_STREAM = 0x46  # spawn-key tag of the flight seeds (see flight_rng)
MAX_ATTEMPTS = 64


class CityLike(Protocol):
    """What a flight needs from ``benchmark.sim.City``."""

    def ground_height(self, E: np.ndarray, N: np.ndarray) -> np.ndarray: ...

    def clearance(self, E: np.ndarray, N: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True)
class FlightSpec:
    """Ranges of one family of flights. Degrees here (a config edge), radians in ``Flight``."""

    altitude_m: tuple[float, float] = (80.0, 120.0)  # above the ground at the centre
    pitch_deg: tuple[float, float] = (-50.0, 0.0)  # lo == hi fixes the pitch (flight test sets)
    roll_deg: tuple[float, float] = (-10.0, 10.0)
    radius_m: tuple[float, float] = (
        60.0,
        380.0,
    )  # orbit radius; keeps |dN| < 500 m (sat half-height)
    speed_mps: tuple[float, float] = (6.0, 15.0)
    heading_wobble_deg: float = 25.0  # amplitude of the slow camera-heading oscillation
    samples: int = 16  # samples per flight
    frame_stride: int = 15  # video frames between two samples: 30 fps / 15 = 2 samples/s
    fps: float = 30.0
    clearance_margin_m: float = 15.0

    def __post_init__(self) -> None:
        for name in ("altitude_m", "pitch_deg", "roll_deg", "radius_m", "speed_mps"):
            lo, hi = getattr(self, name)
            if not lo <= hi:
                raise ValueError(f"FlightSpec.{name}: expected lo <= hi, got ({lo}, {hi})")
        if self.samples < 1 or self.frame_stride < 1 or self.fps <= 0:
            raise ValueError(
                f"FlightSpec: samples, frame_stride >= 1 and fps > 0 expected, got "
                f"samples={self.samples} frame_stride={self.frame_stride} fps={self.fps}"
            )
        if self.radius_m[0] <= 0:
            raise ValueError(f"FlightSpec.radius_m must be positive, got {self.radius_m}")


@dataclass(frozen=True)
class Flight:
    """One sampled flight. Every array has shape ``(S,)`` with S = ``spec.samples``.

    ``E, N, U`` metres ENU; ``yaw, pitch, roll`` radians (paper Eq. 1, yaw in (-pi, pi]);
    ``frame`` is the 30 fps video frame number inside the flight, ``time_s`` = frame / fps.
    """

    centre: tuple[float, float]
    E: np.ndarray
    N: np.ndarray
    U: np.ndarray
    yaw: np.ndarray
    pitch: np.ndarray
    roll: np.ndarray
    frame: np.ndarray
    time_s: np.ndarray
    attempt: int


def flight_rng(seed: int, group: int, flight: int, attempt: int) -> np.random.Generator:
    """The generator of one flight attempt; independent of every other flight and of order."""
    ss = np.random.SeedSequence(int(seed), spawn_key=(FLIGHT_STREAM, group, flight, attempt))
    return np.random.default_rng(ss)


def fold_into(x: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Reflect ``x`` into ``[lo, hi]`` (a triangle wave), which keeps a smooth curve continuous.

    Clipping would park the value on the bound for a while; reflection keeps it moving.
    """
    if hi <= lo:
        return np.full_like(x, lo)
    width = hi - lo
    y = np.mod(x - lo, 2.0 * width)
    folded = lo + np.where(y > width, 2.0 * width - y, y)
    return np.where((x >= lo) & (x <= hi), x, folded)  # exact identity inside the range


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Wrap radians into (-pi, pi]."""
    return np.pi - np.mod(np.pi - a, 2.0 * np.pi)


def _oscillation(
    rng: np.random.Generator, t: np.ndarray, period_s: tuple[float, float]
) -> np.ndarray:
    """A smooth unit-amplitude wiggle: a sum of two sines with random periods and phases."""
    out = np.zeros_like(t)
    for weight in (0.7, 0.3):
        period = rng.uniform(*period_s)
        out += weight * detmath.sin(2.0 * np.pi * t / period + rng.uniform(0.0, 2.0 * np.pi))
    return out


def _draw_flight(
    rng: np.random.Generator, centre: tuple[float, float], ground_at_centre: float, spec: FlightSpec
) -> dict[str, np.ndarray]:
    frame = np.arange(spec.samples, dtype=np.int64) * spec.frame_stride
    t = frame / spec.fps
    deg = math.pi / 180.0

    # Orbit: polar angle advances at speed / radius, radius wobbles by up to 25 %.
    r0 = rng.uniform(*spec.radius_m)
    r_amp = rng.uniform(0.0, 0.25) * r0
    radius = fold_into(r0 + r_amp * _oscillation(rng, t, (20.0, 60.0)), *spec.radius_m)
    speed = rng.uniform(*spec.speed_mps)
    direction = rng.choice([-1.0, 1.0])
    theta0 = rng.uniform(-np.pi, np.pi)
    # Integrate d(theta)/dt = v / r on a fine grid (exact enough: r changes slowly).
    fine_t = np.linspace(0.0, max(t[-1], 1e-6), max(8 * spec.samples, 64))
    fine_r = np.interp(fine_t, t, radius) if spec.samples > 1 else np.full_like(fine_t, r0)
    dtheta = speed / fine_r
    fine_theta = theta0 + direction * np.concatenate(
        [[0.0], np.cumsum(0.5 * (dtheta[1:] + dtheta[:-1]) * np.diff(fine_t))]
    )
    theta = np.interp(t, fine_t, fine_theta)
    E = centre[0] + radius * detmath.cos(theta)
    N = centre[1] + radius * detmath.sin(theta)

    # Heading of travel: the tangent of the circle (radius drift ignored for the camera).
    vE, vN = -direction * detmath.sin(theta), direction * detmath.cos(theta)
    travel_yaw = detmath.arctan2(-vE, vN)  # yaw 0 looks north, +90 deg looks west (DEVELOPERS.md)
    offset = rng.uniform(-np.pi, np.pi)
    wobble = spec.heading_wobble_deg * deg * _oscillation(rng, t, (10.0, 40.0))
    yaw = wrap_angle(travel_yaw + offset + wobble)

    def slow(rng_range: tuple[float, float], amp_frac: float, scale: float) -> np.ndarray:
        lo, hi = rng_range[0] * scale, rng_range[1] * scale
        base = rng.uniform(lo, hi)
        amp = rng.uniform(0.0, amp_frac) * (hi - lo)
        return fold_into(base + amp * _oscillation(rng, t, (8.0, 30.0)), lo, hi)

    pitch = slow(spec.pitch_deg, 0.25, deg)
    roll = slow(spec.roll_deg, 0.4, deg)
    U = ground_at_centre + slow(spec.altitude_m, 0.2, 1.0)
    return dict(E=E, N=N, U=U, yaw=yaw, pitch=pitch, roll=roll, frame=frame, time_s=t)


def generate_flight(
    city: CityLike,
    centre: tuple[float, float],
    spec: FlightSpec,
    *,
    seed: int,
    group: int,
    flight: int,
    accept: Callable[[dict[str, np.ndarray]], bool] | None = None,
) -> Flight:
    """Draw flight number ``flight`` of seed group ``group`` around ``centre`` (E, N metres).

    Deterministic in (seed, group, flight, spec, city). Attempts whose camera would come closer
    than ``spec.clearance_margin_m`` to a structure top are redrawn with the next attempt index.
    ``accept`` (optional) vetoes an attempt given its sample arrays (``E, N, U, yaw, pitch, roll``),
    e.g. to keep a test flight away from the training frames. Raises ``RuntimeError`` if
    ``MAX_ATTEMPTS`` attempts all fail (a city too tall for the spec, or a too strict ``accept``).
    """
    centre = (float(centre[0]), float(centre[1]))
    ground = float(
        np.asarray(city.ground_height(np.array([centre[0]]), np.array([centre[1]]))).ravel()[0]
    )
    worst = -np.inf
    for attempt in range(MAX_ATTEMPTS):
        d = _draw_flight(flight_rng(seed, group, flight, attempt), centre, ground, spec)
        top = np.asarray(city.clearance(d["E"], d["N"]), dtype=np.float64).reshape(d["E"].shape)
        margin = float(np.min(d["U"] - top))
        worst = max(worst, margin)
        if margin >= spec.clearance_margin_m and (accept is None or accept(d)):
            return Flight(centre=centre, attempt=attempt, **d)
    raise RuntimeError(
        f"generate_flight: no acceptable flight around centre {centre} in {MAX_ATTEMPTS} attempts "
        f"(clearance margin wanted {spec.clearance_margin_m} m, best {worst:.1f} m); raise "
        f"FlightSpec.altitude_m, lower the city's structure heights or relax the accept test"
    )
