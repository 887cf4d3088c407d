"""Districts and their street networks: per texel, the street coordinates of its district's grid.

A city is a warped Voronoi partition into districts of ``Style.district_m`` metres (scaled to the
tile, so a 2 km town still has several). Each district has its own street frame:

- ``grid``: a rotated grid (angle drawn over the full [0, 90) deg range, stratified over the
  districts so no angle dominates the tile) with its own block pitches, warped by the style's
  smooth noise (``warp_amp``);
- ``organic``: the same with a smaller pitch and a strong, short-wavelength warp (curved streets of
  an old town);
- ``radial``: ring roads round a central green, cut by spokes into wedge blocks (a circus).

District boundaries are arterial roads (``art``: metric distance to the boundary centreline), so
blocks end at a street, never at a seam through buildings. For every texel the generator gets its
distances to the nearest street centrelines of its district (``du``, ``dv``, metres), the half
widths of those streets, its block's local coordinates ``lu, lv`` and size ``bw, bh`` (metres,
interior after carriageway and pavement) and ``edge``, the distance to an irregular block edge
(the arterial's pavement or a radial district's central green), which block programmes respect.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from benchmark.sim import detmath
from benchmark.sim.textures import smooth_noise
from benchmark.sim.world_styles import Style

GRID, ORGANIC, RADIAL = 0, 1, 2
KINDS = ("grid", "organic", "radial")
FAR = np.float32(1.0e4)  # "no irregular edge / boundary near this texel", metres
KEY_BASE = 4096  # street / block keys: (district * 4096 + line) * 4096 + line
BlockTable = Callable[[np.ndarray, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


def rng_for(style: str, seed: int, stream: str) -> np.random.Generator:
    """An independent, reproducible numpy stream per (style, seed, purpose)."""
    return np.random.default_rng(
        [zlib.crc32(style.encode()), int(seed), zlib.crc32(stream.encode())]
    )


@dataclass(frozen=True)
class District:
    kind: int  # GRID, ORGANIC or RADIAL
    angle: float  # grid angle, radians in [0, pi): direction of grad u
    centre: tuple[float, float]  # Voronoi seed (E, N), metres; the centre of a radial district
    pitch_u: tuple[float, float]  # block pitch ranges, metres
    pitch_v: tuple[float, float]

    def centre_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        return np.full((1, 1), self.centre[0]), np.full((1, 1), self.centre[1])


@dataclass
class Streets:
    """Per-texel street fields, all (H, W), metres unless said otherwise."""

    u: np.ndarray  # float32 street coordinate across the "u" streets (along the v streets)
    v: np.ndarray  # float32
    du: np.ndarray  # float32 distance to the nearest u-street centreline
    dv: np.ndarray
    hu: np.ndarray  # float32 half carriageway width of that street
    hv: np.ndarray
    lu: np.ndarray  # float32 block-local coordinates from the block's lower-left interior corner
    lv: np.ndarray
    bw: np.ndarray  # float32 block interior size
    bh: np.ndarray
    ksu: np.ndarray  # int32 street key (district, line below) of the u and v streets
    ksv: np.ndarray
    btype: np.ndarray  # uint8 block programme (index into city_layout.BLOCK_TYPES)
    dens: np.ndarray  # float32 density value of the block in [0, 1] (1 = dense and tall)
    label: np.ndarray  # int16 district index
    art: np.ndarray  # float32 distance to the district boundary (arterial centreline), FAR if none
    art_along: np.ndarray  # float32 coordinate along that boundary
    edge: np.ndarray  # float32 distance to an irregular block edge, FAR if none
    art_half: float  # arterial half carriageway width
    districts: tuple[District, ...]


def plan_districts(S: Style, seed: int, size_e: float, size_n: float) -> tuple[District, ...]:
    """Districts of a ``size_e x size_n`` m tile: a jittered lattice of seeds, stratified angles.

    The district scale is ``sqrt(area / 8)`` clipped to ``S.district_m``: about 8 districts on a
    2 km town tile, bigger districts (up to the style's maximum) on a full city.
    """
    r = rng_for(S.name, seed, "districts")
    scale = float(np.clip(math.sqrt(size_e * size_n / 8.0), *S.district_m))
    nx = max(1, round(size_e / scale))
    ny = max(1, round(size_n / scale))
    n = nx * ny
    # Angles: one per stratum of [0, pi/2), strata shuffled over the districts, so that the
    # area-weighted mean of exp(4 i angle) over the tile is small (no dominant street direction).
    angles = (r.uniform(0, 1) + r.permutation(n) + r.uniform(-0.35, 0.35, n)) * (0.5 * math.pi / n)
    angles = np.mod(angles, 0.5 * math.pi)
    jit = r.uniform(-0.3, 0.3, (n, 2))
    kinds = r.choice(3, size=n, p=[1.0 - S.p_organic - S.p_radial, S.p_organic, S.p_radial])
    pf = r.uniform(0.8, 1.25, n)
    swap = r.uniform(size=n) < 0.5
    out = []
    for k in range(n):
        a, b = divmod(k, ny)
        e = ((a + 0.5 + jit[k, 0]) / nx - 0.5) * size_e
        nn = ((b + 0.5 + jit[k, 1]) / ny - 0.5) * size_n
        out.append((e, nn))
    cen = np.asarray(out)
    if S.old_town != "grid" and n > 1:  # the district nearest the tile centre is the old core
        kinds[int(np.argmin(detmath.hypot(cen[:, 0], cen[:, 1])))] = KINDS.index(S.old_town)
    dists = []
    for k in range(n):
        f = pf[k] * (0.75 if kinds[k] == ORGANIC else 1.0)
        pu = (S.block_u[0] * f, S.block_u[1] * f)
        pv = (S.block_v[0] * f, S.block_v[1] * f)
        # The grid is the same under a quarter turn, the elongation of its blocks is not: a
        # random quarter turn spreads the long block axis over [0, pi).
        a = angles[k] + (0.5 * math.pi if swap[k] else 0.0)
        dists.append(District(int(kinds[k]), float(a), tuple(cen[k]), pu, pv))
    return tuple(dists)


def partition(
    S: Style, seed: int, E: np.ndarray, N: np.ndarray, mpp: float, centres: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """District label (int16), metric distance to the nearest boundary and the along-boundary
    coordinate (float32, metres), for a Voronoi partition of warped coordinates (smooth, curving
    boundaries).

    The distance to the boundary between the nearest seed c1 and the second nearest c2 is the
    bisector distance ``(|p-c2|^2 - |p-c1|^2) / (2 |c2-c1|)`` in warped coordinates, divided by
    its numerical gradient norm to make it metric in the unwarped plane (the warp stretches it by
    up to ~30 %). It is computed on a grid of ~4 m and interpolated bilinearly (exact where the
    field is linear; the label is wrong at most 2 m from a boundary, inside the arterial road).
    """
    H, W = E.shape
    n = len(centres)
    if n == 1:
        return np.zeros((H, W), np.int16), np.full((H, W), FAR), np.zeros((H, W), np.float32)
    f = max(1, int(4.0 / mpp))
    if H % f or W % f:
        f = 1
    h, w = H // f, W // f
    Ec = E.reshape(h, f, w, f).mean(axis=(1, 3))
    Nc = N.reshape(h, f, w, f).mean(axis=(1, 3))
    scale = math.sqrt(W * H) * mpp / math.sqrt(n)
    r = rng_for(S.name, seed, "district_warp")
    amp = np.float32(0.12 * scale)
    pe = Ec + amp * smooth_noise(r, (h, w), 0.9 * scale / (mpp * f))
    pn = Nc + amp * smooth_noise(r, (h, w), 0.9 * scale / (mpp * f))
    c = centres.astype(np.float32)
    d2 = (pe[None] - c[:, 0, None, None]) ** 2 + (pn[None] - c[:, 1, None, None]) ** 2
    lab1 = np.argmin(d2, axis=0)
    best1 = np.take_along_axis(d2, lab1[None], 0)[0]
    np.put_along_axis(d2, lab1[None], np.inf, 0)
    lab2 = np.argmin(d2, axis=0)
    best2 = np.take_along_axis(d2, lab2[None], 0)[0]
    del d2
    de = c[lab2, 0] - c[lab1, 0]
    dn = c[lab2, 1] - c[lab1, 1]
    sep = np.sqrt(de * de + dn * dn)
    art = (best2 - best1) / (2.0 * sep)
    along = ((pe - c[lab1, 0]) * -dn + (pn - c[lab1, 1]) * de) / sep
    gj, gi = np.gradient(art)
    art /= np.clip(np.sqrt(gj * gj + gi * gi) / np.float32(mpp * f), 0.7, 1.6)
    label = np.repeat(np.repeat(lab1.astype(np.int16), f, 0), f, 1)
    return label, _upsample(art, f), _upsample(along, f)


def _upsample(a: np.ndarray, f: int) -> np.ndarray:
    """Bilinear upsampling by the integer factor ``f`` of a field sampled at block centres
    (edge rows / columns extrapolated flat), float32."""
    if f == 1:
        return a.astype(np.float32)
    h, w = a.shape
    t = (np.arange(f, dtype=np.float32) + 0.5) / f - 0.5  # texel offsets in block units

    def along(x, axis, m):
        pos = (np.arange(m, dtype=np.float32)[:, None] + t[None, :]).ravel()
        i0 = np.clip(np.floor(pos).astype(np.int64), 0, m - 1)
        i1 = np.clip(i0 + 1, 0, m - 1)
        wt = np.clip(pos - np.floor(pos), 0.0, 1.0).astype(np.float32)
        wt = np.where(pos < 0, 0.0, wt).astype(np.float32)
        x0 = np.take(x, i0, axis=axis)
        x1 = np.take(x, i1, axis=axis)
        shape = [1, 1]
        shape[axis] = -1
        return x0 + (x1 - x0) * wt.reshape(shape)

    return along(along(a.astype(np.float32), 0, h), 1, w).astype(np.float32)


def _lines(rng, lo: float, hi: float, pitch: tuple[float, float]) -> np.ndarray:
    start = lo - pitch[1] - rng.uniform(0, pitch[1])
    n = int((hi - start) / pitch[0]) + 3
    lines = start + np.concatenate([[0.0], np.cumsum(rng.uniform(*pitch, n))])
    return lines.astype(np.float32)  # float32 keeps the per-texel temporaries small


def _widths(rng, n: int, S: Style) -> np.ndarray:
    off = rng.integers(0, S.major_every)
    major = (np.arange(n) + off) % S.major_every == 0
    return np.where(major, S.road_major, S.road_minor).astype(np.float32)


def _axis(coord, lines, widths, scale=None):
    """Per texel: line index below, distance to the nearest line, its half width, the local
    coordinate from the interior edge above the line below and the block interior size. ``scale``
    (per texel) converts coordinate units to metres (radial spokes)."""
    k = np.clip(np.searchsorted(lines, coord, side="right") - 1, 0, len(lines) - 2).astype(np.int32)
    lo = lines[k]
    hi = lines[k + 1]
    wlo = widths[k]
    whi = widths[k + 1]
    s = np.float32(1.0) if scale is None else scale
    dlo = (coord - lo) * s
    dhi = (hi - coord) * s
    near_lo = dlo < dhi
    dist = np.where(near_lo, dlo, dhi)
    half = np.where(near_lo, wlo, whi) * 0.5
    local = dlo - 0.5 * wlo
    size = (hi - lo) * s - 0.5 * (wlo + whi)
    return k, dist, half, local, size


def street_fields(
    S: Style, seed: int, E: np.ndarray, N: np.ndarray, mpp: float, table: BlockTable, park: int
) -> Streets:
    """All per-texel street fields of the city ``(S, seed)`` on the texel centres ``E, N`` (H, W).

    ``table(keys, E, N) -> (btype, dens)`` gives the programme and density of blocks from their
    int64 keys and centres (metres); ``park`` is the programme of a radial district's centre.
    """
    H, W = E.shape
    dists = plan_districts(S, seed, W * mpp, H * mpp)
    centres = np.asarray([d.centre for d in dists])
    label, art, art_along = partition(S, seed, E, N, mpp, centres)
    art_half = 0.5 * S.road_major * 1.15
    f32 = lambda: np.empty((H, W), np.float32)  # noqa: E731
    F = Streets(
        *(f32() for _ in range(10)),
        np.empty((H, W), np.int32),
        np.empty((H, W), np.int32),
        np.empty((H, W), np.uint8),
        f32(),
        label,
        art,
        art_along,
        (art - np.float32(art_half + S.sidewalk)).astype(np.float32),
        art_half,
        dists,
    )
    warp = None
    if S.warp_amp > 0:
        warp = [smooth_noise(rng_for(S.name, seed, w), (H, W), S.warp_cell / mpp) for w in "uv"]
    organic = None
    if any(d.kind == ORGANIC for d in dists):
        pitch = 0.25 * (sum(S.block_u) + sum(S.block_v)) * 0.75
        cell = 4.0 * pitch
        amp = np.float32(max(S.warp_amp, 0.25 * cell))
        organic = [
            amp * smooth_noise(rng_for(S.name, seed, "organic_" + w), (H, W), cell / mpp)
            for w in "uv"
        ]
    flat_label = label.ravel()
    order = np.argsort(flat_label, kind="stable")
    bounds = np.searchsorted(flat_label[order], np.arange(len(dists) + 1))
    for d, dist in enumerate(dists):
        idx = order[bounds[d] : bounds[d + 1]]
        if idx.size == 0:
            continue
        r = rng_for(S.name, seed, f"district_{d}")
        e = E.ravel()[idx]
        n = N.ravel()[idx]
        if dist.kind == RADIAL:
            outside = _radial(S, F, d, dist, r, idx, e, n, table, park)
            idx, e, n = idx[outside], e[outside], n[outside]
            if idx.size == 0:
                continue
        ca, sa = math.cos(dist.angle), math.sin(dist.angle)
        u = e * ca + n * sa
        v = -e * sa + n * ca
        if warp is not None:
            u += np.float32(S.warp_amp) * warp[0].ravel()[idx]
            v += np.float32(S.warp_amp) * warp[1].ravel()[idx]
        if dist.kind == ORGANIC:
            u += organic[0].ravel()[idx]
            v += organic[1].ravel()[idx]
        ul = _lines(r, float(u.min()), float(u.max()), dist.pitch_u)
        vl = _lines(r, float(v.min()), float(v.max()), dist.pitch_v)
        # Block centres (unwarped) for the programme table.
        cu = 0.5 * (ul[:-1] + ul[1:])[:, None]
        cv = 0.5 * (vl[:-1] + vl[1:])[None, :]
        _store(S, F, d, idx, u, v, ul, vl, _widths(r, len(ul), S), _widths(r, len(vl), S))
        keys = _keys(d, np.arange(len(ul) - 1)[:, None], np.arange(len(vl) - 1)[None, :])
        bt, dn = table(keys, cu * ca - cv * sa, cu * sa + cv * ca)
        _lookup(F, idx, bt, dn)
    return F


def _keys(d: int, ku, kv) -> np.ndarray:
    ku = np.asarray(ku, np.int64)
    kv = np.asarray(kv, np.int64)
    return (d * KEY_BASE + ku) * KEY_BASE + kv


def _store(S, F: Streets, d, idx, u, v, ul, vl, wu, wv, sv=None) -> None:
    if max(len(ul), len(vl)) >= KEY_BASE:
        raise ValueError(f"district {d}: {max(len(ul), len(vl))} street lines, at most {KEY_BASE}")
    ku, du, hu, lu, bw = _axis(u, ul, wu)
    kv, dv, hv, lv, bh = _axis(v, vl, wv, sv)
    sw = np.float32(S.sidewalk)
    for name, val in (
        ("u", u),
        ("v", v),
        ("du", du),
        ("dv", dv),
        ("hu", hu),
        ("hv", hv),
        ("lu", lu - sw),
        ("lv", lv - sw),
        ("bw", bw - 2 * sw),
        ("bh", bh - 2 * sw),
        ("ksu", d * KEY_BASE + ku),
        ("ksv", d * KEY_BASE + kv),
    ):
        getattr(F, name).ravel()[idx] = val


def _lookup(F: Streets, idx, btype_table, dens_table, ku=None, kv=None) -> None:
    ku = F.ksu.ravel()[idx] % KEY_BASE if ku is None else ku
    kv = F.ksv.ravel()[idx] % KEY_BASE if kv is None else kv
    F.btype.ravel()[idx] = btype_table[ku, kv]
    F.dens.ravel()[idx] = dens_table[ku, kv]


def _radial(S, F: Streets, d, dist: District, r, idx, e, n, table, park: int) -> None:
    """A circus: 2-4 ring roads round a central green (radius 30-70 m); between two rings, spokes
    every ``pitch_v`` metres at the band's mid radius (offset per band, so spokes of neighbouring
    bands meet the rings in T-junctions, as in real radial towns). Fills the texels inside the
    outer ring road (and that road); returns the mask of the others, which get the district's
    grid (ending at the ring road's pavement)."""
    x = e - np.float32(dist.centre[0])
    y = n - np.float32(dist.centre[1])
    rad = np.sqrt(x * x + y * y)
    th = detmath.arctan2(y, x)
    r0 = r.uniform(30.0, 70.0)
    rings = [-float(FAR), r0]
    for _ in range(r.integers(2, 5)):
        rings.append(rings[-1] + r.uniform(*dist.pitch_u))
    rings.append(float(FAR))  # virtual line: beyond the outer ring road the district is a grid
    rl = np.asarray(rings, np.float32)
    wr = _widths(r, len(rl), S)
    wr[0] = wr[-1] = 0.0
    wr[-2] = S.road_major
    r_out = rl[-2]
    sw = np.float32(S.sidewalk)
    outside = rad > r_out
    # Grid blocks outside end at the outer ring road's pavement (an irregular edge).
    out_edge = rad - r_out - np.float32(0.5 * S.road_major) - sw
    F.edge.ravel()[idx[outside]] = np.minimum(F.edge.ravel()[idx[outside]], out_edge[outside])
    band = np.clip(np.searchsorted(rl, rad, side="right") - 1, 0, len(rl) - 2)
    band[outside] = -1
    for b in range(len(rl) - 2):
        sel = np.flatnonzero(band == b)
        if sel.size == 0:
            continue
        if b == 0:  # the central green: no spokes
            vl = np.asarray([-FAR, FAR], np.float32)
            wv = np.zeros(2, np.float32)
            v = np.zeros(sel.size, np.float32)
            sv = None
        else:
            mid = 0.5 * (rl[b] + rl[b + 1])
            ns = max(6, round(2 * math.pi * mid / r.uniform(*dist.pitch_v)))
            step = 2 * math.pi / ns
            j = np.arange(-1, ns + 2)
            vl = (mid * (r.uniform(0, step) - math.pi + j * step)).astype(np.float32)
            wv = _widths(r, ns, S)[j % ns]
            v = th[sel] * np.float32(mid)
            sv = (rad[sel] / np.float32(mid)).astype(np.float32)
        ii = idx[sel]
        _store(S, F, d, ii, rad[sel], v, rl, vl, wr, wv, sv)
        if b == 0:
            bt, dn = table(_keys(d, 0, np.zeros((1, 1))), *dist.centre_arrays())
            bt = np.full_like(bt, park)
            kv = np.zeros(sel.size, np.int64)
            edge = rl[1] - 0.5 * wr[1] - sw - rad[sel]
            F.edge.ravel()[ii] = np.minimum(F.edge.ravel()[ii], edge)
        else:
            # Spoke index modulo the spoke count: the block across theta = pi is one block.
            kv = (F.ksv.ravel()[ii] % KEY_BASE - 1) % ns
            F.ksv.ravel()[ii] = d * KEY_BASE + kv
            ang = (0.5 * (vl[1 : ns + 1] + vl[2 : ns + 2]) / mid)[None, :]
            keys = _keys(d, b, np.arange(ns)[None, :])
            cx = dist.centre[0] + mid * detmath.cos(ang)
            cy = dist.centre[1] + mid * detmath.sin(ang)
            bt, dn = table(keys, cx, cy)
        _lookup(F, ii, bt, dn, np.zeros(sel.size, np.int64), kv)
    return outside
