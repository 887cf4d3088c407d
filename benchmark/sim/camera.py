"""Pinhole camera model shared by the UAV renderer, the satellite renderer and the tests.

Conventions (DEVELOPERS.md): navigation frame ENU; body frame x right, y forward, z up; the camera
looks along body +y; ``R_b^n = Rz(yaw) Rx(pitch) Ry(roll)`` (paper Eq. 1) maps body vectors to ENU.

Pixel coordinates are continuous ``(u, v)`` with u to the right (body +x) and v downwards (body -z).
The centre of pixel ``image[i, j]`` (row i, column j) is at ``(u, v) = (j, i)``, so the principal
point of a ``W x H`` image is ``(cx, cy) = ((W - 1) / 2, (H - 1) / 2)`` and rounding a projected
``(u, v)`` gives the column and row index directly. A body-frame point ``p = (x, y, z)`` with
``y > 0`` lands at ``u = cx + f x / y``, ``v = cy - f z / y``, where ``f = (W / 2) / tan(fov / 2)``
for the horizontal field of view ``fov``: the outer edges of the outer pixels (``u = -0.5`` and
``u = W - 0.5``) are exactly at ``+-fov / 2``. Pixels are square (one focal length for u and v).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from benchmark.sim import detmath

__all__ = ["Camera", "euler_to_rotmat_np", "project_enu_to_pixel"]


@dataclass(frozen=True)
class Camera:
    """A pinhole camera: image size in pixels and the horizontal field of view in degrees.

    ``fov_deg`` is horizontal (across ``width``); the vertical field of view follows from the square
    pixels: ``2 atan(tan(fov / 2) * height / width)``.
    """

    width: int
    height: int
    fov_deg: float

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"Camera.{name} must be a positive integer, got {value!r}")
        if not (math.isfinite(self.fov_deg) and 0.0 < self.fov_deg < 179.0):
            raise ValueError(f"Camera.fov_deg must be in (0, 179) degrees, got {self.fov_deg!r}")

    @classmethod
    def square(cls, size: int, fov_deg: float = 60.0) -> Camera:
        """A ``size x size`` camera (the dataset's images are square)."""
        return cls(size, size, fov_deg)

    @property
    def focal_px(self) -> float:
        """Focal length in pixels, ``f = (W / 2) / tan(fov / 2)``."""
        return 0.5 * self.width / math.tan(math.radians(self.fov_deg) / 2.0)

    @property
    def principal_point(self) -> tuple[float, float]:
        """``(cx, cy) = ((W - 1) / 2, (H - 1) / 2)``: pixel centres sit on integer coordinates."""
        return (0.5 * (self.width - 1), 0.5 * (self.height - 1))

    def intrinsics(self) -> np.ndarray:
        """The ``(3, 3)`` matrix K mapping camera-frame ``(x, -z, y)`` to homogeneous pixels."""
        cx, cy = self.principal_point
        f = self.focal_px
        return np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])


def euler_to_rotmat_np(yaw: Any, pitch: Any, roll: Any) -> np.ndarray:
    """``R_b^n = Rz(yaw) Rx(pitch) Ry(roll)`` as float64 numpy (paper Eq. 1).

    ``yaw, pitch, roll``: radians, scalars or arrays broadcast against each other; returns
    ``(..., 3, 3)`` (``(3, 3)`` for scalars). A numpy twin of ``benchmark.geometry.euler_to_rotmat``
    for the renderer, which must not pay for torch per frame; the tests check the two agree.
    ISA-independent (``detmath``: libm cos/sin and the two products in a fixed order, not BLAS),
    so the dataset's labels (``splits.relative_labels``) hold exactly the rotation the renderer
    used, on every CPU.
    """
    yaw, pitch, roll = np.broadcast_arrays(*(np.asarray(a, np.float64) for a in (yaw, pitch, roll)))
    cz, sz = detmath.cos(yaw), detmath.sin(yaw)
    cx, sx = detmath.cos(pitch), detmath.sin(pitch)
    cy, sy = detmath.cos(roll), detmath.sin(roll)
    zero, one = np.zeros_like(cz), np.ones_like(cz)

    def mat(rows: list[list[np.ndarray]]) -> np.ndarray:
        return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)

    Rz = mat([[cz, -sz, zero], [sz, cz, zero], [zero, zero, one]])
    Rx = mat([[one, zero, zero], [zero, cx, -sx], [zero, sx, cx]])
    Ry = mat([[cy, zero, sy], [zero, one, zero], [-sy, zero, cy]])
    return detmath.matmul(detmath.matmul(Rz, Rx), Ry)


def check_pose(position_enu: np.ndarray, yaw: float, pitch: float, roll: float) -> np.ndarray:
    """Validate a pose; return the position as a float64 ``(3,)`` array. Raises ValueError."""
    pos = np.asarray(position_enu, dtype=np.float64)
    if pos.shape != (3,):
        raise ValueError(f"position_enu must have shape (3,), got {pos.shape}")
    if not np.all(np.isfinite(pos)):
        raise ValueError(f"position_enu must be finite, got {pos.tolist()}")
    for name, value in (("yaw", yaw), ("pitch", pitch), ("roll", roll)):
        if not math.isfinite(float(value)):
            raise ValueError(f"{name} must be finite (radians), got {value!r}")
    return pos


def project_enu_to_pixel(
    points_enu: np.ndarray,
    position_enu: np.ndarray,
    yaw: float,
    pitch: float,
    roll: float,
    camera: Camera,
) -> tuple[np.ndarray, np.ndarray]:
    """Project ENU points into the camera: the same pinhole model the renderer uses.

    Args:
        points_enu: ``(N, 3)`` world points, metres, ENU.
        position_enu: ``(3,)`` camera centre, metres, ENU.
        yaw, pitch, roll: radians, ``R_b^n = Rz(yaw) Rx(pitch) Ry(roll)``.
        camera: the intrinsics.

    Returns:
        ``uv``: ``(N, 2)`` float64 pixel coordinates ``(u, v)`` (pixel centres on integers, see the
        module docstring); ``in_front``: ``(N,)`` bool, True where the point is in front of the
        camera (body ``y > 0``). ``uv`` is NaN where ``in_front`` is False.
    """
    pos = check_pose(position_enu, yaw, pitch, roll)
    pts = np.asarray(points_enu, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points_enu must have shape (N, 3), got {pts.shape}")
    R = euler_to_rotmat_np(float(yaw), float(pitch), float(roll))
    body = detmath.matmul(pts - pos, R)  # rows: R^T (p - c), i.e. ENU -> body
    x, y, z = body[:, 0], body[:, 1], body[:, 2]
    in_front = y > 1e-9
    f = camera.focal_px
    cx, cy = camera.principal_point
    safe_y = np.where(in_front, y, 1.0)
    uv = np.stack([cx + f * x / safe_y, cy - f * z / safe_y], axis=1)
    uv[~in_front] = np.nan
    return uv, in_front
