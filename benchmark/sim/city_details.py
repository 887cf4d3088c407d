"""Distinctive details: churches with spires, sports pitches, railways with trains, bus lanes.

Landmarks and long linear features make places recognisable from both the UAV and the satellite
view (the network has something unambiguous to match), and they differ between styles: churches
and pitches in oxford / cambridge, railways in london / industrial, red bus lanes in london.
"""

from __future__ import annotations

import math

import numpy as np

from benchmark.sim import detmath
from benchmark.sim.city_blocks import BlockPixels, Canvas, _set, lerp, pick, touching
from benchmark.sim.render_core import MAT_BUILDING, MAT_GROUND, MAT_SMALL, MAT_WATER
from benchmark.sim.textures import hash01
from benchmark.sim.world_styles import Style

WHITE = np.float32(236.0)


def line_cover(dist: np.ndarray, width: float) -> np.ndarray:
    """Texel coverage (0..1) of a painted line of ``width`` metres at distance ``dist`` (1 m/px)."""
    return np.clip(0.5 + (0.5 * width - dist), 0.0, 1.0).astype(np.float32)


def _paint(cv: Canvas, idx: np.ndarray, cover: np.ndarray, colour) -> None:
    sel = cover > 0
    ii = idx[sel]
    c = cover[sel][:, None]
    cv.rgb[ii] = cv.rgb[ii] * (1.0 - c) + np.asarray(colour, np.float32) * c


def fill_lawn(S: Style, cv: Canvas, P: BlockPixels) -> None:
    """Mown lawns with stripes, a path ring, trees at the edge; big ones carry a football pitch."""
    stripe = (np.floor(P.lu / 7.0) % 2) * 2.0 - 1.0
    col = np.asarray(S.grass, np.float32)[None, :] * (
        1.0 + 0.07 * stripe[:, None] + 0.04 * cv.grain[P.idx][:, None]
    )
    cv.rgb[P.idx] = col
    cv.mat[P.idx] = MAT_GROUND
    d = np.minimum(np.minimum(P.lu, P.lv), np.minimum(P.bw - P.lu, P.bh - P.lv))
    d = np.minimum(d, P.edge)  # the ring path follows a district-boundary arterial too
    cv.tree[P.idx] = np.where(d < 6.0, S.tree_park, 0.0).astype(np.float32)
    ring = (d > 7.0) & (d < 9.0)
    _set(cv, P.idx, ring, rgb=np.asarray(S.pavement, np.float32), tree=0.0)
    # A pitch (105 x 68 m scaled to fit inside the ring) on 60 % of the lawns.
    along_u = P.bw >= P.bh
    x = np.where(along_u, P.lu - 0.5 * P.bw, P.lv - 0.5 * P.bh)
    y = np.where(along_u, P.lv - 0.5 * P.bh, P.lu - 0.5 * P.bw)
    long_side = np.maximum(P.bw, P.bh) - 24.0
    short_side = np.minimum(P.bw, P.bh) - 24.0
    k = np.minimum(1.0, np.minimum(long_side / 105.0, short_side / 68.0))
    hl, hw = 52.5 * k, 34.0 * k
    has = (hash01(P.key, cv.seed, 71) < 0.6) & (k > 0.45)
    ax, ay = np.abs(x), np.abs(y)
    # No pitch where a district boundary cuts into it (it would be cut in half).
    has &= ~touching(P.key, (ax < 52.5 * k + 2.0) & (ay < 34.0 * k + 2.0), d < 4.0)
    # Distance to the pitch outline (a rectangle), then the halfway line.
    outline = np.minimum(
        np.where(ay <= hw, np.abs(ax - hl), detmath.hypot(ax - hl, ay - hw)),
        np.where(ax <= hl, np.abs(ay - hw), detmath.hypot(ax - hl, ay - hw)),
    )
    dist = np.minimum(outline, np.where(ay <= hw, np.abs(x), 1e3))
    dist = np.minimum(dist, np.abs(detmath.hypot(x, y) - 9.15 * k))  # centre circle
    pen = np.minimum(
        np.where(ay <= 20.15 * k, np.abs(ax - (hl - 16.5 * k)), 1e3),
        np.where((ax >= hl - 16.5 * k) & (ax <= hl), np.abs(ay - 20.15 * k), 1e3),
    )
    dist = np.minimum(dist, pen)
    cover = np.where(has, line_cover(dist, 0.3), 0.0).astype(np.float32) * 0.9
    _paint(cv, P.idx, cover, WHITE)


def fill_plaza(S: Style, cv: Canvas, P: BlockPixels) -> None:
    """A paved square with trees round it and a fountain, or (church_prob) a church with a spire."""
    tile = ((np.floor(P.lu / 3.0) + np.floor(P.lv / 3.0)) % 2) * 2.0 - 1.0
    col = np.asarray(S.pavement, np.float32)[None, :] * (
        1.0 + 0.04 * tile[:, None] + 0.03 * cv.grain[P.idx][:, None]
    )
    cv.rgb[P.idx] = col
    cv.mat[P.idx] = MAT_GROUND
    edge = np.minimum(np.minimum(P.lu, P.lv), np.minimum(P.bw - P.lu, P.bh - P.lv))
    edge = np.minimum(edge, P.edge)
    cv.tree[P.idx] = np.where(edge < 8.0, 0.35, 0.02).astype(np.float32)
    church = hash01(P.key, cv.seed, 72) < S.church_prob
    x = P.lu - 0.5 * P.bw
    y = P.lv - 0.5 * P.bh
    r = detmath.hypot(x, y)
    # Fountain or church only where a district boundary does not cut through it.
    centre = (np.abs(x) < np.minimum(0.3 * np.maximum(P.bw, P.bh), 22.0) + 2.0) & (np.abs(y) < 8)
    centre |= (np.abs(y) < np.minimum(0.3 * np.maximum(P.bw, P.bh), 22.0) + 2.0) & (np.abs(x) < 8)
    cut = touching(P.key, centre, P.edge < 2.0)
    church &= ~cut
    f = ~church & ~cut
    _set(
        cv,
        P.idx,
        f & (r < 5.0) & (r > 4.2),
        rgb=np.asarray((200, 196, 186), np.float32),
        struct=0.6,
    )
    _set(
        cv,
        P.idx,
        f & (r <= 4.2),
        rgb=np.asarray(S.water, np.float32) * 1.3,
        mat=MAT_WATER,
        struct=0.3,
    )
    _set(
        cv,
        P.idx,
        f & (r < 1.0),
        rgb=np.asarray((190, 186, 176), np.float32),
        mat=MAT_SMALL,
        struct=3.5,
    )
    # Church: nave along the block's long axis, gabled, with a square tower and spire at one end.
    along_u = P.bw >= P.bh
    a = np.where(along_u, x, y)
    b = np.where(along_u, y, x)
    half_len = np.minimum(0.3 * np.maximum(P.bw, P.bh), 22.0)
    nave = church & (np.abs(a) < half_len) & (np.abs(b) < 6.0)
    nave_h = 12.0 + 6.0 - np.abs(b)  # 45 deg roof, ridge at 18 m
    tx = a - (half_len - 3.5)
    tower = church & (np.abs(tx) < 3.5) & (np.abs(b) < 3.5)
    spire = 30.0 + 14.0 * (1.0 - np.maximum(np.abs(tx), np.abs(b)) / 3.5)
    height = np.where(tower, spire, nave_h).astype(np.float32)
    inb = nave | tower
    row = (hash01(P.key, cv.seed, 73) * cv.n_palette).astype(np.int64)
    roof = np.where(tower[:, None], np.float32((96, 100, 106)), np.float32((88, 92, 100)))
    roof = roof * (1.0 + 0.05 * cv.grain[P.idx][:, None])
    _set(
        cv, P.idx, inb, struct=height, rgb=roof, mat=(MAT_BUILDING + row).astype(np.uint8), tree=0.0
    )


def bus_lanes(
    rgb: np.ndarray,
    on: np.ndarray,
    d: np.ndarray,
    half: np.ndarray,
    other: np.ndarray,
    half_other: np.ndarray,
    width: np.ndarray,
    S: Style,
) -> np.ndarray:
    """Paint red bus lanes along the kerbs of major roads; returns the lane mask (no parking)."""
    lane = on & (width >= S.road_major) & (d > half - 3.6) & (d < half - 0.3)
    lane &= other > half_other + 4.0
    rgb[lane] = rgb[lane] * 0.35 + np.float32((150, 58, 48)) * 0.65
    return lane


def meander(
    rng: np.random.Generator,
    E: np.ndarray,
    N: np.ndarray,
    half_n: float,
    amp: float,
    wavelength: float,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Signed distance (metres) to a gently curving line across the tile, the along-line coordinate
    and the line's mean direction (radians)."""
    ang = rng.uniform(0, math.pi)
    off = rng.uniform(-0.35, 0.35) * half_n
    k = 2 * math.pi / wavelength
    ph = rng.uniform(0, 2 * math.pi)
    s = E * math.cos(ang) + N * math.sin(ang)
    c = -E * math.sin(ang) + N * math.cos(ang)
    centre = off + amp * detmath.sin(k * s + ph)
    slope = amp * k * detmath.cos(k * s + ph)
    return ((c - centre) / np.sqrt(1.0 + slope * slope)).astype(np.float32), s, ang


def add_railway(
    rng: np.random.Generator,
    cv: Canvas,
    E: np.ndarray,
    N: np.ndarray,
    keep: np.ndarray,
    half_n: float,
    S: Style,
) -> np.ndarray:
    """A double-track railway: ballast, four rails, verges, 0-2 trains; major roads bridge it.

    ``keep`` (H*W bool, flat) marks texels the railway must not overwrite (major roads). Returns
    the flat corridor mask.
    """
    sd, s, _ = meander(rng, E, N, half_n, amp=rng.uniform(40, 120), wavelength=2600.0)
    sd = sd.ravel()
    s = s.ravel().astype(np.float32)
    corridor = (np.abs(sd) < 12.0) & ~keep
    idx = np.flatnonzero(corridor)
    d = sd[idx]
    g = cv.grain[idx]
    ballast = np.abs(d) < 6.0
    verge = np.asarray(S.grass, np.float32) * 0.9
    base = np.where(ballast[:, None], np.float32((128, 118, 106)), verge)
    cv.rgb[idx] = base * (1.0 + 0.08 * g[:, None])
    cv.mat[idx] = MAT_GROUND
    cv.struct[idx] = 0.0
    cv.tree[idx] = np.where(np.abs(d) > 9.0, 0.06, 0.0).astype(np.float32)
    rails = np.zeros(idx.shape, np.float32)
    for c in (-2.25 - 0.72, -2.25 + 0.72, 2.25 - 0.72, 2.25 + 0.72):
        rails = np.maximum(rails, line_cover(np.abs(d - c), 0.25))
    _paint(cv, idx, rails, (72, 64, 58))
    # Trains: 80-220 m long, 3.0 m wide, 3.9 m high, coaches every 20 m.
    n_trains = int(hash01(cv.seed, cv.change, 81) * 3)
    span = float(s.max() - s.min())
    for k in range(n_trains):
        track = -2.25 if hash01(cv.seed, cv.change, k, 82) < 0.5 else 2.25
        length = lerp((80.0, 220.0), hash01(cv.seed, cv.change, k, 83))
        s0 = float(s.min()) + 0.1 * span + 0.8 * span * float(hash01(cv.seed, cv.change, k, 84))
        sl = s[idx] - s0
        on = (np.abs(d - track) < 1.5) & (sl > 0) & (sl < length)
        colour = pick(
            ((200, 40, 40), (230, 230, 226), (40, 70, 140), (120, 124, 130)),
            np.full(int(on.sum()), float(hash01(cv.seed, cv.change, k, 85))),
        )
        gap = (sl[on] % 20.0) < 0.8
        colour = np.where(gap[:, None], colour * 0.4, colour)
        cv.rgb[idx[on]] = colour
        cv.struct[idx[on]] = 3.9
        cv.mat[idx[on]] = MAT_SMALL
    return corridor
