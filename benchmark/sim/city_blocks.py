"""Block programmes: what fills one street block (terraces, houses, slabs, warehouses, parks, ...).

Each ``fill_*`` function receives the texels of all blocks of its type as flat arrays
(``BlockPixels``: local coordinates ``lu, lv`` in metres from the block's lower-left interior
corner, block size ``bw, bh``, block key) and writes structure height above ground, albedo,
material, tree probability into the ``Canvas``. Every random choice is a ``hash01`` of integer keys
(block, parcel, slot, ...), so a changed city (``Canvas.change != 0``) can re-draw cars, demolish or
add a few buildings without reshuffling the rest.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from benchmark.sim import detmath
from benchmark.sim.render_core import MAT_BUILDING, MAT_GROUND, MAT_SMALL, MAT_TREE, MAT_WATER
from benchmark.sim.textures import hash01
from benchmark.sim.world_styles import Style

MAX_EAVE_M = 50.0  # flights are >= 70 m above ground: keep 20 m of clearance
CAR_COLOURS = np.array(
    [
        (228, 228, 226),
        (30, 32, 36),
        (170, 172, 176),
        (112, 114, 118),
        (150, 28, 30),
        (36, 58, 120),
        (40, 70, 52),
        (210, 200, 180),
        (60, 60, 64),
        (200, 200, 204),
    ],
    np.float32,
)
TRAILER_COLOURS = np.array(
    [(232, 232, 230), (200, 202, 206), (40, 80, 140), (170, 40, 36), (226, 226, 220)], np.float32
)


@dataclass
class Canvas:
    """Flat (H*W) views of the city rasters being generated, plus the generation keys."""

    struct: np.ndarray  # float32, structure height above ground, metres
    rgb: np.ndarray  # float32 (H*W, 3) albedo
    mat: np.ndarray  # uint8 material codes (render_core.MAT_*)
    tree: np.ndarray  # float32 tree-candidate acceptance probability
    grain: np.ndarray  # float32 per-texel noise in [-1, 1]
    seed: int
    change: int  # 0 = the city as flown; != 0 = the same city at an earlier time
    n_palette: int


@dataclass
class BlockPixels:
    idx: np.ndarray  # flat texel indices
    lu: np.ndarray
    lv: np.ndarray
    bw: np.ndarray
    bh: np.ndarray
    key: np.ndarray  # int64 block key
    district: np.ndarray  # [0, 1]: 1 = dense, tall district; 0 = green, low district
    edge: (
        np.ndarray
    )  # metres to an irregular block edge (district-boundary arterial), large if none
    edge_along: np.ndarray  # metres along that edge (parcel frontage coordinate)


def touching(key: np.ndarray, mask: np.ndarray, near: np.ndarray) -> np.ndarray:
    """Texels of ``mask`` whose object (same ``key``) has any texel in ``mask & near``.

    Objects (houses, sheds, containers, pitches) cut by an irregular block edge are removed whole
    with this (``mask & ~touching(...)``) instead of being cut in half. Exact as long as an object
    never straddles two fill chunks, which city_layout guarantees (chunks split by block key).
    """
    bad = mask & near
    if not bad.any():
        return np.zeros_like(mask)
    return mask & np.isin(key, np.unique(key[bad]))


def lerp(lo_hi: tuple[float, float], t: np.ndarray) -> np.ndarray:
    return lo_hi[0] + (lo_hi[1] - lo_hi[0]) * t


def pick(colours: Sequence[Sequence[float]], t: np.ndarray) -> np.ndarray:
    table = np.asarray(colours, np.float32)
    return table[np.minimum((t * len(table)).astype(np.int64), len(table) - 1)]


def _jitter(c: np.ndarray, t: np.ndarray, amount: float) -> np.ndarray:
    return c * (1.0 + amount * (t[:, None] - 0.5) * 2.0).astype(np.float32)


def _set(cv: Canvas, idx, sel, *, struct=None, rgb=None, mat=None, tree=None):
    ii = idx[sel]
    if struct is not None:
        cv.struct[ii] = struct[sel] if np.ndim(struct) else struct
    if rgb is not None:
        cv.rgb[ii] = rgb[sel] if np.ndim(rgb) == 2 else rgb
    if mat is not None:
        cv.mat[ii] = mat[sel] if np.ndim(mat) else mat
    if tree is not None:
        cv.tree[ii] = tree


def _grass(S: Style, cv: Canvas, P: BlockPixels, sel, density: float):
    g = cv.grain[P.idx[sel]]
    col = np.asarray(S.grass, np.float32)[None, :] * (1.0 + 0.08 * g[:, None])
    cv.rgb[P.idx[sel]] = col
    cv.mat[P.idx[sel]] = MAT_GROUND
    cv.tree[P.idx[sel]] = density


def _buildings(S: Style, cv: Canvas, P: BlockPixels, inb, pkey, eave, roof, gable, high: bool):
    """Write building texels: heights, roof albedo, material with the palette row."""
    hp = hash01(pkey, cv.seed, 41)
    flat_c = pick(S.flat_roof_colours, hash01(pkey, cv.seed, 42))
    gab_c = pick(S.roof_colours, hash01(pkey, cv.seed, 43))
    col = np.where(gable[:, None], gab_c, flat_c)
    col = _jitter(col, hp, 0.07) * (1.0 + 0.05 * cv.grain[P.idx][:, None])
    row = (hash01(pkey, cv.seed, 44) * cv.n_palette).astype(np.int64)
    if cv.change:
        # The earlier city: demolish some buildings (bare soil) and build on some gaps.
        gone = hash01(pkey, cv.change, 51) < (0.10 if high else 0.05)
        inb = inb & ~gone
        soil = np.asarray(S.soil, np.float32) * (1.0 + 0.1 * cv.grain[P.idx[gone]][:, None])
        cv.rgb[P.idx[gone]] = soil
        cv.mat[P.idx[gone]] = MAT_GROUND
        cv.struct[P.idx[gone]] = 0.0
    _set(
        cv,
        P.idx,
        inb,
        struct=roof.astype(np.float32),
        rgb=col,
        mat=(MAT_BUILDING + row).astype(np.uint8),
        tree=0.0,
    )
    return inb


def _roof_details(S: Style, cv: Canvas, P: BlockPixels, roof, pkey, d, along, D, pw, chim):
    """Solar panels on the street-side slope of some gabled roofs (fewer in the earlier city) and
    brick-coloured chimney stacks."""
    solar = hash01(pkey, cv.seed, 15) < S.solar_prob
    if cv.change:
        solar &= hash01(pkey, cv.change, 16) < 0.5  # many panels were installed later
    panel = roof & solar & (d > 1.2) & (d < 0.5 * D - 1.0) & (np.abs(along) < 0.3 * pw)
    grid = ((d % 1.7) < 0.15) | ((along % 1.1) < 0.12)
    colour = np.where(grid[:, None], np.float32((70, 76, 90)), np.float32((34, 42, 66)))
    _set(cv, P.idx, panel, rgb=colour)
    _set(cv, P.idx, chim, rgb=np.asarray((128, 74, 58), np.float32))


def fill_terrace(S: Style, cv: Canvas, P: BlockPixels, high: bool) -> None:
    """Buildings round the block perimeter (terraces, or slabs when ``high``), gardens inside.

    An irregular block edge (a district-boundary arterial) is a fifth side: the terraces turn to
    face it, their parcels laid out along it."""
    hb = lambda k: hash01(P.key, cv.seed, k)  # noqa: E731
    D = np.minimum(lerp(S.depth, hb(1)), 0.5 * np.minimum(P.bw, P.bh))
    e = np.stack([P.lu, P.lv, P.bw - P.lu, P.bh - P.lv, P.edge])
    side = np.argmin(e, axis=0)
    d = np.min(e, axis=0)
    along = np.where(side == 4, P.edge_along, np.where(side % 2 == 0, P.lv, P.lu))
    pw = lerp(S.parcel, hb(2))
    pidx = np.floor(along / pw + hb(3)).astype(np.int64)
    pkey = P.key * 1009 + side * 211 + pidx
    hp = lambda k: hash01(pkey, cv.seed, k)  # noqa: E731
    gap = hp(5) < (0.04 if high else 0.07)
    if cv.change:
        gap = gap & ~(hash01(pkey, cv.change, 52) < 0.5)
    eave = lerp(S.height_high if high else S.height_low, hp(6)) * (0.8 + 0.4 * P.district)
    eave = np.minimum(eave, MAX_EAVE_M)
    gable = (hp(7) < (S.gable_prob * (0.3 if high else 1.0))) & (D < 16.0)
    pitch = detmath.tan(np.radians(lerp((30.0, 45.0), hp(8))))
    ridge = pitch * (0.5 * D - np.abs(d - 0.5 * D))
    roof = eave + np.where(gable, ridge, 0.0)
    inb = (d < D) & ~gap & (P.bw > 8.0) & (P.bh > 8.0)
    if high:
        # Some slabs carry a recessed upper block (podium + setback storeys).
        flat = inb & ~gable
        setback = flat & (hp(17) < 0.35) & (d > 3.5) & (d < D - 3.5)
        extra = np.minimum(lerp((6.0, 14.0), hp(18)), MAX_EAVE_M + 4.0 - eave)
        roof = roof + np.where(setback, np.maximum(extra, 0.0), 0.0)
        # Parapets and rooftop plant on flat roofs.
        cell = 9.0
        cu = np.floor(P.lu / cell)
        cvv = np.floor(P.lv / cell)
        unit = (
            (hash01(P.key, cu, cvv, cv.seed) < 0.3)
            & (np.abs(P.lu - (cu + 0.5) * cell) < 1.6)
            & (np.abs(P.lv - (cvv + 0.5) * cell) < 1.1)
            & (d > 2.5)
            & (d < D - 2.5)
        )
        roof = (
            roof
            + np.where(flat & unit, 2.2, 0.0)
            + np.where(flat & ((d < 0.7) | (np.abs(d - D) < 0.7)), 0.8, 0.0)
        )
    # Rear extensions into the courtyard: narrower, 3-4 m, flat, on about half the parcels.
    pc = (pidx - hb(3) + 0.5) * pw
    ext_d = lerp((3.0, 7.0), hp(12))
    ext = (
        (d >= D)
        & (d < D + ext_d)
        & (np.abs(along - pc) < 0.3 * pw)
        & (hp(13) < S.p_extension)
        & ~gap
        & (0.5 * np.minimum(P.bw, P.bh) > D + ext_d + 3.0)
    )
    ext_h = lerp((3.0, 4.2), hp(14))
    roof = np.where(ext, ext_h, roof)
    gable = gable & ~ext
    inb = inb | ext
    # Chimney stacks on the ridge at the parcel walls of gabled terraces.
    chim = gable & inb & (np.abs(d - 0.5 * D) < 0.9) & ((along - (pc - 0.5 * pw)) < 1.6)
    roof = np.where(chim, eave + pitch * 0.5 * D + 1.2, roof)
    inb = _buildings(S, cv, P, inb, pkey, eave, roof, gable, high)
    _roof_details(S, cv, P, inb & gable & ~chim, pkey, d, along - pc, D, pw, chim & inb)
    ins = ((d >= D) | gap) & ~inb
    # Courtyards: gardens, or paved service yards.
    paved = hash01(P.key, cv.seed, 9) < (S.paved_yard if high else 0.5 * S.paved_yard)
    yard = ins & paved
    g = cv.grain[P.idx]
    pav = np.asarray(S.pavement, np.float32)[None, :] * (0.92 + 0.05 * g[:, None])
    _set(cv, P.idx, yard, rgb=pav, mat=MAT_GROUND, tree=S.tree_garden * 0.5)
    _grass(S, cv, P, ins & ~paved, S.tree_garden)


def fill_detached(S: Style, cv: Canvas, P: BlockPixels) -> None:
    """Detached houses with gabled roofs in gardens along both long sides; hedges, driveways."""
    south = P.lv < 0.5 * P.bh
    b = np.where(south, P.lv, P.bh - P.lv)
    lw = lerp(S.parcel, hash01(P.key, cv.seed, 1))
    lot = np.floor(P.lu / lw).astype(np.int64)
    a = P.lu - lot * lw
    pkey = P.key * 1009 + south * 211 + lot
    hp = lambda k: hash01(pkey, cv.seed, k)  # noqa: E731
    hw = np.minimum(lerp((8.0, 12.0), hp(2)), lw - 5.0)
    hd = lerp((8.0, 11.0), hp(3))
    sb = lerp((4.0, 8.0), hp(4))
    xo = lerp((-1.5, 1.5), hp(5))
    ac = a - 0.5 * lw - xo
    inh = (np.abs(ac) < 0.5 * hw) & (b > sb) & (b < sb + hd) & (0.5 * P.bh > sb + hd + 4)
    inh &= P.lu < P.bw - 2.0
    inh &= ~touching(pkey, inh, P.edge < 2.0)  # whole houses only along a district boundary
    eave = lerp(S.height_low, hp(6))
    pitch = detmath.tan(np.radians(lerp((32.0, 45.0), hp(7))))
    ridge_across = hp(8) < 0.25  # some houses have the ridge perpendicular to the street
    r1 = pitch * (0.5 * hd - np.abs(b - sb - 0.5 * hd))
    r2 = pitch * (0.5 * hw - np.abs(ac))
    gable = np.ones_like(inh)
    roof = eave + np.where(ridge_across, r2, r1)
    g = cv.grain[P.idx]
    _grass(S, cv, P, ~inh, np.where(b > sb + hd + 3, S.tree_garden, 0.01).astype(np.float32)[~inh])
    drive = (ac > 0.5 * hw + 0.5) & (ac < 0.5 * hw + 3.5) & (b < sb + hd)
    pav = np.asarray(S.pavement, np.float32)[None, :] * (0.85 + 0.05 * g[:, None])
    _set(cv, P.idx, drive & ~inh, rgb=pav, mat=MAT_GROUND, tree=0.0)
    # A car on some driveways.
    car = drive & (hash01(pkey, cv.seed, cv.change, 9) < 0.45) & (b > 1.0) & (b < 5.4)
    car &= np.abs(ac - 0.5 * hw - 2.0) < 0.9
    car &= ~touching(pkey, car, P.edge < 1.0)
    ccol = pick(CAR_COLOURS, hash01(pkey, cv.seed, cv.change, 10))
    _set(cv, P.idx, car, struct=1.5, rgb=ccol, mat=MAT_SMALL)
    hedge = ((a < 0.7) | (b < 0.7)) & (b < 0.5 * P.bh - 0.5) & ~drive & (hp(11) < 0.7)
    hcol = np.asarray(S.tree, np.float32)[None, :] * (0.8 + 0.15 * g[:, None])
    _set(cv, P.idx, hedge & ~inh, struct=1.6, rgb=hcol, mat=MAT_TREE, tree=0.0)
    _buildings(S, cv, P, inh, pkey, eave, roof, gable, False)


def fill_parking(S: Style, cv: Canvas, P: BlockPixels) -> None:
    """Asphalt lot with stall lines and cars: rows of 5 m stalls either side of 6 m aisles."""
    g = cv.grain[P.idx]
    asph = np.asarray(S.asphalt, np.float32)[None, :] * (1.0 + 0.06 * g[:, None])
    border = (P.lu < 2.5) | (P.lv < 2.5) | (P.bw - P.lu < 2.5) | (P.bh - P.lv < 2.5)
    border |= P.edge < 2.5
    _set(cv, P.idx, ~border, rgb=asph, mat=MAT_GROUND, tree=0.0)
    _grass(S, cv, P, border, S.tree_park)
    y = (P.lv - 2.5) % 16.0
    row = np.floor((P.lv - 2.5) / 16.0).astype(np.int64)
    stall_row = (y < 5.0) | (y >= 11.0)
    b = np.where(y < 5.0, y, 16.0 - y)
    x = P.lu - 2.5
    stall = np.floor(x / 2.5).astype(np.int64)
    a = x - stall * 2.5
    inside = ~border & (P.lv < P.bh - 5.0)
    line = inside & stall_row & (a < 0.12 + 0.0 * a) & ~border
    cv.rgb[P.idx[line]] = np.float32(215.0)
    skey = (P.key * 131 + row) * 4099 + stall * 2 + (y < 5.0)
    occ = hash01(skey, cv.seed, cv.change, 21) < lerp((0.3, 0.9), hash01(P.key, cv.seed, 23))
    car = inside & stall_row & occ & (np.abs(a - 1.25) < 0.9) & (b > 0.4) & (b < 4.7)
    car &= ~touching(skey, car, border)
    ccol = pick(CAR_COLOURS, hash01(skey, cv.seed, cv.change, 22))
    glass = (b > 1.6) & (b < 2.4) | (b > 3.6) & (b < 4.1)
    ccol = np.where(glass[:, None], ccol * 0.35 + 20.0, ccol)
    _set(cv, P.idx, car, struct=1.5, rgb=ccol, mat=MAT_SMALL)


def fill_park(
    S: Style, cv: Canvas, P: BlockPixels, noise_a: np.ndarray, noise_b: np.ndarray
) -> None:
    """Grass with tree clumps, winding gravel paths (iso-lines of a noise field), maybe a pond."""
    clump = np.clip(0.5 + noise_b, 0.0, 1.0)
    _grass(S, cv, P, np.ones(P.idx.shape, bool), 0.0)
    cv.tree[P.idx] = (S.tree_park * (0.25 + 1.2 * clump)).astype(np.float32)
    path = (np.abs(noise_a) < 0.035) | (np.abs(noise_b - 0.1) < 0.02)
    gravel = np.asarray((196, 184, 156), np.float32)[None, :] * (
        1.0 + 0.06 * cv.grain[P.idx][:, None]
    )
    _set(cv, P.idx, path, rgb=gravel, tree=0.0)
    pond = (noise_a > 0.55) & (hash01(P.key, cv.seed, 3) < 0.5)
    wcol = np.asarray(S.water, np.float32)
    _set(cv, P.idx, pond, rgb=wcol, mat=MAT_WATER, struct=-0.8, tree=0.0)


__all__ = [
    "MAT_GROUND",
    "BlockPixels",
    "Canvas",
    "fill_detached",
    "fill_park",
    "fill_parking",
    "fill_terrace",
    "touching",
]
