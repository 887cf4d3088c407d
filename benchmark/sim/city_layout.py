"""City assembly: from (style, seed) to height, albedo and material rasters.

The street network (city_districts.py) is a patchwork of districts separated by arterial roads,
each with its own grid angle and pitches (grids warped by smooth noise, organic old cores, radial
streets round greens). For every texel it gives the distance to the nearest street centrelines
(carriageway, kerb, pavement, markings, parked cars), the block and the local block coordinates,
which the block programmes (city_blocks.py, ...) turn into buildings, gardens, parks, lots. A
river band (city_nature.py) overrides it; major streets bridge it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from benchmark.sim import city_blocks as cb
from benchmark.sim import city_details as cd
from benchmark.sim import city_industry as ci
from benchmark.sim import detmath
from benchmark.sim.city_districts import KEY_BASE, Streets, rng_for, street_fields
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

    # Street network: districts with their own grids (city_districts.py).
    F = street_fields(
        S,
        seed,
        E,
        N,
        mpp,
        lambda keys, ce, cn: _block_types(S, seed, change, keys, ce, cn),
        BLOCK_TYPES.index("park"),
    )
    # Wall direction (mod 90 deg) = direction of grad u, quantised to 2.8 deg steps so a parcel's
    # walls share one direction (the window grid is laid out along it). Across district
    # boundaries grad u is meaningless, but those texels are arterial roads, never walls.
    gu_n, gu_e = np.gradient(F.u)
    theta_u = detmath.arctan2(gu_n, gu_e).astype(np.float32)
    del gu_e, gu_n
    theta = np.mod(theta_u, math.pi / 2)
    orient = ((np.round(theta / (math.pi / 2) * 32.0) % 32) * 8).astype(np.uint8)
    del theta
    du, dv, hu, hv = F.du, F.dv, F.hu, F.hv
    on_u = du < hu  # on a street running along v (constant u)
    on_v = dv < hv
    on_a = F.art < F.art_half  # on a district-boundary arterial
    sw = S.sidewalk
    # The carriageway of an irregular edge (arterial, or a circus' outer ring seen from the
    # grid outside it) is everything beyond its pavement.
    road = on_u | on_v | on_a | (F.edge < -sw)
    walk = ~road & ((du < hu + sw) | (dv < hv + sw) | (F.edge < 0))
    # Slivers between a grid street and the arterial too narrow to build on become pavement.
    dgrid = np.minimum(np.minimum(F.lu, F.lv), np.minimum(F.bw - F.lu, F.bh - F.lv))
    walk |= ~road & (F.edge < 9.0) & (F.edge + dgrid < 14.0)
    del dgrid

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

    # Carriageway, kerbs and pavements; boulevard trees along the arterials.
    asph = np.asarray(S.asphalt, np.float32)
    rgb[:] = asph * (1.0 + 0.05 * grain[..., None])
    pav = np.asarray(S.pavement, np.float32)
    rgb[walk] = pav * (1.0 + 0.04 * grain[walk][:, None])
    tree[walk] = S.tree_street
    tree[walk & (F.edge < 0)] = min(1.0, 3.0 * S.tree_street + 0.05)
    no_parking = np.zeros((H, W), bool)
    if S.bus_lanes:
        no_parking |= cd.bus_lanes(rgb, on_u & ~on_v & ~on_a, du, hu, dv, hv, 2 * hu, S)
        no_parking |= cd.bus_lanes(rgb, on_v & ~on_u & ~on_a, dv, hv, du, hu, 2 * hv, S)
    _markings(rgb, F, on_u & ~on_a, on_v & ~on_a, S)
    _arterial_markings(rgb, F, on_a)
    near_a = F.art < F.art_half + 6.0
    _street_cars(
        cv,
        F,
        on_u & ~no_parking & ~near_a,
        on_v & ~no_parking & ~near_a,
        seed,
        change,
    )
    del no_parking, near_a

    # Blocks.
    inner = ~road & ~walk
    park_a = smooth_noise(rng("park_a"), shape, 60.0 / mpp)
    park_b = smooth_noise(rng("park_b"), shape, 90.0 / mpp)
    flat = np.flatnonzero(inner.ravel())
    bt = F.btype.ravel()[flat]
    bkey_all = (F.ksu.ravel()[flat].astype(np.int64) * KEY_BASE) + (F.ksv.ravel()[flat] % KEY_BASE)
    # Texels are independent given their block keys (parcel-level choices only look at texels
    # of the same block), so each type is filled in chunks of about 1M texels split by block
    # key: same result, a fraction of the temporary memory.
    for t, name in enumerate(BLOCK_TYPES):
        sel_t = flat[bt == t]
        if sel_t.size == 0:
            continue
        keys_t = bkey_all[bt == t]
        n_chunks = max(1, int(np.ceil(sel_t.size / 1e6)))
        chunk = keys_t % n_chunks
        for c in range(n_chunks):
            sel = sel_t[chunk == c]
            if sel.size == 0:
                continue
            P = cb.BlockPixels(
                sel,
                F.lu.ravel()[sel],
                F.lv.ravel()[sel],
                F.bw.ravel()[sel],
                F.bh.ravel()[sel],
                keys_t[chunk == c],
                F.dens.ravel()[sel],
                F.edge.ravel()[sel],
                F.art_along.ravel()[sel],
            )
            _fill(S, cv, P, name, park_a.ravel()[sel], park_b.ravel()[sel])
    del park_a, park_b, flat, bt, bkey_all

    rail = np.zeros((H, W), bool)
    if S.railway:
        major = (on_u & (hu >= 0.5 * S.road_major)) | (on_v & (hv >= 0.5 * S.road_major)) | on_a
        rail = cd.add_railway(rng("railway"), cv, E, N, major.ravel(), 0.5 * H * mpp, S)
        rail = rail.reshape(H, W)
        del major

    # River: water band, grassy banks with a towpath, major streets bridge it.
    if S.river_width > 0:
        d, ang_r = river_distance(rng("river"), E, N, 0.5 * H * mpp, S.river_width)
        half = 0.5 * S.river_width
        valley = detmath.exp(-((d / (3.0 * S.river_width)) ** 2)).astype(np.float32)
        ground -= 3.0 * valley
        bank = (d < half + 14.0) & (d >= half)
        # Bridges: every other major street of the family that crosses the river most squarely
        # in its district (grad u along the river: the constant-u streets cross it).
        cross_u = np.abs(detmath.cos(theta_u - ang_r)) > np.abs(detmath.sin(theta_u - ang_r))
        major_u = on_u & (hu >= 0.5 * S.road_major) & (hash01(F.ksu, seed, 61) < 0.5)
        major_v = on_v & (hv >= 0.5 * S.road_major) & (hash01(F.ksv, seed, 61) < 0.5)
        lines = np.where(cross_u, major_u, major_v) & ~on_a
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
    del F, theta_u
    tint = np.asarray(SEASON_GRASS[season], np.float32)
    green = (mat == MAT_GROUND) & (rgb[..., 1] > rgb[..., 0] * 1.15)
    rgb[green] *= tint

    tree_h = plant_trees(tree, rgb, mat, grain, S, seed, change, season, mpp)
    height = ground + np.maximum(struct, tree_h)
    pal = facade_palette(S, rng("palette"))
    orient = np.where(mat >= MAT_BUILDING, orient, 0).astype(np.uint8)
    return Rasters(height.astype(np.float32), ground, rgb, mat, orient, pal)


def _fill(S: Style, cv: cb.Canvas, P: cb.BlockPixels, name: str, park_a, park_b) -> None:
    if name in ("terrace", "slab"):
        cb.fill_terrace(S, cv, P, high=name == "slab")
    elif name == "detached":
        cb.fill_detached(S, cv, P)
    elif name == "warehouse":
        ci.fill_warehouse(S, cv, P)
    elif name == "park":
        cb.fill_park(S, cv, P, park_a, park_b)
    elif name == "parking":
        cb.fill_parking(S, cv, P)
    elif name == "lawn":
        cd.fill_lawn(S, cv, P)
    else:
        cd.fill_plaza(S, cv, P)


def _block_types(S: Style, seed: int, change: int, keys, ce, cn):
    """Block type and density value of blocks from their int64 keys and centres (E, N metres).

    The density value in [0, 1] is a smooth field (three random plane waves, ~1-2 km) evaluated
    at the block centre: high = dense and tall (slabs, terraces), low = green (parks, lawns,
    houses). It gives the city large-scale structure instead of i.i.d. blocks.
    """
    r = rng_for(S.name, seed, "district")
    E = np.asarray(ce, np.float64)
    N = np.asarray(cn, np.float64)
    acc = np.zeros(np.broadcast(E, N).shape)
    for _ in range(3):
        k = 2 * math.pi / r.uniform(1200.0, 2400.0)
        a = r.uniform(0, 2 * math.pi)
        acc += detmath.sin(k * (E * math.cos(a) + N * math.sin(a)) + r.uniform(0, 2 * math.pi))
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
    key = np.broadcast_to(np.asarray(keys, np.int64), dist.shape)
    u = hash01(key, seed, 7)
    btype = (u[..., None] > cum).sum(axis=-1).clip(0, len(base) - 1)
    if change:  # open land built on by the later date is still open in the earlier image, etc.
        flip = hash01(key, change, 8) < 0.06
        btype = np.where(flip & (btype >= 4), 3 if S.p_warehouse > 0 else 2, btype)
    return btype, dist


def _markings(rgb, F: Streets, on_u, on_v, S: Style) -> None:
    """Dashed centre lines, lane lines on major roads, zebra crossings; 0.15 m lines are drawn with
    their texel coverage (anti-aliased), so they read as faint lines at 1 m/px, as in real
    imagery."""
    white = np.float32(235.0)
    mpp_cov = 1.0
    u, v, du, hu, dv, hv = F.u, F.v, F.du, F.hu, F.dv, F.hv

    def cover(dist, width):
        return np.clip(0.5 + (0.5 * width - dist) / mpp_cov, 0.0, 1.0)

    only_u = on_u & ~on_v & (dv > hv + 3.0)
    only_v = on_v & ~on_u & (du > hu + 3.0)
    for only, d, half, along in ((only_u, du, hu, v), (only_v, dv, hv, u)):
        dash = ((along / 9.0) % 1.0) < 0.4
        c = cover(d, 0.3) * dash
        major = half >= 0.5 * S.road_major
        lane = np.abs(d - 0.5 * half)
        c = np.maximum(c, cover(lane, 0.3) * dash * major)
        edge = np.abs(d - (half - 0.6))
        c = np.maximum(c, cover(edge, 0.3) * major)
        c = np.where(only, c, 0.0).astype(np.float32)
        sel = c > 0
        rgb[sel] = rgb[sel] * (1.0 - c[sel, None]) + white * c[sel, None]
    # Zebra crossings just before intersections on major roads.
    for on, d, half, dist_other, half_other in ((on_u, du, hu, dv, hv), (on_v, dv, hv, du, hu)):
        band = (
            on
            & (dist_other > half_other + S.sidewalk + 0.5)
            & (dist_other < half_other + S.sidewalk + 3.5)
            & (half >= 0.5 * S.road_major)
        )
        stripe = band & ((d % 1.2) < 0.6) & (d < half - 0.4)
        rgb[stripe] = white * 0.95


def _arterial_markings(rgb, F: Streets, on_a) -> None:
    """District-boundary arterials: dashed centre line, lane lines and solid edge lines."""
    half = F.art_half
    d = F.art[on_a]
    dash = ((F.art_along[on_a] / 9.0) % 1.0) < 0.4
    c = np.clip(0.5 + 0.15 - d, 0.0, 1.0) * dash
    c = np.maximum(c, np.clip(0.5 + 0.15 - np.abs(d - 0.5 * half), 0.0, 1.0) * dash)
    c = np.maximum(c, np.clip(0.5 + 0.15 - np.abs(d - (half - 0.6)), 0.0, 1.0))
    cols = rgb[on_a]
    rgb[on_a] = cols * (1.0 - c[:, None]) + np.float32(235.0) * c[:, None]


def _street_cars(cv, F: Streets, on_u, on_v, seed, change) -> None:
    """Cars parked along the kerbs, 6 m slots, the occupancy re-drawn in a changed city."""
    for on, d, half, along, other, half_o, k in (
        (on_u, F.du, F.hu, F.v, F.dv, F.hv, F.ksu),
        (on_v, F.dv, F.hv, F.u, F.du, F.hu, F.ksv),
    ):
        lane = on & (d > half - 2.3) & (d < half - 0.4) & (other > half_o + 6.0)
        slot = np.floor(along / 6.0).astype(np.int64)
        pos = along - (slot + 0.5) * 6.0
        side = (d > 0).astype(np.int64)
        idx = np.flatnonzero((lane & (np.abs(pos) < 2.25)).ravel())
        key = k.ravel()[idx].astype(np.int64) * 7919 + slot.ravel()[idx] * 2 + side.ravel()[idx]
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
