"""UAV and satellite views of a ``City``: ``render_uav``, ``render_satellite``, ``satellite_pose``.

Both are the same per-pixel ray caster (render_core.py) with the pinhole model of camera.py: the UAV
camera looks along body +y with ``R_b^n = Rz(yaw) Rx(pitch) Ry(roll)``; the satellite camera is the
paper's (Eq. 5): pitch -90 deg, heading 0, so it looks straight down with north at the top of the
image, placed ``height_m`` above the terrain at the centre. Its image covers ``footprint_m`` (E x N)
at the centre's terrain height with square pixels (so a 2 km x 1 km footprint is a 2:1 image), is
rendered at about 4x the output resolution (never finer than the texture) and then squashed to
``size x size`` with ``cv2.INTER_AREA``, as the paper resizes its 2 km x 1 km images to 224 x 224.
Buildings lean away from the nadir point by the true perspective relief displacement
``r h / (H - h)``.

Illumination: a city has ``city.n_lights`` illumination states; ``light=k`` renders with state k's
baked ortho texture (its shading and shadows) and its sun for the facades' Lambert term, so the UAV
frames of a flight and the satellite image of its centre can be lit at independent times of day.
``visibility_m`` is the UAV view's fog distance V (``c = c e^{-t/V} + haze (1 - e^{-t/V})``),
``VISIBILITY_M`` by default; the satellite image has no haze.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from benchmark.sim import render_core as rc
from benchmark.sim.camera import Camera, check_pose, euler_to_rotmat_np
from benchmark.sim.world import City

HAZE = (206.0, 214.0, 222.0)
ZENITH = (96.0, 140.0, 200.0)
VISIBILITY_M = 2600.0


def _check_visibility(visibility_m: float | None) -> float:
    if visibility_m is None:
        return VISIBILITY_M
    ok = isinstance(visibility_m, (int, float, np.integer, np.floating))
    if not (ok and not isinstance(visibility_m, bool) and math.isfinite(visibility_m)):
        raise ValueError(f"visibility_m must be a finite number of metres, got {visibility_m!r}")
    if not 10.0 <= visibility_m <= 1e6:
        raise ValueError(f"visibility_m must be in [10, 1e6] metres, got {visibility_m!r}")
    return float(visibility_m)


def _params(city: City, light: int, visibility_m: float | None) -> np.ndarray:
    """Kernel parameters for illumination state ``light``; ``visibility_m`` None: no fog."""
    fog = visibility_m is not None
    p = np.zeros(rc.N_PARAMS)
    e0, n0 = city.origin
    p[rc.P_MPP] = city.metres_per_px
    p[rc.P_E0] = e0
    p[rc.P_N0] = n0
    p[rc.P_GMAX] = city.height_range[1] + 0.01
    p[rc.P_SUN : rc.P_SUN + 3] = city.light_suns[light]
    p[rc.P_AMB] = 0.55
    p[rc.P_DIF] = 0.6
    p[rc.P_HAZE : rc.P_HAZE + 3] = HAZE
    p[rc.P_VIS] = visibility_m if fog else 0.0
    p[rc.P_ZENITH : rc.P_ZENITH + 3] = ZENITH
    p[rc.P_TMAX] = 5.0 * visibility_m if fog else 1e5  # beyond 5 V the haze is 99.3 % opaque
    p[rc.P_GSCALE] = 4.0
    p[rc.P_GMIN] = city.height_range[0]
    return p


def _render(
    city: City,
    pos: np.ndarray,
    R: np.ndarray,
    f: float,
    cx: float,
    cy: float,
    width: int,
    height: int,
    ss: int,
    light: int,
    visibility_m: float | None,
) -> np.ndarray:
    out = np.empty((height, width, 3), np.uint8)
    world = (
        city.hpyr,
        city.hoff,
        city.hdims,
        city.tex[light],
        city.toff,
        city.tdims,
        city.mat,
        city.orient,
        city.ground,
        city.palette,
        _params(city, light, visibility_m),
    )
    rc.render_image(
        out, np.ascontiguousarray(R), pos, float(f), float(cx), float(cy), int(ss), world
    )
    return out


def render_uav(
    city: City,
    position_enu: np.ndarray,
    yaw: float,
    pitch: float,
    roll: float,
    camera: Camera,
    *,
    supersample: int = 1,
    light: int = 0,
    visibility_m: float | None = None,
) -> np.ndarray:
    """The forward-looking UAV view, ``(camera.height, camera.width, 3)`` uint8.

    Args:
        position_enu: ``(3,)`` camera centre, metres (absolute ENU height, not above ground).
        yaw, pitch, roll: radians (DEVELOPERS.md conventions).
        supersample: rays per pixel per axis (box filtered); textures are mip-mapped anyway, so
            1 is fine for training data, 2 removes the residual edge aliasing.
        light: illumination state in ``[0, city.n_lights)`` (baked texture and facade sun).
        visibility_m: fog distance V, metres, in [10, 1e6]; None: ``VISIBILITY_M`` (2600 m).

    Raises ValueError for a non-finite pose, a camera inside the geometry (below the surface of
    the texel it is in), a bad ``light`` or a bad ``visibility_m``.
    """
    pos = check_pose(position_enu, yaw, pitch, roll)
    if not isinstance(camera, Camera):
        raise TypeError(f"camera must be a benchmark.sim.Camera, got {type(camera).__name__}")
    if not isinstance(city, City):
        raise TypeError(f"city must be a benchmark.sim.City, got {type(city).__name__}")
    if not (isinstance(supersample, (int, np.integer)) and 1 <= supersample <= 8):
        raise ValueError(f"supersample must be an integer in [1, 8], got {supersample!r}")
    light = city.check_light(light)
    vis = _check_visibility(visibility_m)
    surf = float(city.surface_height(pos[0], pos[1]))
    if pos[2] <= surf + 0.5:
        raise ValueError(
            f"camera at {pos.tolist()} is inside the geometry: the surface there is {surf:.1f} m"
        )
    R = euler_to_rotmat_np(float(yaw), float(pitch), float(roll))
    cx, cy = camera.principal_point
    w, h = camera.width, camera.height
    return _render(city, pos, R, camera.focal_px, cx, cy, w, h, supersample, light, vis)


def satellite_pose(
    city: City, centre_en: np.ndarray, *, height_m: float = 1000.0
) -> tuple[np.ndarray, tuple[float, float, float]]:
    """Position ``(3,)`` ENU metres and ``(yaw, pitch, roll)`` radians of the satellite camera.

    The camera is ``height_m`` above the terrain at ``centre_en``, heading 0, pitch -90 deg, roll 0
    (paper Eq. 5: ``Q_sat^n = [-0.7071, 0.7071, 0, 0]`` up to sign).
    """
    c = np.asarray(centre_en, np.float64)
    if c.shape != (2,) or not np.all(np.isfinite(c)):
        raise ValueError(f"centre_en must be a finite (2,) array (E, N), got {centre_en!r}")
    if not (math.isfinite(height_m) and height_m > 50.0):
        raise ValueError(f"height_m must be > 50 m, got {height_m!r}")
    g = float(city.ground_height(c[0], c[1]))
    return np.array([c[0], c[1], g + height_m]), (0.0, -math.pi / 2, 0.0)


def satellite_camera(
    footprint_m: tuple[float, float], height_m: float, gsd_m: float
) -> tuple[int, int, float]:
    """Render size ``(width, height)`` and focal length (pixels) of a nadir camera whose square
    pixels cover ``gsd_m`` metres at ``height_m`` and whose image covers ``footprint_m``."""
    w = max(2, round(footprint_m[0] / gsd_m))
    h = max(2, round(footprint_m[1] / gsd_m))
    f = w * height_m / footprint_m[0]  # the outer pixel edges see the footprint's edges
    return w, h, f


def render_satellite(
    city: City,
    centre_en: np.ndarray,
    *,
    height_m: float = 1000.0,
    footprint_m: tuple[float, float] = (2000.0, 1000.0),
    size: int = 224,
    oversample: float = 4.0,
    light: int = 0,
) -> np.ndarray:
    """The north-up nadir satellite image around ``centre_en``, ``(size, size, 3)`` uint8.

    Rendered with square pixels of ground sampling distance
    ``max(metres_per_px, footprint_E / (oversample * size))`` at the centre's terrain height, then
    resized (anisotropically for a non-square footprint) to ``size x size`` with INTER_AREA.
    No haze. ``light``: illumination state in ``[0, city.n_lights)`` (ValueError otherwise).
    """
    light = city.check_light(light)
    if not (isinstance(size, (int, np.integer)) and size >= 8):
        raise ValueError(f"size must be an integer >= 8, got {size!r}")
    fe, fn = (float(footprint_m[0]), float(footprint_m[1]))
    if not (fe > 0 and fn > 0 and math.isfinite(fe) and math.isfinite(fn)):
        raise ValueError(f"footprint_m must be two positive sizes (E, N), got {footprint_m!r}")
    pos, (yaw, pitch, roll) = satellite_pose(city, centre_en, height_m=height_m)
    gsd = max(city.metres_per_px, fe / (oversample * size))
    w, h, f = satellite_camera((fe, fn), height_m, gsd)
    R = euler_to_rotmat_np(yaw, pitch, roll)
    img = _render(city, pos, R, f, 0.5 * (w - 1), 0.5 * (h - 1), w, h, 1, light, None)
    if (w, h) == (size, size):
        return img
    return cv2.resize(img, (size, size), interpolation=cv2.INTER_AREA)
