"""Camera and ground-plane maths of the matching encoder, in torch (batched, differentiable).

The same pinhole model as ``benchmark.sim.camera`` (the truth; models must not import the
simulator, so the tests check these functions against ``project_enu_to_pixel``):

- UAV camera: body x right, y forward (the optical axis), z up; ``R_b^n = Rz(yaw) Rx(pitch)
  Ry(roll)``; a body point ``(x, y, z)`` with ``y > 0`` lands at ``u = cx + f x / y``,
  ``v = cy - f z / y`` with ``f = (W / 2) / tan(fov / 2)`` and ``(cx, cy) = ((W - 1) / 2,
  (H - 1) / 2)`` (pixel centres on integers).
- Satellite image (``benchmark.sim.render.render_satellite``): nadir, north up, covering the
  footprint ``(F_E, F_N)`` metres at the terrain height of its centre, squashed to ``S x S`` px,
  so the ground point ``(dE, dN)`` metres from the centre is at ``u = (dE / F_E + 1/2) S - 1/2``,
  ``v = (1/2 - dN / F_N) S - 1/2`` (the footprint's edges are the outer pixels' edges).

Ground offsets are expressed in two horizontal frames: ENU ``(dE, dN)`` and the UAV's *level*
frame ``(a, b)``, ENU turned by the UAV's yaw (``a`` to the right of the heading, ``b`` along
it): ``(dE, dN) = Rz(yaw) (a, b)``. The ground is the plane ``altitude`` metres below the camera
(the terrain height of the satellite image's centre; buildings and terrain relief are not
modelled).

Feature maps: a map of stride ``s`` made by ``s x s`` average pooling (after any number of
stride-1, centred convolutions) has its cell ``j`` centred on pixel ``s j + (s - 1) / 2``;
:func:`pixel_to_grid` turns pixel coordinates into ``grid_sample`` coordinates
(``align_corners=True``) of such a map.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from benchmark.geometry import euler_to_rotmat

__all__ = [
    "focal_px",
    "ground_to_uav_pixel",
    "offset_grid",
    "pixel_to_grid",
    "rotate_to_level",
    "sat_pixel_of_offset",
]

# A ground point must be at least this far in front of the camera (metres along the optical
# axis) to be projected; nearer ones (and those behind) are masked. 1 m is far below the nearest
# visible ground at the benchmark's 70-120 m altitudes.
MIN_DEPTH_M = 1.0


def focal_px(width: int, fov: Tensor) -> Tensor:
    """``f = (W / 2) / tan(fov / 2)`` px for the horizontal field of view ``fov`` (rad)."""
    return 0.5 * width / torch.tan(0.5 * fov)


def rotate_to_level(offsets_en: Tensor, yaw: Tensor) -> Tensor:
    """ENU ground offsets ``(..., 2)`` (dE, dN) -> the level frame ``(a, b)`` of heading ``yaw``.

    ``(a, b) = Rz(-yaw) (dE, dN)``; ``yaw`` broadcasts against ``offsets_en[..., 0]`` (rad).
    """
    c, s = torch.cos(yaw), torch.sin(yaw)
    de, dn = offsets_en[..., 0], offsets_en[..., 1]
    return torch.stack([c * de + s * dn, -s * de + c * dn], dim=-1)


def ground_to_uav_pixel(
    offsets_level: Tensor,
    pitch: Tensor,
    roll: Tensor,
    altitude: Tensor,
    fov: Tensor,
    size: int,
) -> tuple[Tensor, Tensor]:
    """Project ground points given in the UAV's level frame into its ``size x size`` image.

    Args:
        offsets_level: ``(B, ..., 2)`` ground offsets ``(a, b)`` metres from the point below the
            camera (a right of the heading, b along it).
        pitch, roll: ``(B,)`` rad (``R_b^n = Rz(yaw) Rx(pitch) Ry(roll)``; yaw is in the frame).
        altitude: ``(B,)`` metres, camera height above the ground plane.
        fov: ``(B,)`` horizontal field of view, rad.
        size: image side, px.

    Returns:
        ``uv (B, ..., 2)`` pixel coordinates (pixel centres on integers) and ``valid (B, ...)``:
        in front of the camera by at least :data:`MIN_DEPTH_M` and inside the image (within the
        outer pixels' edges). ``uv`` is finite everywhere (invalid points get a clamped depth).
    """
    if offsets_level.shape[-1] != 2:
        raise ValueError(f"offsets_level must end in 2 (a, b), got {tuple(offsets_level.shape)}")
    batch = offsets_level.shape[0]
    for name, t in (("pitch", pitch), ("roll", roll), ("altitude", altitude), ("fov", fov)):
        if t.shape != (batch,):
            raise ValueError(f"{name} must have shape ({batch},), got {tuple(t.shape)}")
    R = euler_to_rotmat(torch.zeros_like(pitch), pitch, roll)  # (B, 3, 3) body -> level frame
    extra = offsets_level.dim() - 2
    h = altitude.view(batch, *([1] * extra)).expand(offsets_level.shape[:-1])
    p = torch.stack([offsets_level[..., 0], offsets_level[..., 1], -h], dim=-1)  # level frame
    # R^T p for every point, as the row vectors p^T R: one (B, points, 3) @ (B, 3, 3) product
    # (broadcasting R over the points would copy a 3 x 3 matrix per point)
    body = (p.reshape(batch, -1, 3) @ R).view_as(p)
    x, y, z = body.unbind(-1)
    f = focal_px(size, fov).view(batch, *([1] * extra))
    c = 0.5 * (size - 1)
    depth = y.clamp(min=MIN_DEPTH_M)
    uv = torch.stack([c + f * x / depth, c - f * z / depth], dim=-1)
    edge = size - 0.5
    inside = (
        (uv[..., 0] >= -0.5) & (uv[..., 0] <= edge) & (uv[..., 1] >= -0.5) & (uv[..., 1] <= edge)
    )
    return uv, (y >= MIN_DEPTH_M) & inside


def sat_pixel_of_offset(offsets_en: Tensor, footprint_m: Tensor, size: int) -> Tensor:
    """Satellite-image pixel ``(u, v)`` of ENU ground offsets from the image centre.

    ``offsets_en (B, ..., 2)`` metres (dE, dN); ``footprint_m (B, 2)`` (F_E, F_N) metres; returns
    ``(B, ..., 2)`` with ``u = (dE / F_E + 1/2) S - 1/2``, ``v = (1/2 - dN / F_N) S - 1/2``.
    """
    batch = offsets_en.shape[0]
    if footprint_m.shape != (batch, 2):
        raise ValueError(
            f"footprint_m must have shape ({batch}, 2), got {tuple(footprint_m.shape)}"
        )
    fp = footprint_m.view(batch, *([1] * (offsets_en.dim() - 2)), 2)
    u = (offsets_en[..., 0] / fp[..., 0] + 0.5) * size - 0.5
    v = (0.5 - offsets_en[..., 1] / fp[..., 1]) * size - 0.5
    return torch.stack([u, v], dim=-1)


def pixel_to_grid(uv: Tensor, size: int, stride: tuple[int, int] = (1, 1)) -> Tensor:
    """``grid_sample`` coordinates (``align_corners=True``) of pixel ``uv (..., 2)`` in the
    feature map of a ``size x size`` image pooled by ``stride = (s_x, s_y)``."""
    out = []
    for k, s in enumerate(stride):
        n = size // s  # cells of the pooled map along this axis
        j = (uv[..., k] - 0.5 * (s - 1)) / s
        out.append(2.0 * j / max(n - 1, 1) - 1.0)
    return torch.stack(out, dim=-1)


def offset_grid(radius: int, cell_m: float, *, dtype: torch.dtype = torch.float32) -> Tensor:
    """``(2 r + 1, 2 r + 1, 2)`` ENU offsets (dE, dN) metres of a square grid of cells centred on
    0: row ``i`` (north first) has ``dN = (r - i) cell``, column ``j`` has ``dE = (j - r) cell``."""
    if radius < 0 or not math.isfinite(cell_m) or cell_m <= 0:
        raise ValueError(f"offset_grid: need radius >= 0 and cell_m > 0, got {radius}, {cell_m}")
    k = torch.arange(-radius, radius + 1, dtype=dtype) * cell_m
    dn, de = torch.meshgrid(-k, k, indexing="ij")
    return torch.stack([de, dn], dim=-1)
