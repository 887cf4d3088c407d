"""Procedural noise, hashing and mip pyramids for the city generator (lighting: lighting.py).

All functions are deterministic: noise comes from ``numpy.random.Generator`` streams seeded by the
caller, hashes are pure integer arithmetic (no Python ``hash``), and the numba kernels are serial.
Arrays are indexed ``[j, i]`` with j along north (row 0 = southern edge), i along east.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

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
    """Box-filtered mip pyramid of an ``(H, W, 3)`` uint8 texture, flattened to ``(N, 3)`` uint8.

    Level k + 1 is the 2 x 2 mean of level k's unrounded float32 values, rounded half-up to uint8
    (so rounding errors do not accumulate down the pyramid).
    """
    h, w = rgb.shape[:2]
    shapes = [(h >> k, w >> k) for k in range(levels + 1)]
    sizes = [a * b for a, b in shapes]
    offsets = np.zeros(levels + 1, np.int64)
    offsets[1:] = np.cumsum(sizes)[:-1]
    flat = np.empty((sum(sizes), 3), np.uint8)
    flat[: sizes[0]] = np.ascontiguousarray(rgb, np.uint8).reshape(-1, 3)
    if levels:
        _mean_levels(np.ascontiguousarray(rgb, np.uint8), levels, flat, offsets)
    return flat, offsets, np.array(shapes, np.int64)


@njit(cache=True)
def _mean_levels(rgb, levels, flat, offsets):
    acc = rgb.astype(np.float32)
    for k in range(1, levels + 1):
        hh = acc.shape[0] // 2
        ww = acc.shape[1] // 2
        nxt = np.empty((hh, ww, 3), np.float32)
        base = offsets[k]
        for j in range(hh):
            for i in range(ww):
                for c in range(3):
                    v = (
                        acc[2 * j, 2 * i, c]
                        + acc[2 * j, 2 * i + 1, c]
                        + acc[2 * j + 1, 2 * i, c]
                        + acc[2 * j + 1, 2 * i + 1, c]
                    ) * np.float32(0.25)
                    nxt[j, i, c] = v
                    flat[base + j * ww + i, c] = np.uint8(min(max(v + 0.5, 0.0), 255.0))
        acc = nxt


def _flatten(levels):
    """Concatenate ``(rows, cols)`` levels into one flat array with offsets and dims."""
    sizes = [a.size for a in levels]
    offsets = np.zeros(len(levels), np.int64)
    offsets[1:] = np.cumsum(sizes)[:-1]
    flat = np.ascontiguousarray(np.concatenate([a.ravel() for a in levels]))
    dims = np.array([a.shape for a in levels], np.int64)
    return flat, offsets, dims
