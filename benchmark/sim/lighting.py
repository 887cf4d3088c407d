"""Illumination states of a city: sun directions, cast shadows and baked ortho textures.

Every city carries ``K`` illumination states (``N_LIGHTS``), each a sun direction and an ortho
texture with that sun's shading and shadows baked in, so a flight and a satellite image can be
rendered at independent times of day (issue 9: facade shading must not encode the heading).

Sun directions are unit ENU vectors towards the sun; azimuth clockwise from north, elevation above
the horizon. ``sample_suns`` stratifies the K azimuths over the full circle and, independently,
the K elevations over the season's band. Why the full circle: a sun confined to the southern sky
(one mid-latitude town's morning-to-afternoon path, 70-290 deg, elevation highest near south) is a
compass: with it, a linear probe on image-wide UAV statistics (``benchmark.analysis.heading_cue``)
still read the heading at 0.80-0.86x the constant predictor's yaw error. The simulated towns may lie
at any latitude of either hemisphere, where the sun can stand in any direction, and the elevation
says nothing about the azimuth.

Shadows (``sun_visibility``) are traced by a sweep, O(texels) per sun instead of a march per texel:
parallel sun rays one texel apart are scanned from the sun side, carrying the height of the shadow
volume cast by everything upstream; each texel is lit when its top is above that height, averaged
between the two rays that bracket it (a one-texel penumbra, no lateral drift with distance).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from scipy.ndimage import uniform_filter

from benchmark.sim.textures import mean_pyramid

N_LIGHTS = 8  # illumination states per city (see world.py for the cost)
# Elevation bands (deg) by season: the flown city in summer, the earlier city in winter/autumn.
ELEVATION_DEG = {"summer": (15.0, 65.0), "winter": (12.0, 24.0), "autumn": (20.0, 34.0)}


def sun_vector(azimuth: float, elevation: float) -> np.ndarray:
    """Unit ENU vector ``(3,)`` towards a sun at ``azimuth`` (rad, clockwise from north) and
    ``elevation`` (rad above the horizon)."""
    ce = math.cos(elevation)
    return np.array([math.sin(azimuth) * ce, math.cos(azimuth) * ce, math.sin(elevation)])


def sun_angles(sun: np.ndarray) -> tuple[float, float]:
    """``(azimuth in [0, 2 pi), elevation)`` radians of a unit ENU sun vector (inverse of
    ``sun_vector``)."""
    az = math.atan2(float(sun[0]), float(sun[1])) % (2.0 * math.pi)
    el = math.asin(max(-1.0, min(1.0, float(sun[2]))))
    return az, el


def sample_suns(rng: np.random.Generator, n: int, season: str) -> np.ndarray:
    """``(n, 3)`` float64 unit sun vectors of ``n`` illumination states, in random order.

    Azimuths: one in each of ``n`` equal sectors of the full circle (a random offset shared by
    all, uniform in the first sector, plus ``k 360/n`` deg), so every direction is equally likely
    and consecutive states are ``360/n`` deg apart (8 states: 45 deg; 90-270 deg always covered).
    Elevations: one in each of ``n`` equal strata of the season's band (summer 15-65 deg, the
    earlier city's winter 12-24 or autumn 20-34), uniform within its stratum, assigned to the
    azimuths in random order (independent of them).
    """
    if not (isinstance(n, (int, np.integer)) and n >= 1):
        raise ValueError(f"n_lights must be an integer >= 1, got {n!r}")
    if season not in ELEVATION_DEG:
        raise ValueError(f"season must be one of {sorted(ELEVATION_DEG)}, got {season!r}")
    sector = 360.0 / n
    az = rng.uniform(0.0, sector) + sector * np.arange(n)
    lo, hi = ELEVATION_DEG[season]
    el = lo + (hi - lo) * (rng.permutation(n) + rng.uniform(0.0, 1.0, n)) / n
    order = rng.permutation(n)
    return np.stack([sun_vector(math.radians(az[k]), math.radians(el[k])) for k in order])


@njit(cache=True)
def _mirror(i, n):
    m = i % (2 * n)
    if m >= n:
        m = 2 * n - 1 - m
    return m


@njit(cache=True)
def _sweep_visibility(h, t, drop, extra):
    """Sun visibility of ``h`` (rows y, columns x) for a sun towards +x with dy/dx = ``t``
    (|t| <= 1), the shadow volume sinking ``drop`` metres per column; ``extra`` columns beyond the
    eastern edge are scanned (mirror-tiled) so occluders outside the tile cast their shadows in.

    Texel (i, j) has its centre at index coordinates (i, j); ray m runs through y = m + t x. The
    texel lies between rays m0 = floor(j - t i) and m0 + 1 at fraction w; its visibility is
    ``(1 - w) [lit along m0] + w [lit along m0 + 1]``.
    """
    H, W = h.shape
    out = np.empty((H, W), np.float32)
    ncol = W + extra
    prev = np.empty(W)
    cur = np.empty(W)
    if t >= 0.0:
        m_lo = math.floor(-t * (W - 1))
        m_hi = H
    else:
        m_lo = 0
        m_hi = math.floor(H - 1 - t * (W - 1)) + 1
    shrink = 1e-9 if t >= 0.0 else -1e-9
    for m in range(m_lo, m_hi + 1):
        # Scan ray m from the sun side: u is the shadow height at column c cast by columns > c.
        u = -1e300
        for c in range(ncol - 1, -1, -1):
            if c < W:
                cur[c] = u
            # The ray crosses column c between y = m + t (c -+ 1/2): at most two rows (|t| <= 1),
            # both of which it passes through (as an exact traversal of the texel squares would).
            # (Shrunk by 1e-9 so a ray through a texel corner touches neither diagonal neighbour.)
            cc = _mirror(c, W)
            r0 = math.floor(m + t * (c - 0.5) + 0.5 + shrink)
            r1 = math.floor(m + t * (c + 0.5) + 0.5 - shrink)
            hv = max(h[_mirror(r0, H), cc], h[_mirror(r1, H), cc])
            u = max(u, hv) - drop
        if m > m_lo:
            for i in range(W):
                y = (m - 1) + t * i
                j = math.ceil(y)
                if j < 0 or j >= H:
                    continue
                w = j - y
                if w < 1e-9:  # on ray m - 1 up to rounding
                    w = 0.0
                top = h[j, i] + 0.05
                a = 1.0 if top >= prev[i] else 0.0
                b = 1.0 if top >= cur[i] else 0.0
                out[j, i] = (1.0 - w) * a + w * b
        prev, cur = cur, prev
    return out


def sun_visibility(
    height: np.ndarray, mpp: float, sun: np.ndarray, gmax: float | None = None
) -> np.ndarray:
    """Fraction ``(H, W)`` float32 in [0, 1] of each texel top that sees the sun (mirror-tiled
    height field, metres; ``sun`` a unit ENU vector with ``sun[2] > 0``).

    ``gmax`` (default: the highest point) bounds how far upstream occluders are searched. The sun
    is brought to the canonical case (towards +x, |dy/dx| <= 1) by transposing and flipping the
    grid; the mirror tiling commutes with both.
    """
    h = np.asarray(height, np.float64)
    sun = np.asarray(sun, np.float64)
    horiz = math.hypot(sun[0], sun[1])
    if sun[2] <= 0.0:
        raise ValueError(f"sun must be above the horizon (sun[2] > 0), got {sun.tolist()}")
    if horiz < 1e-9:
        return np.ones(h.shape, np.float32)
    sx, sy = float(sun[0]), float(sun[1])
    transpose = abs(sy) > abs(sx)
    if transpose:
        h, sx, sy = h.T, sy, sx
    flip = sx < 0.0
    if flip:
        h, sx = h[:, ::-1], -sx
    top = float(h.max()) if gmax is None else float(gmax)
    drop = float(sun[2]) / sx * mpp  # metres per column along the ray
    extra = min(h.shape[1] * 64, math.ceil(max(top - float(h.min()), 0.0) / drop) + 2)
    t = sy / sx
    # Axis-aligned and diagonal suns up to rounding: make the rays pass exactly through centres.
    t = 0.0 if abs(t) < 1e-12 else (math.copysign(1.0, t) if abs(abs(t) - 1) < 1e-12 else t)
    vis = _sweep_visibility(np.ascontiguousarray(h), t, drop, extra)
    if flip:
        vis = vis[:, ::-1]
    if transpose:
        vis = vis.T
    return np.ascontiguousarray(vis)


def _normals_and_ao(height: np.ndarray, mpp: float):
    """Height-field gradients (walls' 1-texel risers flattened) and the ambient occlusion."""
    hp = np.pad(height, 1, mode="reflect")
    gx = (hp[1:-1, 2:] - hp[1:-1, :-2]) / (2.0 * mpp)
    gy = (hp[2:, 1:-1] - hp[:-2, 1:-1]) / (2.0 * mpp)
    steep = (gx * gx + gy * gy) > 3.0
    gx = np.where(steep, 0.0, gx)
    gy = np.where(steep, 0.0, gy)
    inv = 1.0 / np.sqrt(1.0 + gx * gx + gy * gy)
    # Ambient occlusion: how far the local mean height (radius ~6 m) rises above this texel.
    k = max(3, round(6.0 / mpp) | 1)
    local = uniform_filter(height.astype(np.float32), size=k, mode="reflect")
    ao = np.clip(1.0 - 0.04 * np.maximum(local - height, 0.0), 0.6, 1.0)
    return gx, gy, inv, ao


def bake_lighting(
    albedo: np.ndarray,
    height: np.ndarray,
    mpp: float,
    sun: np.ndarray,
    ambient: float,
    diffuse: float,
) -> np.ndarray:
    """Ortho colour = albedo x (ambient x AO + diffuse max(0, n.sun) x shadow), uint8 ``(H, W, 3)``.

    Normals come from central differences of the height field; slopes steeper than 60 deg are the
    1-texel risers of walls and are treated as flat (a wall has no top area in the ortho view).
    Shadows are softened by a 3x3 box blur (a penumbra about one texel wide). A light ambient
    occlusion darkens ground close to taller neighbours (the foot of walls, under trees).
    """
    geom = _normals_and_ao(height, mpp)
    return _shade(albedo, height, mpp, np.asarray(sun, np.float64), ambient, diffuse, geom)


def _shade(albedo, height, mpp, sun, ambient, diffuse, geom) -> np.ndarray:
    gx, gy, inv, ao = geom
    vis = sun_visibility(height, mpp, sun, float(height.max()) + 0.1)
    vis = uniform_filter(vis, size=3, mode="reflect")
    out = np.empty(albedo.shape, np.uint8)
    _shade_kernel(albedo, gx, gy, inv, ao, vis, sun, float(ambient), float(diffuse), out)
    return out


@njit(cache=True)
def _shade_kernel(albedo, gx, gy, inv, ao, vis, sun, ambient, diffuse, out):
    """``out = clip(albedo (ambient ao + diffuse max(0, n.sun) vis) + 0.5)`` as uint8, per texel
    (one fused pass instead of a dozen full-size float temporaries)."""
    H, W = vis.shape
    for j in range(H):
        for i in range(W):
            ndotl = (-gx[j, i] * sun[0] - gy[j, i] * sun[1] + sun[2]) * inv[j, i]
            shade = np.float32(ambient * ao[j, i] + diffuse * max(ndotl, 0.0) * vis[j, i])
            for c in range(3):
                v = albedo[j, i, c] * shade + np.float32(0.5)
                out[j, i, c] = np.uint8(min(max(v, 0.0), 255.0))


def bake_light_states(
    albedo: np.ndarray,
    height: np.ndarray,
    mpp: float,
    suns: np.ndarray,
    levels: int,
    *,
    ambient: float = 0.55,
    diffuse: float = 0.6,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mip pyramids of the ortho texture under each sun: ``(tex (K, N, 3) uint8, offsets, dims)``.

    ``tex[k]`` is the flattened ``mean_pyramid`` (``levels`` halvings) of ``bake_lighting`` with
    ``suns[k]``; offsets and dims are shared by all states. Normals and ambient occlusion are
    computed once.
    """
    suns = np.asarray(suns, np.float64)
    if suns.ndim != 2 or suns.shape[1] != 3 or len(suns) < 1:
        raise ValueError(f"suns must be (K, 3) with K >= 1, got shape {suns.shape}")
    geom = _normals_and_ao(height, mpp)
    tex = None
    offsets = dims = None
    for k, sun in enumerate(suns):
        ortho = _shade(albedo, height, mpp, sun, ambient, diffuse, geom)
        flat, offsets, dims = mean_pyramid(ortho, levels)
        if tex is None:
            tex = np.empty((len(suns), *flat.shape), np.uint8)
        tex[k] = flat
    return tex, offsets, dims
