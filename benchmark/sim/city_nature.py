"""Terrain relief, the river and trees of a procedural city.

Terrain: fractal value noise (wavelengths 700 m and below) of the style's amplitude, with a valley
carved along the river. River: a meandering band (two sines along a random direction) of the style's
width; its surface lies 1.2 m below the surrounding ground. Trees: candidates on a jittered 5 m grid
accepted with the probability the block programmes painted (parks high, gardens low), stamped as
domed crowns (height field + albedo with leaf grain), the tallest crown winning where they overlap.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from benchmark.sim import detmath
from benchmark.sim.render_core import MAT_BUILDING, MAT_TREE
from benchmark.sim.textures import fbm, hash01
from benchmark.sim.world_styles import Style

SEASON_TREE = {  # tint of the crown albedo, crown radius factor, crown opacity
    "summer": ((1.0, 1.0, 1.0), 1.0, 1.0),
    "autumn": ((1.55, 1.1, 0.75), 0.95, 1.0),
    "winter": ((1.45, 1.15, 1.25), 0.7, 0.55),  # bare branches: the ground shows through
}
SEASON_GRASS = {
    "summer": (1.0, 1.0, 1.0),
    "autumn": (1.12, 1.0, 0.85),
    "winter": (1.22, 1.02, 0.95),
}


def terrain(rng: np.random.Generator, shape: tuple[int, int], mpp: float, S: Style) -> np.ndarray:
    """Ground height, float32 ``shape``, metres; zero mean over the tile."""
    g = fbm(rng, shape, 700.0 / mpp, octaves=3) * np.float32(S.terrain_amp * 1.6)
    return (g - g.mean()).astype(np.float32)


def river_distance(
    rng: np.random.Generator, E: np.ndarray, N: np.ndarray, half_n: float, width: float
) -> tuple[np.ndarray, float]:
    """Distance (metres, float32) to a meandering river centreline, and its mean direction.

    The river runs roughly east-west (within +-35 deg) and crosses the tile away from its centre,
    at 25-60 % of the half-height north or south, so the flight area sees it but is not all water.
    """
    ang = rng.uniform(-0.6, 0.6)
    side = 1.0 if rng.uniform() < 0.5 else -1.0
    off = side * rng.uniform(0.25, 0.6) * half_n
    a1, l1, p1 = rng.uniform(40, 120), rng.uniform(700, 1400), rng.uniform(0, 2 * math.pi)
    # Small wiggles only for narrow rivers (a wide river with tight bends looks like a lake chain).
    a2 = rng.uniform(10, 40) * min(1.0, 30.0 / width)
    l2, p2 = rng.uniform(200, 400), rng.uniform(0, 2 * math.pi)
    s = E * math.cos(ang) + N * math.sin(ang)
    c = -E * math.sin(ang) + N * math.cos(ang)
    k1, k2 = 2 * math.pi / l1, 2 * math.pi / l2
    centre = off + a1 * detmath.sin(k1 * s + p1) + a2 * detmath.sin(k2 * s + p2)
    slope = a1 * k1 * detmath.cos(k1 * s + p1) + a2 * k2 * detmath.cos(k2 * s + p2)
    return (np.abs(c - centre) / np.sqrt(1.0 + slope * slope)).astype(np.float32), ang


@njit(cache=True)
def _stamp_trees(cx, cy, rad, top, col, opacity, rgb, mat, tree_h, grain):
    """Stamp domed crowns (grid units for cx, cy, rad) into tree_h/rgb/mat; ``opacity`` < 1 lets
    the ground show through bare winter crowns."""
    H, W = tree_h.shape
    for k in range(cx.shape[0]):
        r = rad[k]
        i0 = max(0, math.floor(cx[k] - r))
        i1 = min(W - 1, math.ceil(cx[k] + r))
        j0 = max(0, math.floor(cy[k] - r))
        j1 = min(H - 1, math.ceil(cy[k] + r))
        for j in range(j0, j1 + 1):
            for i in range(i0, i1 + 1):
                if mat[j, i] >= MAT_BUILDING:
                    continue
                dx = (i + 0.5 - cx[k]) / r
                dy = (j + 0.5 - cy[k]) / r
                d2 = dx * dx + dy * dy
                if d2 >= 1.0:
                    continue
                z = top[k] * (0.3 + 0.7 * math.sqrt(1.0 - d2))
                if z > tree_h[j, i]:
                    tree_h[j, i] = z
                    g = grain[j, i]
                    # Leaf clumps: darker toward the rim, per-texel grain.
                    f = 0.82 + 0.18 * math.sqrt(1.0 - d2) + 0.16 * g
                    for c in range(3):
                        rgb[j, i, c] = rgb[j, i, c] * (1.0 - opacity) + col[k, c] * f * opacity
                    mat[j, i] = MAT_TREE


def plant_trees(
    prob: np.ndarray,
    rgb: np.ndarray,
    mat: np.ndarray,
    grain: np.ndarray,
    S: Style,
    seed: int,
    change: int,
    season: str,
    mpp: float,
) -> np.ndarray:
    """Place and stamp trees; returns the tree height above ground (float32 (H, W), 0 elsewhere).

    ``prob`` (H, W) is the per-candidate acceptance probability painted by the block programmes.
    In a changed city (``change != 0``) 20 % of the trees are gone and 15 % more grow elsewhere.
    """
    H, W = prob.shape
    spacing = 5.0 / mpp
    gi, gj = np.meshgrid(np.arange(int(W / spacing)), np.arange(int(H / spacing)))
    gi = gi.ravel().astype(np.int64)
    gj = gj.ravel().astype(np.int64)
    cx = (gi + hash01(gi, gj, seed, 1)) * spacing
    cy = (gj + hash01(gi, gj, seed, 2)) * spacing
    p = prob[np.minimum(cy.astype(np.int64), H - 1), np.minimum(cx.astype(np.int64), W - 1)]
    u = hash01(gi, gj, seed, 3)
    keep = u < p
    if change:
        keep = (keep & (hash01(gi, gj, change, 4) >= 0.2)) | ((u >= p) & (u < 1.15 * p))
    cx, cy, gi, gj = cx[keep], cy[keep], gi[keep], gj[keep]
    tint, rfac, opacity = SEASON_TREE[season]
    rad = (2.2 + 3.6 * detmath.power(hash01(gi, gj, seed, 5), 1.5)) * rfac / mpp
    top = 6.0 + 10.0 * hash01(gi, gj, seed, 6)
    base = np.asarray(S.tree, np.float64)[None, :]
    var = hash01(gi, gj, seed, 7)[:, None]
    col = base * (0.75 + 0.5 * var) * np.asarray(tint)[None, :]
    if season == "autumn":
        # A third of the crowns turn orange/yellow.
        turn = hash01(gi, gj, seed, 8) < 0.35
        col[turn] = np.asarray((150.0, 104.0, 48.0)) * (0.8 + 0.4 * var[turn])
    order = np.argsort(top, kind="stable")
    tree_h = np.zeros((H, W), np.float32)
    _stamp_trees(
        cx[order],
        cy[order],
        rad[order],
        top[order],
        col[order].astype(np.float32),
        float(opacity),
        rgb,
        mat,
        tree_h,
        grain,
    )
    return tree_h
