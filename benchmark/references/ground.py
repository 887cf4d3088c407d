"""Ground-plane geometry shared by the references: UAV pixels cast onto the ground, satellite pixels
lifted to it.

The one approximation every reference makes: the ground is the horizontal plane at the terrain
height of the satellite image's centre, ``z_g = sat_U - height_m`` (the satellite camera is
``height_m`` above the terrain at its centre, ``benchmark.sim.render.satellite_pose``). Terrain
relief and buildings break it; that is part of what the references measure.

UAV side (``benchmark/sim/camera.py`` is the truth). Pixel ``(u, v)`` (centres on integers) looks
along the body direction ``d_b = ((u - cx) / f, 1, -(v - cy) / f)``; in the navigation frame
``d_n = Rz(yaw) Rx(pitch) Ry(roll) d_b``. Yaw turns about the vertical, so it leaves ``d_n``'s
vertical component and the distance along the ray to the plane unchanged and turns the horizontal
hit offset: one cast at yaw 0 serves every yaw (:func:`rotate_offsets`).

Satellite side (``benchmark.sim.render.render_satellite``). The image is a north-up nadir view of
``footprint_E x footprint_N`` metres at ``z_g``, rendered with square pixels (``w x h``, focal
``w H / footprint_E``) and resized to ``S x S`` with INTER_AREA. OpenCV's resize maps a
destination pixel centre ``x`` to the source position ``(x + 0.5) w / S - 0.5``; composing that
with the pinhole gives an affine map with anisotropic ground sampling (metres per pixel
``footprint_E / S`` across, ``footprint_N / S`` down; 20.8 x 10.4 m at 96 px for 2 x 1 km)::

    E = E_sat + (x - (S - 1) / 2) footprint_E / S,    N = N_sat - (y - (S - 1) / 2) footprint_N / S

independent of the render size ``w x h``. Metres and radians throughout.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from benchmark.sim import Camera

__all__ = ["GroundCast", "SatelliteGrid", "cast_uav_pixels", "rotate_offsets"]


@dataclass(frozen=True)
class SatelliteGrid:
    """Where a ``size x size`` satellite image lies on the ground plane.

    ``centre_en``: ``(E, N)`` of the capture point (the image centre), metres; ``ground_u``: the
    plane's height ``z_g`` (the terrain at the centre), metres; ``footprint_m``: ``(E, N)`` extent,
    metres; ``size``: pixels per side.
    """

    centre_en: tuple[float, float]
    ground_u: float
    footprint_m: tuple[float, float]
    size: int

    def __post_init__(self) -> None:
        fe, fn = self.footprint_m
        if not (math.isfinite(fe) and math.isfinite(fn) and fe > 0 and fn > 0):
            raise ValueError(f"SatelliteGrid.footprint_m must be two positive sizes, got {fe, fn}")
        if not (isinstance(self.size, (int, np.integer)) and self.size >= 2):
            raise ValueError(f"SatelliteGrid.size must be an integer >= 2, got {self.size!r}")
        vals = (*self.centre_en, self.ground_u)
        if not all(math.isfinite(float(x)) for x in vals):
            raise ValueError(f"SatelliteGrid.centre_en/ground_u must be finite, got {vals}")

    @property
    def metres_per_px(self) -> tuple[float, float]:
        """Ground sampling ``(E per column, N per row)``, metres (anisotropic for 2:1)."""
        return (self.footprint_m[0] / self.size, self.footprint_m[1] / self.size)

    def enu_to_pixel(self, east: np.ndarray, north: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ground points (absolute E, N, metres, any shape) -> continuous ``(x, y)`` pixels."""
        sx, sy = self.metres_per_px
        c = 0.5 * (self.size - 1)
        return (c + (east - self.centre_en[0]) / sx, c - (north - self.centre_en[1]) / sy)

    def offset_to_pixel(self, de: np.ndarray, dn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Offsets from the capture point ``(dE, dN)`` metres -> continuous ``(x, y)`` pixels."""
        sx, sy = self.metres_per_px
        c = 0.5 * (self.size - 1)
        return (c + de / sx, c - dn / sy)

    def pixel_to_enu(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Lift pixels ``(x, y)`` (any equal shapes) to ground points ``(..., 3)`` absolute ENU."""
        sx, sy = self.metres_per_px
        c = 0.5 * (self.size - 1)
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        east = self.centre_en[0] + (x - c) * sx
        north = self.centre_en[1] - (y - c) * sy
        return np.stack([east, north, np.full_like(east, self.ground_u)], axis=-1)


@dataclass(frozen=True)
class GroundCast:
    """UAV pixels cast onto the ground plane at yaw 0.

    ``rows``, ``cols``: ``(P,)`` int indices of the pixels whose ray hits the plane within
    ``[min_range_m, max_range_m]`` horizontally; ``offsets``: ``(P, 2)`` float64 horizontal hit
    offsets ``(dE, dN)`` from the UAV, metres, for yaw 0 (rotate with :func:`rotate_offsets`);
    ``ranges``: ``(P,)`` horizontal distances, metres.
    """

    rows: np.ndarray
    cols: np.ndarray
    offsets: np.ndarray
    ranges: np.ndarray


def cast_uav_pixels(
    camera: Camera,
    pitch: float,
    roll: float,
    height_above_ground_m: float,
    *,
    max_range_m: float = math.inf,
    min_range_m: float = 0.0,
) -> GroundCast:
    """Cast every pixel centre of ``camera`` onto the ground plane ``height_above_ground_m`` below
    the UAV, with the UAV at yaw 0 (north) and the given ``pitch``, ``roll`` (radians).

    A pixel is kept when its ray points downwards and meets the plane at a horizontal distance in
    ``[min_range_m, max_range_m]``. Raises ValueError for a UAV at or below the plane.
    """
    h = float(height_above_ground_m)
    if not (math.isfinite(h) and h > 0):
        raise ValueError(f"height_above_ground_m must be a positive number of metres, got {h!r}")
    for name, value in (("pitch", pitch), ("roll", roll)):
        if not math.isfinite(float(value)):
            raise ValueError(f"{name} must be finite (radians), got {value!r}")
    f = camera.focal_px
    cx, cy = camera.principal_point
    rows, cols = np.mgrid[0 : camera.height, 0 : camera.width]
    rows, cols = rows.ravel(), cols.ravel()
    d_body = np.stack(
        [(cols - cx) / f, np.ones(cols.shape), -(rows - cy) / f], axis=1
    )  # (HW, 3), body frame
    cp, sp = math.cos(pitch), math.sin(pitch)
    cr, sr = math.cos(roll), math.sin(roll)
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, cp, -sp], [0.0, sp, cp]])
    Ry = np.array([[cr, 0.0, sr], [0.0, 1.0, 0.0], [-sr, 0.0, cr]])
    d_n = d_body @ (Rx @ Ry).T  # yaw 0: R_b^n = Rx(pitch) Ry(roll)
    down = d_n[:, 2] < -1e-9
    t = np.where(down, h / np.where(down, -d_n[:, 2], 1.0), np.inf)
    offsets = d_n[:, :2] * t[:, None]
    with np.errstate(invalid="ignore"):
        ranges = np.hypot(offsets[:, 0], offsets[:, 1])
        keep = down & (ranges <= max_range_m) & (ranges >= min_range_m)
    return GroundCast(rows[keep], cols[keep], offsets[keep], ranges[keep])


def rotate_offsets(offsets: np.ndarray, yaws: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Yaw-0 ground offsets ``(P, 2)`` turned by each of ``yaws`` ``(K,)`` radians (counter-
    clockwise from above, DEVELOPERS.md): ``(dE (K, P), dN (K, P))`` metres."""
    c, s = np.cos(yaws)[:, None], np.sin(yaws)[:, None]
    e, n = offsets[None, :, 0], offsets[None, :, 1]
    return c * e - s * n, s * e + c * n
