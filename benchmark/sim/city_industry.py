"""Industrial plots: sheds with yards and trailers, container stacks, tank farms, truck parks.

The flight-test analogue of the paper (Sec. 3.5) is an industrial area whose satellite image shows
moved vehicles and trailers and changed structures, so trailers, containers and trucks are keyed
by ``Canvas.change`` (re-drawn in the earlier city) while sheds, tanks and yards persist unless a
demolition hits them (``city_blocks._buildings``).
"""

from __future__ import annotations

import numpy as np

from benchmark.sim import detmath
from benchmark.sim.city_blocks import (
    TRAILER_COLOURS,
    BlockPixels,
    Canvas,
    _buildings,
    _set,
    lerp,
    pick,
    touching,
)
from benchmark.sim.render_core import MAT_GROUND, MAT_SMALL
from benchmark.sim.textures import hash01
from benchmark.sim.world_styles import Style

SHED, CONTAINERS, TANKS, TRUCKS = 0, 1, 2, 3
# Plot kind probabilities per style (shed, containers, tanks, truck park).
S_KINDS = {
    "oxford": (1.0, 0.0, 0.0, 0.0),
    "cambridge": (1.0, 0.0, 0.0, 0.0),
    "london": (0.85, 0.1, 0.0, 0.05),
    "industrial": (0.78, 0.08, 0.06, 0.08),
}
CONTAINER_COLOURS = np.array(
    [
        (40, 80, 150),
        (170, 50, 40),
        (200, 120, 40),
        (60, 120, 70),
        (150, 150, 150),
        (220, 220, 214),
        (120, 60, 100),
    ],
    np.float32,
)


def _containers(cv: Canvas, P: BlockPixels, pkey, sel, xl, y, pl, W) -> None:
    """Rows of 12.2 x 2.44 m containers stacked 1-3 high (2.6 m each), 4 m aisles every 4 rows."""
    m = 5.0
    row = np.floor((y - m) / 2.74).astype(np.int64)
    col = np.floor((xl - m) / 12.7).astype(np.int64)
    ry = (y - m) - row * 2.74
    cx = (xl - m) - col * 12.7
    inside = sel & (xl > m) & (xl < pl - m) & (y > m) & (y < W - m) & (row % 5 != 4)
    box = inside & (ry < 2.44) & (cx < 12.2)
    skey = (pkey * 4099 + row) * 131 + col
    levels = np.floor(hash01(skey, cv.seed, cv.change, 91) * 4.0)  # 0 = empty slot
    box &= levels > 0
    box &= ~touching(skey, box, P.edge < 1.0)
    colour = pick(CONTAINER_COLOURS, hash01(skey, cv.seed, cv.change, 92))
    ribs = (cx % 0.6) < 0.15
    colour = colour * (1.0 - 0.12 * ribs)[:, None]
    _set(cv, P.idx, box, struct=(2.6 * levels).astype(np.float32), rgb=colour, mat=MAT_SMALL)
    gravel = np.float32((150, 144, 132)) * (1.0 + 0.06 * cv.grain[P.idx][:, None])
    _set(cv, P.idx, sel & ~box, rgb=gravel, mat=MAT_GROUND)


def _tanks(cv: Canvas, P: BlockPixels, pkey, sel, xl, y, pl, W) -> None:
    """A grid of round storage tanks (radius 6-11 m, 9-15 m high, slightly domed white roofs)."""
    r = lerp((6.0, 11.0), hash01(pkey, cv.seed, 93))
    pitch = 2.6 * r
    ci = np.floor((xl - 6.0) / pitch)
    cj = np.floor((y - 6.0) / pitch)
    dx = (xl - 6.0) - (ci + 0.5) * pitch
    dy = (y - 6.0) - (cj + 0.5) * pitch
    d = detmath.hypot(dx, dy)
    fits = ((ci + 1) * pitch + 6.0 < pl) & ((cj + 1) * pitch + 6.0 < W)
    tank = sel & (d < r) & fits & (hash01(pkey, ci, cj, cv.seed, 94) < 0.85)
    tkey = (pkey * 4099 + ci.astype(np.int64)) * 4099 + cj.astype(np.int64)
    tank &= ~touching(tkey, tank, P.edge < 2.0)
    h = lerp((9.0, 15.0), hash01(pkey, ci, cj, cv.seed, 95))
    roof = h + 1.5 * (1.0 - (d / r) ** 2)
    grey = np.where(hash01(pkey, cv.seed, 96) < 0.7, 226.0, 180.0).astype(np.float32)
    colour = np.repeat(grey[:, None], 3, axis=1)
    ring = np.abs(d - r * 0.7) < 0.4
    colour = colour * (1.0 - 0.15 * ring)[:, None]
    _set(cv, P.idx, tank, struct=roof.astype(np.float32), rgb=colour, mat=MAT_SMALL)
    bund = sel & ~tank & fits & (np.maximum(np.abs(dx), np.abs(dy)) > 0.5 * pitch - 1.0)
    _set(cv, P.idx, bund, struct=1.0, rgb=np.asarray((160, 156, 148), np.float32))


def fill_warehouse(S: Style, cv: Canvas, P: BlockPixels) -> None:
    """1-3 plots per block along its long side: big flat-roofed sheds with concrete yards, trailers
    and bay lines; in industrial districts also container stacks, tank farms and truck parks."""
    hb = lambda k: hash01(P.key, cv.seed, k)  # noqa: E731
    along_u = P.bw >= P.bh
    L = np.where(along_u, P.bw, P.bh)
    x = np.where(along_u, P.lu, P.lv)  # along the long side
    y = np.where(along_u, P.lv, P.lu)
    W = np.where(along_u, P.bh, P.bw)
    n = 1 + (hb(1) * 3).astype(np.int64)
    part = np.minimum(np.floor(x / (L / n)).astype(np.int64), n - 1)
    x0 = part * (L / n)
    xl = x - x0
    pl = L / n
    pkey = P.key * 1009 + part
    hp = lambda k: hash01(pkey, cv.seed, k)  # noqa: E731
    mx = lerp((5.0, 12.0), hp(2))
    front = lerp((16.0, 30.0), hp(3))  # yard depth in front of the shed
    back = lerp((4.0, 10.0), hp(4))
    kind = np.searchsorted(np.cumsum(S_KINDS[S.name]), hp(9)).clip(0, 3)
    inb = (xl > mx) & (xl < pl - mx) & (y > front) & (y < W - back) & (kind == SHED)
    inb &= (pl - 2 * mx > 15.0) & (W - front - back > 15.0)
    # A shed on a block cut by a district boundary keeps a setback from it (one wall follows the
    # arterial, under a flat roof); it is dropped if less than a 15 m deep shed is left.
    cut = touching(pkey, inb, P.edge < mx)
    inb &= P.edge > mx
    inb &= ~touching(pkey, inb, cut & (P.edge < mx + 1.0) & ((y - front < 15.0) | (xl - mx < 15.0)))
    eave = lerp(S.height_high, hp(5))
    # Skylight strips across the roof every 6-10 m; a few sheds have a low-pitch double roof.
    sp = lerp((6.0, 10.0), hp(6))
    sky = ((xl % sp) < 1.2) & (hp(7) < 0.6)
    gable = (hp(8) < S.gable_prob) & ~cut
    yr = y - front
    wr = W - front - back
    roof = eave + np.where(gable, np.minimum(0.12 * (0.5 * wr - np.abs(yr - 0.5 * wr)), 3.0), 0.0)
    inb = _buildings(S, cv, P, inb, pkey, eave, roof, gable, True)
    sel = inb & sky
    cv.rgb[P.idx[sel]] = cv.rgb[P.idx[sel]] * 0.55 + np.float32(0.45 * 235.0)
    g = cv.grain[P.idx]
    conc = np.asarray(S.pavement, np.float32)[None, :] * (0.9 + 0.05 * g[:, None])
    yard = ~inb
    _set(cv, P.idx, yard, rgb=conc, mat=MAT_GROUND, tree=0.0)
    _containers(cv, P, pkey, kind == CONTAINERS, xl, y, pl, W)
    _tanks(cv, P, pkey, kind == TANKS, xl, y, pl, W)
    yard &= (kind == SHED) | (kind == TRUCKS)
    front = np.where(kind == TRUCKS, W, front)  # a truck park is all front yard
    # Trailers (13.6 x 2.6 m) parked nose-in along the yard's front band, 4 m slots.
    slot = np.floor(xl / 4.0).astype(np.int64)
    sx = xl - (slot + 0.5) * 4.0
    occ = hash01(pkey, slot, cv.seed, cv.change, 13) < 0.55
    yb = np.where(kind == TRUCKS, y % 34.0, y)  # truck parks: rows of bays with 18 m aisles
    trailer = occ & (np.abs(sx) < 1.3) & (yb > 2.0) & (yb < 15.6) & (front > 17.0) & yard
    trailer &= (xl > 2.0) & (xl < pl - 2.0)
    trailer &= ~touching(pkey * 4099 + slot, trailer, P.edge < 1.0)
    tcol = pick(TRAILER_COLOURS, hash01(pkey, slot, cv.seed, cv.change, 14))
    tcol = tcol * (1.0 - 0.25 * (np.abs(sx) > 1.0))[:, None]
    _set(cv, P.idx, trailer, struct=3.9, rgb=tcol, mat=MAT_SMALL)
    # Yard markings: painted bay lines.
    bay = yard & ~trailer & (np.abs(sx) > 1.85) & (yb > 1.0) & (yb < 16.0) & (front > 17.0)
    cv.rgb[P.idx[bay]] = np.float32(220.0)
