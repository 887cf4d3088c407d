"""Street network and city assembly: from (style, seed) to height, albedo and material rasters.

The street network is a rotated grid with irregular spacings whose coordinates ``(u, v)`` are
displaced by smooth noise (``warp_amp``): strongly warped for oxford (curved streets), nearly
straight for cambridge/industrial. For every texel the generator finds the enclosing grid lines,
hence its distance to the nearest street centreline (carriageway, kerb, pavement, markings, parked
cars) and its block and local block coordinates, which the block programmes (city_blocks.py) turn
into buildings, gardens, parks, lots. A river band (city_nature.py) overrides it; major streets
bridge it.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass

import numpy as np

from benchmark.sim import city_blocks as cb
from benchmark.sim import city_details as cd
from benchmark.sim import city_industry as ci
from benchmark.sim.city_nature import SEASON_GRASS, plant_trees, river_distance, terrain
from benchmark.sim.render_core import MAT_BUILDING, MAT_GROUND, MAT_SMALL, MAT_WATER
from benchmark.sim.textures import fine_grain, hash01, smooth_noise
from benchmark.sim.world_styles import Style

N_PALETTE = 200
BLOCK_TYPES = ("terrace", "detached", "slab", "warehouse", "park", "parking", "lawn", "plaza")


@dataclass
class Rasters:
    """Generator output, arrays indexed [j (north), i (east)], row 0 = southern edge."""

    height: np.ndarray  # float32 (H, W) absolute surface height, metres
    ground: np.ndarray  # float32 (H, W) terrain height, metres
    albedo: np.ndarray  # float32 (H, W, 3)
    mat: np.ndarray  # uint8 (H, W)
    orient: np.ndarray  # uint8 (H, W): wall direction mod 90 deg, 256 steps
    palette: np.ndarray  # float64 (N_PALETTE, 10)


def rng_for(style: str, seed: int, stream: str) -> np.random.Generator:
    """An independent, reproducible numpy stream per (style, seed, purpose)."""
    return np.random.default_rng(
        [zlib.crc32(style.encode()), int(seed), zlib.crc32(stream.encode())]
    )


def facade_palette(S: Style, rng: np.random.Generator) -> np.ndarray:
    """(N_PALETTE, 10): wall rgb, window rgb, floor height, window spacing, window w/h fractions."""
    pal = np.zeros((N_PALETTE, 10))
    walls = np.asarray(S.wall_colours, np.float64)
    wins = np.asarray(S.window_colours, np.float64)
    pal[:, 0:3] = walls[rng.integers(0, len(walls), N_PALETTE)] * rng.uniform(
        0.88, 1.12, (N_PALETTE, 1)
    )
    pal[:, 3:6] = wins[rng.integers(0, len(wins), N_PALETTE)] * rng.uniform(
        0.85, 1.2, (N_PALETTE, 1)
    )
    pal[:, 6] = rng.uniform(*S.floor_h, N_PALETTE)
    pal[:, 7] = rng.uniform(*S.window_spacing, N_PALETTE)
    pal[:, 8] = rng.uniform(0.35, 0.7, N_PALETTE)
    pal[:, 9] = rng.uniform(0.4, 0.65, N_PALETTE)
    return np.clip(pal, 0.0, None)


def _grid_lines(rng, lo: float, hi: float, pitch: tuple[float, float]) -> np.ndarray:
    start = lo - pitch[1] - rng.uniform(0, pitch[1])
    n = int((hi - start) / pitch[0]) + 3
    lines = start + np.concatenate([[0.0], np.cumsum(rng.uniform(*pitch, n))])
    return lines.astype(np.float32)  # float32 keeps the per-texel temporaries small


def _axis(coord, lines, widths):
    """Per texel: index of the line below, distance to the nearest line, that road's half width."""
    k = np.clip(np.searchsorted(lines, coord, side="right") - 1, 0, len(lines) - 2).astype(np.int32)
    lo = lines[k]
    hi = lines[k + 1]
    dlo = coord - lo
    dhi = hi - coord
    near_lo = dlo < dhi
    dist = np.where(near_lo, dlo, dhi)
    half = np.where(near_lo, widths[k], widths[k + 1]) * 0.5
    return k, lo, hi, dist, half


def generate(
    style: Style,
    seed: int,
    shape: tuple[int, int],
    mpp: float,
    change: int,
    season: str,
) -> Rasters:
    """Build the rasters of one city (before lighting)."""
    S = style
    H, W = shape
    rng = lambda name: rng_for(S.name, seed, name)  # noqa: E731
    e = (np.arange(W, dtype=np.float32) + 0.5) * mpp - 0.5 * W * mpp
    n = (np.arange(H, dtype=np.float32) + 0.5) * mpp - 0.5 * H * mpp
    E, N = np.meshgrid(e, n)
    ground = terrain(rng("terrain"), shape, mpp, S)
    grain = fine_grain(rng("grain"), shape)

    # Street grid in warped, rotated coordinates.
    r = rng("streets")
    ang = r.uniform(0, math.pi / 2)
    u = E * math.cos(ang) + N * math.sin(ang)
    v = -E * math.sin(ang) + N * math.cos(ang)
    if S.warp_amp > 0:
        u += S.warp_amp * smooth_noise(rng("warp_u"), shape, S.warp_cell / mpp)
        v += S.warp_amp * smooth_noise(rng("warp_v"), shape, S.warp_cell / mpp)
    # Wall direction (mod 90 deg) = direction of grad u, quantised to 2.8 deg steps so a parcel's
    # walls share one direction (the window grid is laid out along it).
    gu_e = np.gradient(u, axis=1)
    gu_n = np.gradient(u, axis=0)
    theta = np.mod(np.arctan2(gu_n, gu_e), math.pi / 2)
    orient = ((np.round(theta / (math.pi / 2) * 32.0) % 32) * 8).astype(np.uint8)
    del gu_e, gu_n, theta
    ul = _grid_lines(r, float(u.min()), float(u.max()), S.block_u)
    vl = _grid_lines(r, float(v.min()), float(v.max()), S.block_v)
    off_u, off_v = r.integers(0, S.major_every, 2)
    wu = np.where((np.arange(len(ul)) + off_u) % S.major_every == 0, S.road_major, S.road_minor)
    wv = np.where((np.arange(len(vl)) + off_v) % S.major_every == 0, S.road_major, S.road_minor)
    wu = wu.astype(np.float32)
    wv = wv.astype(np.float32)
    ku, ulo, uhi, du, hu = _axis(u, ul, wu)
    kv, vlo, vhi, dv, hv = _axis(v, vl, wv)
    on_u = du < hu  # on a street running along v (constant u)
    on_v = dv < hv
    road = on_u | on_v
    sw = S.sidewalk
    walk = ~road & ((du < hu + sw) | (dv < hv + sw))

    rgb = np.empty((H, W, 3), np.float32)
    mat = np.zeros((H, W), np.uint8)
    struct = np.zeros((H, W), np.float32)
    tree = np.zeros((H, W), np.float32)
    cv = cb.Canvas(
        struct.reshape(-1),
        rgb.reshape(-1, 3),
        mat.reshape(-1),
        tree.reshape(-1),
        grain.reshape(-1),
        seed,
        change,
        N_PALETTE,
    )

    # Carriageway, kerbs and pavements.
    asph = np.asarray(S.asphalt, np.float32)
    rgb[:] = asph * (1.0 + 0.05 * grain[..., None])
    pav = np.asarray(S.pavement, np.float32)
    rgb[walk] = pav * (1.0 + 0.04 * grain[walk][:, None])
    tree[walk] = S.tree_street
    no_parking = np.zeros((H, W), bool)
    if S.bus_lanes:
        no_parking |= cd.bus_lanes(rgb, on_u & ~on_v, du, hu, dv, hv, wu[ku], S)
        no_parking |= cd.bus_lanes(rgb, on_v & ~on_u, dv, hv, du, hu, wv[kv], S)
    _markings(rgb, u, v, du, hu, dv, hv, on_u, on_v, wu[ku], wv[kv], S)
    _street_cars(
        cv, u, v, du, hu, dv, hv, on_u & ~no_parking, on_v & ~no_parking, ku, kv, seed, change
    )
    del no_parking

    # Blocks.
    lu = u - ulo - 0.5 * wu[ku] - sw
    lv = v - vlo - 0.5 * wv[kv] - sw
    bw = (uhi - ulo) - 0.5 * (wu[ku] + wu[ku + 1]) - 2 * sw
    bh = (vhi - vlo) - 0.5 * (wv[kv] + wv[kv + 1]) - 2 * sw
    inner = ~road & ~walk
    bkey = ku.astype(np.int64) * 100003 + kv.astype(np.int64)
    btable, dtable = _block_types(S, seed, change, ul, vl, ang)
    btype = btable[ku, kv]
    district = dtable[ku, kv]
    park_a = smooth_noise(rng("park_a"), shape, 60.0 / mpp)
    park_b = smooth_noise(rng("park_b"), shape, 90.0 / mpp)
    flat = np.flatnonzero(inner.ravel())
    bt = btype.ravel()[flat]
    # Texels are independent given their block keys, so each type is filled in chunks of 1M
    # texels: same result, a fraction of the temporary memory.
    jobs = [
        (t, name, sel)
        for t, name in enumerate(BLOCK_TYPES)
        for sel in np.array_split(flat[bt == t], max(1, int(np.ceil(np.sum(bt == t) / 1e6))))
    ]
    for _t, name, sel in jobs:
        if sel.size == 0:
            continue
        P = cb.BlockPixels(
            sel,
            lu.ravel()[sel],
            lv.ravel()[sel],
            bw.ravel()[sel],
            bh.ravel()[sel],
            bkey.ravel()[sel],
            district.ravel()[sel],
        )
        if name in ("terrace", "slab"):
            cb.fill_terrace(S, cv, P, high=name == "slab")
        elif name == "detached":
            cb.fill_detached(S, cv, P)
        elif name == "warehouse":
            ci.fill_warehouse(S, cv, P)
        elif name == "park":
            cb.fill_park(S, cv, P, park_a.ravel()[sel], park_b.ravel()[sel])
        elif name == "parking":
            cb.fill_parking(S, cv, P)
        elif name == "lawn":
            cd.fill_lawn(S, cv, P)
        else:
            cd.fill_plaza(S, cv, P)
    del lu, lv, bw, bh, park_a, park_b, district

    rail = np.zeros((H, W), bool)
    if S.railway:
        major = (on_u & (wu[ku] >= S.road_major)) | (on_v & (wv[kv] >= S.road_major))
        rail = cd.add_railway(rng("railway"), cv, E, N, major.ravel(), 0.5 * H * mpp, S)
        rail = rail.reshape(H, W)
        del major

    # River: water band, grassy banks with a towpath, major streets bridge it.
    if S.river_width > 0:
        d, ang_r = river_distance(rng("river"), E, N, 0.5 * H * mpp, S.river_width)
        half = 0.5 * S.river_width
        valley = np.exp(-((d / (3.0 * S.river_width)) ** 2)).astype(np.float32)
        ground -= 3.0 * valley
        bank = (d < half + 14.0) & (d >= half)
        # Bridges: every other major street of the family that crosses the river most squarely.
        cross_u = abs(math.cos(ang + math.pi / 2 - ang_r)) < abs(math.cos(ang - ang_r))
        if cross_u:
            lines = on_u & (wu[ku] >= S.road_major) & (hash01(ku, seed, 61) < 0.5)
        else:
            lines = on_v & (wv[kv] >= S.road_major) & (hash01(kv, seed, 61) < 0.5)
        bridge = (d < half + 14.0) & (lines | rail)
        water = (d < half) & ~bridge
        grass = np.asarray(S.grass, np.float32)
        sel = bank & ~bridge
        rgb[sel] = grass * (0.95 + 0.08 * grain[sel][:, None])
        path = sel & (np.abs(d - half - 7.0) < 1.2)
        rgb[path] = np.float32((180, 170, 150))
        mat[sel] = MAT_GROUND
        struct[sel] = 0.0
        tree[sel] = S.tree_park * 0.6
        tree[path] = 0.0
        rgb[water] = np.asarray(S.water, np.float32) * (1.0 + 0.03 * grain[water][:, None])
        mat[water] = MAT_WATER
        struct[water] = -1.2
        tree[water] = 0.0
        struct[bridge & (d < half + 2.0)] = 1.0
    tint = np.asarray(SEASON_GRASS[season], np.float32)
    green = (mat == MAT_GROUND) & (rgb[..., 1] > rgb[..., 0] * 1.15)
    rgb[green] *= tint

    tree_h = plant_trees(tree, rgb, mat, grain, S, seed, change, season, mpp)
    height = ground + np.maximum(struct, tree_h)
    pal = facade_palette(S, rng("palette"))
    orient = np.where(mat >= MAT_BUILDING, orient, 0).astype(np.uint8)
    return Rasters(height.astype(np.float32), ground, rgb, mat, orient, pal)


def _block_types(S: Style, seed: int, change: int, ul, vl, ang: float):
    """Block type and district value per (ku, kv) grid cell.

    The district value in [0, 1] is a smooth field (three random plane waves, ~1-2 km) evaluated
    at the block centre: high = dense and tall (slabs, terraces), low = green (parks, lawns,
    houses). It gives the city large-scale structure instead of i.i.d. blocks.
    """
    r = rng_for(S.name, seed, "district")
    cu = 0.5 * (ul[:-1] + ul[1:])[:, None]
    cvv = 0.5 * (vl[:-1] + vl[1:])[None, :]
    E = cu * math.cos(ang) - cvv * math.sin(ang)
    N = cu * math.sin(ang) + cvv * math.cos(ang)
    acc = np.zeros(np.broadcast(E, N).shape)
    for _ in range(3):
        k = 2 * math.pi / r.uniform(1200.0, 2400.0)
        a = r.uniform(0, 2 * math.pi)
        acc += np.sin(k * (E * math.cos(a) + N * math.sin(a)) + r.uniform(0, 2 * math.pi))
    dist = np.clip(0.5 + acc / 3.0, 0.0, 1.0)
    base = np.array(
        [
            S.p_terrace,
            S.p_detached,
            S.p_slab,
            S.p_warehouse,
            S.p_park,
            S.p_parking,
            S.p_lawn,
            S.p_plaza,
        ]
    )
    # How each type responds to the district value (dense ... green).
    gain = np.stack(
        [
            np.ones_like(dist),
            1.5 - dist,
            0.2 + 1.6 * dist,
            np.ones_like(dist),
            1.9 - 1.7 * dist,
            np.ones_like(dist),
            1.9 - 1.7 * dist,
            0.3 + dist,
        ],
        axis=-1,
    )
    w = base * gain
    cum = np.cumsum(w / w.sum(axis=-1, keepdims=True), axis=-1)
    ku, kv = np.meshgrid(np.arange(len(ul) - 1), np.arange(len(vl) - 1), indexing="ij")
    key = ku.astype(np.int64) * 100003 + kv
    u = hash01(key, seed, 7)
    btype = (u[..., None] > cum).sum(axis=-1).clip(0, len(base) - 1)
    if change:  # open land built on by the later date is still open in the earlier image, etc.
        flip = hash01(key, change, 8) < 0.06
        btype = np.where(flip & (btype >= 4), 3 if S.p_warehouse > 0 else 2, btype)
    return btype, dist


def _markings(rgb, u, v, du, hu, dv, hv, on_u, on_v, w_u, w_v, S: Style) -> None:
    """Dashed centre lines, lane lines on major roads, zebra crossings; 0.15 m lines are drawn with
    their texel coverage (anti-aliased), so they read as faint lines at 1 m/px, as in real
    imagery."""
    white = np.float32(235.0)
    mpp_cov = 1.0

    def cover(dist, width):
        return np.clip(0.5 + (0.5 * width - dist) / mpp_cov, 0.0, 1.0)

    only_u = on_u & ~on_v & (dv > hv + 3.0)
    only_v = on_v & ~on_u & (du > hu + 3.0)
    for only, d, half, along, width in ((only_u, du, hu, v, w_u), (only_v, dv, hv, u, w_v)):
        dash = ((along / 9.0) % 1.0) < 0.4
        c = cover(d, 0.3) * dash
        major = width >= S.road_major
        lane = np.abs(d - 0.5 * half)
        c = np.maximum(c, cover(lane, 0.3) * dash * major)
        edge = np.abs(d - (half - 0.6))
        c = np.maximum(c, cover(edge, 0.3) * major)
        c = np.where(only, c, 0.0).astype(np.float32)
        sel = c > 0
        rgb[sel] = rgb[sel] * (1.0 - c[sel, None]) + white * c[sel, None]
    # Zebra crossings just before intersections on major roads.
    for on, d, half, dist_other, half_other, width in (
        (on_u, du, hu, dv, hv, w_u),
        (on_v, dv, hv, du, hu, w_v),
    ):
        band = (
            on
            & (dist_other > half_other + S.sidewalk + 0.5)
            & (dist_other < half_other + S.sidewalk + 3.5)
            & (width >= S.road_major)
        )
        stripe = band & ((d % 1.2) < 0.6) & (d < half - 0.4)
        rgb[stripe] = white * 0.95


def _street_cars(cv, u, v, du, hu, dv, hv, on_u, on_v, ku, kv, seed, change) -> None:
    """Cars parked along the kerbs, 6 m slots, the occupancy re-drawn in a changed city."""
    for on, d, half, along, other, half_o, k in (
        (on_u, du, hu, v, dv, hv, ku),
        (on_v, dv, hv, u, du, hu, kv),
    ):
        lane = on & (d > half - 2.3) & (d < half - 0.4) & (other > half_o + 6.0)
        slot = np.floor(along / 6.0).astype(np.int64)
        pos = along - (slot + 0.5) * 6.0
        side = (d > 0).astype(np.int64)
        idx = np.flatnonzero((lane & (np.abs(pos) < 2.25)).ravel())
        key = k.ravel()[idx] * 7919 + slot.ravel()[idx] * 2 + side.ravel()[idx]
        occ = hash01(key, seed, change, 31) < 0.45
        idx = idx[occ]
        key = key[occ]
        col = cb.pick(cb.CAR_COLOURS, hash01(key, seed, change, 32))
        p = np.abs(pos.ravel()[idx])
        glass = (p > 0.3) & (p < 1.0)
        col = np.where(glass[:, None], col * 0.35 + 20.0, col)
        cv.rgb[idx] = col
        cv.struct[idx] = 1.5
        cv.mat[idx] = MAT_SMALL
