"""The matching encoder's differentiable operators: the bird's-eye templates of the UAV view at
every yaw, the satellite features on the same metric grid, and their exhaustive correlation.

Shapes: ``B`` pairs, ``C`` feature channels, ``K`` yaw candidates, templates ``t x t`` cells
(``t = 2 r + 1``), satellite grid ``G x G`` cells (``G = 2 (n + r) + 1`` for ``2 n + 1``
candidate positions per axis). Metres and radians throughout.
"""

from __future__ import annotations

import torch
import torch.nn.functional as nnf
from torch import Tensor

from benchmark.models.matching_geometry import (
    ground_to_uav_pixel,
    offset_grid,
    pixel_to_grid,
    rotate_to_level,
    sat_pixel_of_offset,
)

__all__ = [
    "bev_templates",
    "correlate",
    "correlate_conv",
    "correlate_fft",
    "fft_size",
    "sat_grid",
]


def bev_templates(
    uav_features: Tensor,
    stride: tuple[int, int],
    size: int,
    yaws: Tensor,
    radius: int,
    cell_m: float,
    pitch: Tensor,
    roll: Tensor,
    altitude: Tensor,
    fov: Tensor,
) -> tuple[Tensor, Tensor]:
    """North-up bird's-eye templates of the UAV features, one per candidate yaw.

    Each template cell is an ENU offset ``(dE, dN)`` from the point below the UAV (rows north
    first, :func:`~benchmark.models.matching_geometry.offset_grid`). For yaw ``psi`` the cell is
    turned into the level frame, projected into the UAV image with the camera model and sampled
    (bilinear) from ``uav_features (B, C, h, w)`` of stride ``stride``: one interpolation per
    cell, no image rotation. Cells outside the image, behind the camera or farther than
    ``radius`` cells (a disc, so every yaw sees the same support) are masked.

    Returns ``templates (B, K, C, t, t)`` (zero where masked) and ``mask (B, K, t, t)`` bool.
    """
    b, c = uav_features.shape[:2]
    k = yaws.shape[0]
    grid = offset_grid(radius, cell_m, dtype=uav_features.dtype).to(uav_features.device)
    t = grid.shape[0]
    level = rotate_to_level(grid.unsqueeze(0), yaws.view(k, 1, 1))  # (K, t, t, 2)
    level = level.unsqueeze(0).expand(b, k, t, t, 2)
    uv, valid = ground_to_uav_pixel(level, pitch, roll, altitude, fov, size)
    disc = grid.square().sum(-1) <= (radius * cell_m) ** 2 + 1e-6  # (t, t)
    mask = valid & disc
    coords = pixel_to_grid(uv, size, stride).reshape(b, k * t, t, 2)
    sampled = nnf.grid_sample(
        uav_features, coords, mode="bilinear", padding_mode="zeros", align_corners=True
    )  # (B, C, K t, t)
    templates = sampled.view(b, c, k, t, t).permute(0, 2, 1, 3, 4)
    return templates * mask.unsqueeze(2).to(templates.dtype), mask


def sat_grid(
    sat_features: Tensor,
    stride: tuple[int, int],
    size: int,
    footprint_m: Tensor,
    radius: int,
    cell_m: float,
) -> Tensor:
    """Satellite features resampled to the metric grid ``(B, C, G, G)``, ``G = 2 radius + 1``,
    centred on the image centre, north up (zero outside the footprint). ``sat_features (B, C,
    h, w)`` (one per pair), ``footprint_m (B, 2)`` (E, N) metres."""
    b = sat_features.shape[0]
    grid = offset_grid(radius, cell_m, dtype=sat_features.dtype).to(sat_features.device)
    uv = sat_pixel_of_offset(grid.unsqueeze(0).expand(b, *grid.shape), footprint_m, size)
    coords = pixel_to_grid(uv, size, stride)
    return nnf.grid_sample(
        sat_features, coords, mode="bilinear", padding_mode="zeros", align_corners=True
    )


def correlate_conv(sat: Tensor, templates: Tensor) -> Tensor:
    """``out[b, k, y, x] = sum_{c, i, j} templates[b, k, c, i, j] sat[b, c, y + i, x + j]``:
    every template placed at every position where it fits (``(B, K, G - t + 1, G - t + 1)``),
    as one grouped ``conv2d`` (groups = B)."""
    b, k, c, t, _ = templates.shape
    g = sat.shape[-1]
    out = nnf.conv2d(sat.reshape(1, b * c, g, g), templates.reshape(b * k, c, t, t), groups=b)
    return out.view(b, k, g - t + 1, g - t + 1)


def fft_size(n: int) -> int:
    """The smallest ``m >= n`` whose prime factors are 2, 3 and 5 (pocketfft is fast there; a
    prime size such as 71 takes Bluestein's algorithm, about 10x slower here)."""
    m = max(1, n)
    while True:
        k = m
        for p in (2, 3, 5):
            while k % p == 0:
                k //= p
        if k == 1:
            return m
        m += 1


def correlate_fft(sat: Tensor, templates: Tensor) -> Tensor:
    """:func:`correlate_conv` by the FFT: ``conj(F(template)) F(sat)`` summed over channels is the
    circular cross-correlation; with an FFT size ``L >= G`` the kept outputs ``y, x <= G - t``
    read ``y + i <= G - 1 < L``, so nothing wraps around. Computed in float32 at least."""
    t = templates.shape[-1]
    g = sat.shape[-1]
    n = fft_size(g)
    dtype = torch.promote_types(sat.dtype, torch.float32)
    # Channels first, so that each channel's spectra are contiguous blocks.
    fs = torch.fft.rfft2(sat.to(dtype).transpose(0, 1), s=(n, n))  # (C, B, L, L//2+1)
    ft = torch.fft.rfft2(templates.to(dtype).permute(2, 0, 1, 3, 4), s=(n, n)).conj()
    # Sum over channels one at a time: a batched matmul over every frequency would run
    # B L (L/2 + 1) tiny (K x C) @ (C x 1) products, and the full broadcast product would hold
    # B K C L (L/2 + 1) complex numbers.
    # (unbind, not indexing: the backward of C selects would zero-fill C full-size gradients).
    ft_c, fs_c = ft.unbind(0), fs.unsqueeze(2).unbind(0)  # (B, K, L, L//2+1), (B, 1, ...)
    prod = ft_c[0] * fs_c[0]
    for a, b in zip(ft_c[1:], fs_c[1:], strict=True):
        prod = prod + a * b
    out = torch.fft.irfft2(prod, s=(n, n))
    m = g - t + 1
    return out[..., :m, :m].to(sat.dtype)


def correlate(sat: Tensor, templates: Tensor, method: str = "fft") -> Tensor:
    """:func:`correlate_fft` (``method="fft"``) or :func:`correlate_conv` (``"conv"``)."""
    if sat.dim() != 4 or templates.dim() != 5 or sat.shape[-1] != sat.shape[-2]:
        raise ValueError(
            f"correlate: sat must be (B, C, G, G) and templates (B, K, C, t, t), got "
            f"{tuple(sat.shape)} and {tuple(templates.shape)}"
        )
    if templates.shape[-1] > sat.shape[-1]:
        raise ValueError(
            f"correlate: templates ({templates.shape[-1]} cells) larger than the grid "
            f"({sat.shape[-1]})"
        )
    if method == "fft":
        return correlate_fft(sat, templates)
    if method == "conv":
        return correlate_conv(sat, templates)
    raise ValueError(f"correlate: method must be 'fft' or 'conv', got {method!r}")
