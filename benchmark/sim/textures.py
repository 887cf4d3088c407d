"""Procedural noise, hashing, sun shading/shadow baking and mip pyramids for the city generator.

All functions are deterministic: noise comes from ``numpy.random.Generator`` streams seeded by the
caller, hashes are pure integer arithmetic (no Python ``hash``), and the numba kernels are serial.
Arrays are indexed ``[j, i]`` with j along north (row 0 = southern edge), i along east.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from scipy.ndimage import uniform_filter

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)


def hash01(*keys: np.ndarray | int) -> np.ndarray:
    """Uniform [0, 1) float64 from integer keys (broadcast), splitmix64 finaliser per key.

    Used to give every block, parcel, car slot, ... its own reproducible random numbers without
    drawing from a sequential stream (so one changed parcel does not reshuffle all the others).
    """
    h = np.zeros(np.broadcast(*[np.asarray(k) for k in keys]).shape, dtype=np.uint64)
    with np.errstate(over="ignore"):
        for k in keys:
            k64 = np.asarray(k).astype(np.int64).astype(np.uint64)
            h = (h ^ k64) + _GOLDEN
            h = (h ^ (h >> np.uint64(30))) * _MIX1
            h = (h ^ (h >> np.uint64(27))) * _MIX2
            h = h ^ (h >> np.uint64(31))
    return (h >> np.uint64(11)).astype(np.float64) * (1.0 / 9007199254740992.0)


def smooth_noise(rng: np.random.Generator, shape: tuple[int, int], cell_px: float) -> np.ndarray:
    """Value noise in about [-1, 1], float32 ``shape``: a random lattice every ``cell_px`` texels,
    interpolated with Catmull-Rom bicubics (a serial numba loop: deterministic, and no OpenCV
    thread pool is started in a process that may fork workers afterwards)."""
    h, w = shape
    gh = max(4, math.ceil(h / cell_px) + 4)
    gw = max(4, math.ceil(w / cell_px) + 4)
    lattice = rng.uniform(-1.0, 1.0, size=(gh, gw))
    return _bicubic_upsample(lattice, float(cell_px), h, w)


@njit(cache=True)
def _cubic_weights(f):
    # Catmull-Rom: interpolating, C1, weights sum to 1.
    f2 = f * f
    f3 = f2 * f
    return (
        -0.5 * f3 + f2 - 0.5 * f,
        1.5 * f3 - 2.5 * f2 + 1.0,
        -1.5 * f3 + 2.0 * f2 + 0.5 * f,
        0.5 * f3 - 0.5 * f2,
    )


@njit(cache=True)
def _bicubic_upsample(lattice, cell, h, w):
    """Output texel (j, i) samples the lattice at ((j + 0.5) / cell + 1, (i + 0.5) / cell + 1)."""
    out = np.empty((h, w), np.float32)
    wx = np.empty((w, 4))
    ix = np.empty(w, np.int64)
    for i in range(w):
        x = (i + 0.5) / cell + 1.0
        x0 = math.floor(x)
        ix[i] = x0 - 1
        a, b, c, d = _cubic_weights(x - x0)
        wx[i, 0] = a
        wx[i, 1] = b
        wx[i, 2] = c
        wx[i, 3] = d
    row = np.empty((4, w))
    for j in range(h):
        y = (j + 0.5) / cell + 1.0
        y0 = math.floor(y)
        wy = _cubic_weights(y - y0)
        for k in range(4):
            src = lattice[y0 - 1 + k]
            for i in range(w):
                p = ix[i]
                row[k, i] = (
                    src[p] * wx[i, 0]
                    + src[p + 1] * wx[i, 1]
                    + src[p + 2] * wx[i, 2]
                    + src[p + 3] * wx[i, 3]
                )
        for i in range(w):
            out[j, i] = (
                row[0, i] * wy[0] + row[1, i] * wy[1] + row[2, i] * wy[2] + row[3, i] * wy[3]
            )
    return out


def fbm(
    rng: np.random.Generator, shape: tuple[int, int], cell_px: float, octaves: int = 4
) -> np.ndarray:
    """Fractal sum of ``smooth_noise`` octaves (halving cell, halving amplitude), about [-1, 1]."""
    out = np.zeros(shape, np.float32)
    amp = 1.0
    total = 0.0
    cell = cell_px
    for _ in range(octaves):
        if cell < 1.0:
            break
        out += amp * smooth_noise(rng, shape, cell)
        total += amp
        amp *= 0.5
        cell *= 0.5
    return out / np.float32(total)


def fine_grain(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    """Per-texel white noise in [-1, 1], float32: the texture of asphalt, grass, gravel."""
    return rng.uniform(-1.0, 1.0, size=shape).astype(np.float32)


@njit(cache=True)
def _mirror(i, n):
    m = i % (2 * n)
    if m >= n:
        m = 2 * n - 1 - m
    return m


@njit(cache=True)
def sun_visibility(height, mpp, sun, gmax):
    """1 where a texel top sees the sun, 0 where the height field blocks it (mirror-tiled).

    Marches from each texel centre towards the sun in 0.5-texel steps until the ray rises above the
    highest point ``gmax``. ``sun`` is a unit ENU vector with ``sun[2] > 0``.
    """
    H, W = height.shape
    out = np.ones((H, W), np.float32)
    horiz = math.sqrt(sun[0] * sun[0] + sun[1] * sun[1])
    if horiz < 1e-6:
        return out
    step = 0.5
    sx = sun[0] / horiz * step
    sy = sun[1] / horiz * step
    rise = sun[2] / horiz * step * mpp  # metres per step
    for j in range(H):
        for i in range(W):
            z = height[j, i] + 0.05
            x = i + 0.5
            y = j + 0.5
            while z < gmax:
                x += sx
                y += sy
                z += rise
                hv = height[_mirror(math.floor(y), H), _mirror(math.floor(x), W)]
                if hv > z:
                    out[j, i] = 0.0
                    break
    return out


def bake_lighting(
    albedo: np.ndarray,
    height: np.ndarray,
    mpp: float,
    sun: np.ndarray,
    ambient: float,
    diffuse: float,
) -> np.ndarray:
    """Ortho colour = albedo x (ambient + diffuse max(0, n.sun) x shadow), uint8 ``(H, W, 3)``.

    Normals come from central differences of the height field; slopes steeper than 60 deg are the
    1-texel risers of walls and are treated as flat (a wall has no top area in the ortho view).
    Shadows are softened by a 3x3 box blur (a penumbra about one texel wide). A light ambient
    occlusion darkens ground close to taller neighbours (the foot of walls, under trees).
    """
    hp = np.pad(height, 1, mode="reflect")
    gx = (hp[1:-1, 2:] - hp[1:-1, :-2]) / (2.0 * mpp)
    gy = (hp[2:, 1:-1] - hp[:-2, 1:-1]) / (2.0 * mpp)
    steep = (gx * gx + gy * gy) > 3.0
    gx = np.where(steep, 0.0, gx)
    gy = np.where(steep, 0.0, gy)
    inv = 1.0 / np.sqrt(1.0 + gx * gx + gy * gy)
    ndotl = (-gx * sun[0] - gy * sun[1] + sun[2]) * inv
    gmax = float(height.max()) + 0.1
    vis = sun_visibility(
        np.ascontiguousarray(height, np.float32), mpp, sun.astype(np.float64), gmax
    )
    vis = uniform_filter(vis, size=3, mode="reflect")
    # Ambient occlusion: how far the local mean height (radius ~6 m) rises above this texel.
    k = max(3, round(6.0 / mpp) | 1)
    local = uniform_filter(height.astype(np.float32), size=k, mode="reflect")
    ao = np.clip(1.0 - 0.04 * np.maximum(local - height, 0.0), 0.6, 1.0)
    shade = (ambient * ao + diffuse * np.maximum(ndotl, 0.0) * vis).astype(np.float32)
    out = albedo * shade[:, :, None]
    return np.clip(out + 0.5, 0, 255).astype(np.uint8)


def max_pyramid(height: np.ndarray, levels: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Max-mip pyramid of ``(H, W)`` float32 heights, flattened for numba.

    Returns ``(flat, offsets, dims)``: ``flat`` float32 concatenation of levels 0..levels,
    ``offsets`` (levels+1,) int64, ``dims`` (levels+1, 2) int64 of (rows, cols). H and W must be
    divisible by 2**levels so the mirror tiling maps aligned cells onto aligned cells.
    """
    h, w = height.shape
    if h % (1 << levels) or w % (1 << levels):
        raise ValueError(f"grid {h}x{w} is not divisible by 2**{levels}")
    lev = [np.ascontiguousarray(height, np.float32)]
    for _ in range(levels):
        a = lev[-1]
        a = a.reshape(a.shape[0] // 2, 2, a.shape[1] // 2, 2).max(axis=(1, 3))
        lev.append(np.ascontiguousarray(a))
    return _flatten(lev)


def mean_pyramid(rgb: np.ndarray, levels: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Box-filtered mip pyramid of an ``(H, W, 3)`` uint8 texture, flattened to ``(N, 3)`` uint8."""
    lev = [np.ascontiguousarray(rgb, np.uint8)]
    acc = rgb.astype(np.float32)
    for _ in range(levels):
        acc = acc.reshape(acc.shape[0] // 2, 2, acc.shape[1] // 2, 2, 3).mean(axis=(1, 3))
        lev.append(np.clip(acc + 0.5, 0, 255).astype(np.uint8))
    flat, offsets, dims = _flatten([a.reshape(-1, 3) for a in lev], [a.shape[:2] for a in lev])
    return flat, offsets, dims


def _flatten(levels, shapes=None):
    """Concatenate levels along axis 0 after flattening their two grid axes.

    ``levels`` are (rows, cols) arrays (heights) or already-flat (rows * cols, C) arrays whose grid
    shapes are given in ``shapes``.
    """
    shapes = shapes if shapes is not None else [a.shape for a in levels]
    sizes = [int(s[0]) * int(s[1]) for s in shapes]
    offsets = np.zeros(len(levels), np.int64)
    offsets[1:] = np.cumsum(sizes)[:-1]
    parts = [
        a.ravel() if a.ndim == 2 and a.shape == tuple(sh) else a
        for a, sh in zip(levels, shapes, strict=False)
    ]
    flat = np.ascontiguousarray(np.concatenate(parts, axis=0))
    dims = np.array([[int(s[0]), int(s[1])] for s in shapes], np.int64)
    return flat, offsets, dims
