"""Numba kernels of the height-field ray caster (internal; use ``benchmark.sim.render``).

The world is a 2.5D height field: every texel of the city grid is a flat-topped column of height
``h`` (terrain + buildings + trees + cars, metres, absolute). A ray is marched through a max-mip
pyramid (Tevs et al. 2008, "Maximum mipmaps for fast, accurate, and scalable dynamic height field
rendering"): a cell of level k holds the maximum of its 2^k x 2^k texels, so a ray that stays above
that maximum while crossing the cell skips it at once; otherwise the ray descends a level. The
grid is mirror-tiled to infinity (texel index i maps to i mod 2W, reflected), so the world never
ends and a pitch-0 camera sees a horizon; with dimensions divisible by 2^L the mirror maps aligned
level-k cells onto aligned cells and one pyramid serves every copy.

A hit on a texel top is coloured by the ortho texture of the rendered illumination state (its
baked sun shading and shadows; render.py passes that state's pyramid and sun), sampled
trilinearly from its mip pyramid at the level matching the pixel footprint (footprint
``t * pixel_angle / sqrt(|cos incidence|)``), so distant ground does not shimmer. A hit on a texel's
side is a wall: entering a building from outside gives a facade (palette colour + window grid +
Lambert shading with the wall normal), other steps (terrain, gable steps, cars) reuse the texture.
Windows fade to their mean colour when the pixel footprint approaches the window spacing (the
procedural equivalent of a mip level). Fog: ``c = c e^{-t/V} + haze (1 - e^{-t/V})``.

Grid coordinates: ``gx = (E - E0) / mpp`` and ``gy = (N - N0) / mpp``; texel ``[j, i]`` covers
``gx in [i, i+1)``, ``gy in [j, j+1)`` (row 0 is the southern edge). Everything here is float64,
serial and free of fastmath, so a frame is bit-identical across runs and machines with the same
numba/LLVM. ``error_model="numpy"`` drops the division-by-zero checks from the inner loops (no
division there can be by zero; the output is unchanged) for about 10 % speed.

The facade of a building texel: palette wall colour with a grid of windows (floor height, window
spacing and size from the palette row), laid out along the building's wall direction (``orient``,
snapped against a Sobel estimate of the outward normal) so the windows line up along oblique
staircase walls; windows fade to their mean colour as the pixel footprint reaches the window
spacing (a procedural mip level), and the wall is Lambert-shaded with its horizontal normal.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

# Indices into the float64 ``params`` vector handed to the kernels (built by render.py).
P_MPP, P_E0, P_N0, P_GMAX = 0, 1, 2, 3
P_SUN = 4  # 4, 5, 6: unit vector towards the sun of the rendered illumination state (ENU)
P_AMB, P_DIF = 7, 8
P_HAZE = 9  # 9, 10, 11: haze / horizon colour (0..255)
P_VIS = 12  # fog distance V in metres; <= 0 disables fog
P_ZENITH = 13  # 13, 14, 15: sky colour at the zenith
P_TMAX = 16  # rays longer than this return the haze colour
P_GSCALE = 17  # texels per cell of the coarse ground (terrain) grid
P_GMIN = 18  # lowest surface point (metres)
N_PARAMS = 19

# Material codes in the ``mat`` grid (see world.py); >= MAT_BUILDING is a building whose facade
# palette row is ``mat - MAT_BUILDING``.
MAT_GROUND, MAT_WATER, MAT_TREE, MAT_SMALL, MAT_BUILDING = 0, 1, 2, 3, 16
# Columns of the facade palette: wall rgb, window rgb, floor height, window spacing, window width
# fraction, window height fraction.
PAL_WALL, PAL_WIN, PAL_FLOOR, PAL_SPACING, PAL_WFRAC, PAL_HFRAC = 0, 3, 6, 7, 8, 9
WALL_STEP_M = 2.5  # a step this high between two building texels is a facade, not a roof step
MAX_ITER = 2048
CROWN_BASE = 0.4  # tree columns are transparent below this fraction of their height


@njit(cache=True, error_model="numpy")
def _mirror(i, n):
    if i >= 0 and i < n:
        return i
    m = i % (2 * n)  # numba keeps Python's sign convention: m in [0, 2n)
    if m >= n:
        m = 2 * n - 1 - m
    return m


@njit(cache=True, error_model="numpy")
def _mirror_coord(x, size):
    """Continuous mirror of coordinate x into [0, size) (period 2 size)."""
    m = x % (2.0 * size)
    if m >= size:
        m = 2.0 * size - m
    return m


@njit(cache=True, error_model="numpy")
def _height(hpyr, hoff, hdims, level, ci, cj):
    hh = hdims[level, 0]
    ww = hdims[level, 1]
    return hpyr[hoff[level] + _mirror(cj, hh) * ww + _mirror(ci, ww)]


@njit(cache=True, error_model="numpy")
def _bilinear_rgb(tex, toff, tdims, level, gx, gy):
    """Bilinear RGB of mip ``level`` at level-0 grid coordinates (mirror addressing)."""
    s = float(1 << level)
    hh = tdims[level, 0]
    ww = tdims[level, 1]
    x = gx / s - 0.5
    y = gy / s - 0.5
    x0 = math.floor(x)
    y0 = math.floor(y)
    fx = x - x0
    fy = y - y0
    i0 = _mirror(int(x0), ww)
    i1 = _mirror(int(x0) + 1, ww)
    j0 = _mirror(int(y0), hh)
    j1 = _mirror(int(y0) + 1, hh)
    base = toff[level]
    a = base + j0 * ww
    b = base + j1 * ww
    w00 = (1.0 - fx) * (1.0 - fy)
    w01 = fx * (1.0 - fy)
    w10 = (1.0 - fx) * fy
    w11 = fx * fy
    r = tex[a + i0, 0] * w00 + tex[a + i1, 0] * w01 + tex[b + i0, 0] * w10 + tex[b + i1, 0] * w11
    g = tex[a + i0, 1] * w00 + tex[a + i1, 1] * w01 + tex[b + i0, 1] * w10 + tex[b + i1, 1] * w11
    bl = tex[a + i0, 2] * w00 + tex[a + i1, 2] * w01 + tex[b + i0, 2] * w10 + tex[b + i1, 2] * w11
    return r, g, bl


@njit(cache=True, error_model="numpy")
def _trilinear_rgb(tex, toff, tdims, lod, gx, gy):
    nlev = toff.shape[0]
    if lod <= 0.0:
        return _bilinear_rgb(tex, toff, tdims, 0, gx, gy)
    if lod >= nlev - 1:
        return _bilinear_rgb(tex, toff, tdims, nlev - 1, gx, gy)
    l0 = math.floor(lod)
    w = lod - l0
    a0, a1, a2 = _bilinear_rgb(tex, toff, tdims, l0, gx, gy)
    b0, b1, b2 = _bilinear_rgb(tex, toff, tdims, l0 + 1, gx, gy)
    return (a0 * (1.0 - w) + b0 * w, a1 * (1.0 - w) + b1 * w, a2 * (1.0 - w) + b2 * w)


@njit(cache=True, error_model="numpy")
def ground_bilinear(ground: np.ndarray, gscale: float, gx: float, gy: float) -> float:
    """Terrain height (metres) at level-0 grid coordinates from the coarse ground grid."""
    hh = ground.shape[0]
    ww = ground.shape[1]
    x = gx / gscale - 0.5
    y = gy / gscale - 0.5
    x0 = math.floor(x)
    y0 = math.floor(y)
    fx = x - x0
    fy = y - y0
    i0 = _mirror(int(x0), ww)
    i1 = _mirror(int(x0) + 1, ww)
    j0 = _mirror(int(y0), hh)
    j1 = _mirror(int(y0) + 1, hh)
    top = ground[j0, i0] * (1.0 - fx) + ground[j0, i1] * fx
    bot = ground[j1, i0] * (1.0 - fx) + ground[j1, i1] * fx
    return top * (1.0 - fy) + bot * fy


@njit(cache=True, error_model="numpy")
def _sky(dz, params):
    w = math.sqrt(max(dz, 0.0))
    w = min(1.0, w * 1.6)
    return (
        params[P_HAZE] * (1.0 - w) + params[P_ZENITH] * w,
        params[P_HAZE + 1] * (1.0 - w) + params[P_ZENITH + 1] * w,
        params[P_HAZE + 2] * (1.0 - w) + params[P_ZENITH + 2] * w,
    )


@njit(cache=True, error_model="numpy")
def _fog(col, t, params):
    vis = params[P_VIS]
    if vis <= 0.0:
        return col
    a = 1.0 - math.exp(-t / vis)
    return (
        col[0] * (1.0 - a) + params[P_HAZE] * a,
        col[1] * (1.0 - a) + params[P_HAZE + 1] * a,
        col[2] * (1.0 - a) + params[P_HAZE + 2] * a,
    )


@njit(cache=True, error_model="numpy")
def _facade(hx, hy, hz, t, dx, dy, axis, ci, cj, pix_angle, world):
    """Colour of a facade hit at metres-space point (hx, hy, hz) on texel (ci, cj)."""
    hpyr, hoff, hdims = world[:3]
    mat, orient, ground, palette, params = world[6:]
    hh = hdims[0, 0]
    ww = hdims[0, 1]
    mi = _mirror(ci, ww)
    mj = _mirror(cj, hh)
    m = mat[mj, mi]
    row = m - MAT_BUILDING
    # Outward normal estimate: minus the Sobel gradient of the height around the texel, in the
    # mirrored copy's local frame. Mirroring flips axes, which the Sobel estimate handles for free
    # because it is evaluated on the copy the ray is in (through _height with unmirrored indices).
    gxs = 0.0
    gys = 0.0
    for oj in range(-1, 2):
        for oi in range(-1, 2):
            hv = _height(hpyr, hoff, hdims, 0, ci + oi, cj + oj)
            wgt = 2.0 if (oi == 0 or oj == 0) else 1.0
            gxs += oi * wgt * hv
            gys += oj * wgt * hv
    nx = -gxs
    ny = -gys
    # The crossed texel face: its outward normal points against the ray along the crossed axis.
    fx = 0.0
    fy = 0.0
    if axis == 0:
        fx = -1.0 if dx > 0 else 1.0
    else:
        fy = -1.0 if dy > 0 else 1.0
    nrm = math.sqrt(nx * nx + ny * ny)
    if nrm < 1e-6 or nx * fx + ny * fy <= 0.0:
        nx, ny = fx, fy
    else:
        nx /= nrm
        ny /= nrm
    # Snap to the building's own wall directions (orient = wall angle mod 90 deg in the base tile;
    # a mirrored copy reflects the angle).
    theta = orient[mj, mi] * (0.5 * math.pi / 256.0)
    # A reflection in x maps angle a to pi - a, in y to -a; modulo 90 deg both are -a.
    flip_x = (ci % (2 * ww)) >= ww
    flip_y = (cj % (2 * hh)) >= hh
    if flip_x != flip_y:
        theta = -theta
    # The four wall normals are (c, s) rotated by multiples of 90 deg: pick the closest one.
    c0 = math.cos(theta)
    s0 = math.sin(theta)
    bx = c0
    by = s0
    best = c0 * nx + s0 * ny
    for cx_, cy_ in ((-s0, c0), (-c0, -s0), (s0, -c0)):
        d = cx_ * nx + cy_ * ny
        if d > best:
            best = d
            bx = cx_
            by = cy_
    nx = bx
    ny = by
    # Along-wall coordinate (metres) and height above the terrain. The window grid is laid out in
    # the base tile's frame, so a mirrored copy shows the mirror image of the same facade.
    mpp = params[P_MPP]
    bx_ = _mirror_coord(hx, ww * mpp)
    by_ = _mirror_coord(hy, hh * mpp)
    nbx = -nx if flip_x else nx
    nby = -ny if flip_y else ny
    s = bx_ * (-nby) + by_ * nbx
    zg = hz - ground_bilinear(ground, params[P_GSCALE], hx / mpp, hy / mpp)
    top = _height(hpyr, hoff, hdims, 0, ci, cj) - ground_bilinear(
        ground, params[P_GSCALE], (ci + 0.5), (cj + 0.5)
    )
    floor_h = palette[row, PAL_FLOOR]
    spacing = palette[row, PAL_SPACING]
    wfrac = palette[row, PAL_WFRAC]
    hfrac = palette[row, PAL_HFRAC]
    cosi = abs(nx * dx * mpp + ny * dy * mpp)  # dx, dy are in grid units per metre
    foot = t * pix_angle / max(cosi, 0.15)
    # Window visibility fades out as the footprint approaches the window spacing.
    vis = min(1.0, max(0.0, 1.5 - foot / (0.5 * min(spacing, floor_h))))
    mean_frac = wfrac * hfrac
    is_win = False
    if zg > 0.6 and zg < top - 0.9:
        fz = (zg / floor_h) % 1.0
        fs = (s / spacing) % 1.0
        is_win = abs(fz - 0.55) < 0.5 * hfrac and abs(fs - 0.5) < 0.5 * wfrac
    # Lambert with the horizontal wall normal (the sun vector is ENU), and a band of ambient
    # occlusion at the wall foot.
    # The baked shadows of a mirrored copy are mirrored, so its facades see a mirrored sun.
    sun_x = -params[P_SUN] if flip_x else params[P_SUN]
    sun_y = -params[P_SUN + 1] if flip_y else params[P_SUN + 1]
    lam = nx * sun_x + ny * sun_y
    shade = params[P_AMB] + params[P_DIF] * max(lam, 0.0)
    if zg < 2.0:
        shade *= 0.75 + 0.125 * max(zg, 0.0)
    out0 = 0.0
    out1 = 0.0
    out2 = 0.0
    for c in range(3):
        wall = palette[row, PAL_WALL + c]
        win = palette[row, PAL_WIN + c]
        mean = wall * (1.0 - mean_frac) + win * mean_frac
        pat = win if is_win else wall
        v = (pat * vis + mean * (1.0 - vis)) * shade
        if c == 0:
            out0 = v
        elif c == 1:
            out1 = v
        else:
            out2 = v
    return (out0, out1, out2)


@njit(cache=True, error_model="numpy", inline="always")  # inlined: ~5 % faster
def trace(
    ox: float,
    oy: float,
    oz: float,
    dx: float,
    dy: float,
    dz: float,
    pix_angle: float,
    world: tuple,
) -> tuple[float, float, float]:
    """Colour (0..255, three float64 channels) seen along one ray.

    ``world = (hpyr, hoff, hdims, tex, toff, tdims, mat, orient, ground, palette, params)``: the
    max-mip heights, the texture pyramid, material/orientation grids, the coarse terrain grid, the
    facade palette and the parameter vector (``P_*`` indices).

    ``(ox, oy)`` and ``(dx, dy)`` are in grid units (texels, and texels per metre of ray length),
    ``oz``/``dz`` in metres; ``t`` is the ray length in metres (the direction is unit in metres).
    """
    hpyr, hoff, hdims, tex, toff, tdims, mat = world[:7]
    ground, params = world[8], world[10]
    L = hoff.shape[0] - 1
    mpp = params[P_MPP]
    gmax = params[P_GMAX]
    tmax = params[P_TMAX]
    t = 0.0
    if oz > gmax:
        if dz >= 0.0:
            return _sky(dz, params)
        t = (oz - gmax) / (-dz)
    # Start at the level whose cells match the horizontal run of the ray between the highest and
    # the lowest surface point: steep rays skip the top levels they would only descend through
    # (correct from any level; this only saves iterations).
    level = L
    axis = -1
    inf = 1e300
    if dz < 0.0:
        run = (gmax - params[P_GMIN]) / (-dz) * math.sqrt(dx * dx + dy * dy)
        if run < 1.0:
            level = 0
        else:
            level = min(L, int(math.log2(run)))
    # Integer DDA over the cells of the current level: (ci, cj) holds the ray at length t.
    stepx = 1 if dx > 0.0 else -1
    stepy = 1 if dy > 0.0 else -1
    inv_dx = 1.0 / dx if dx != 0.0 else 0.0
    inv_dy = 1.0 / dy if dy != 0.0 else 0.0
    s = float(1 << level)
    ci = math.floor((ox + t * dx) / s)
    cj = math.floor((oy + t * dy) / s)
    for _ in range(MAX_ITER):
        if dx > 0.0:
            tx = ((ci + 1) * s - ox) * inv_dx
        elif dx < 0.0:
            tx = (ci * s - ox) * inv_dx
        else:
            tx = inf
        if dy > 0.0:
            ty = ((cj + 1) * s - oy) * inv_dy
        elif dy < 0.0:
            ty = (cj * s - oy) * inv_dy
        else:
            ty = inf
        texit = min(tx, ty)
        h = _height(hpyr, hoff, hdims, level, ci, cj)
        zin = oz + t * dz
        zout = oz + texit * dz
        if zin > h and zout > h:
            # Skip the cell; climb a level when the step also leaves the parent cell.
            t = max(t, texit)
            if t > tmax:
                break
            if dz >= 0.0 and zout > gmax:
                return _sky(dz, params)
            if tx < ty:
                axis = 0
                up = (ci >> 1) != ((ci + stepx) >> 1)
                ci += stepx
            else:
                axis = 1
                up = (cj >> 1) != ((cj + stepy) >> 1)
                cj += stepy
            if up and level < L:
                level += 1
                s *= 2.0
                ci >>= 1
                cj >>= 1
            continue
        if level > 0:
            if zin > h:
                t = max(t, (oz - h) / (-dz))
                axis = -1
            level -= 1
            s *= 0.5
            # The child cell holding the ray, clamped into the parent against rounding.
            nci = math.floor((ox + t * dx) / s)
            ncj = math.floor((oy + t * dy) / s)
            ci = min(max(nci, 2 * ci), 2 * ci + 1)
            cj = min(max(ncj, 2 * cj), 2 * cj + 1)
            continue
        # Level 0: the ray meets this texel's column.
        t_top = (oz - h) / (-dz) if dz < 0.0 else -inf
        if zin > h - 1e-6 or axis < 0 or t_top >= t - 1e-6:
            # Top face.
            th = max(t, t_top)
            hx = ox + th * dx
            hy = oy + th * dy
            lod = math.log2(max(th * pix_angle / math.sqrt(max(abs(dz), 0.02)) / mpp, 1e-6))
            col = _trilinear_rgb(tex, toff, tdims, lod, hx, hy)
            if mat[_mirror(cj, hdims[0, 0]), _mirror(ci, hdims[0, 1])] == MAT_WATER:
                # Water reflects the sky, strongly at grazing angles (Schlick's Fresnel, n=1.33).
                fr = 0.02 + 0.98 * (1.0 - abs(dz)) ** 5
                sk = _sky(-dz, params)
                col = (
                    col[0] * (1.0 - fr) + sk[0] * fr,
                    col[1] * (1.0 - fr) + sk[1] * fr,
                    col[2] * (1.0 - fr) + sk[2] * fr,
                )
            return _fog(col, th, params)
        # Side face. Tree columns are solid only in their crown (the upper 60 %): lower down the
        # ray passes under the crown, to the shaded ground beneath or on to the next texel.
        hh0 = hdims[0, 0]
        ww0 = hdims[0, 1]
        m_here = mat[_mirror(cj, hh0), _mirror(ci, ww0)]
        if m_here == MAT_TREE:
            zg = ground_bilinear(ground, params[P_GSCALE], ox + t * dx, oy + t * dy)
            if zin < zg + CROWN_BASE * (h - zg):
                t_ground = (oz - zg) / (-dz) if dz < 0.0 else inf
                if t_ground <= texit:
                    gx_ = ox + t_ground * dx
                    gy_ = oy + t_ground * dy
                    lod = math.log2(max(t_ground * pix_angle / mpp, 1e-6))
                    col = _trilinear_rgb(tex, toff, tdims, lod, gx_, gy_)
                    col = (col[0] * 0.45, col[1] * 0.45, col[2] * 0.45)
                    return _fog(col, t_ground, params)
                t = texit
                if tx < ty:
                    axis = 0
                    ci += stepx
                else:
                    axis = 1
                    cj += stepy
                continue
        if axis == 0:
            pi_ = ci - (1 if dx > 0 else -1)
            pj_ = cj
        else:
            pi_ = ci
            pj_ = cj - (1 if dy > 0 else -1)
        m_prev = mat[_mirror(pj_, hh0), _mirror(pi_, ww0)]
        h_prev = _height(hpyr, hoff, hdims, 0, pi_, pj_)
        hx = ox + t * dx
        hy = oy + t * dy
        if m_here >= MAT_BUILDING and (m_prev < MAT_BUILDING or h - h_prev > WALL_STEP_M):
            col = _facade(hx * mpp, hy * mpp, zin, t, dx, dy, axis, ci, cj, pix_angle, world)
            return _fog(col, t, params)
        # Terrain steps, trees, cars, gable steps: the texture of the texel, a little darker on
        # vertical sides (trees are lit from above).
        lod = math.log2(max(t * pix_angle / mpp, 1e-6))
        col = _trilinear_rgb(tex, toff, tdims, lod, hx, hy)
        if m_here == MAT_TREE:
            # Crown sides darken towards the shaded underside (no trunk geometry in 2.5D).
            zg = ground_bilinear(ground, params[P_GSCALE], hx, hy)
            k = 0.35 + 0.5 * min(1.0, max(0.0, (zin - zg) / max(h - zg, 0.5)))
            col = (col[0] * k, col[1] * k, col[2] * k)
        return _fog(col, t, params)
    return (params[P_HAZE], params[P_HAZE + 1], params[P_HAZE + 2])


@njit(cache=True, error_model="numpy")
def render_image(
    out: np.ndarray,
    R: np.ndarray,
    pos: np.ndarray,
    f: float,
    cx: float,
    cy: float,
    ss: int,
    world: tuple,
) -> None:
    """Fill ``out`` (H, W, 3) uint8 by casting ``ss x ss`` rays per pixel (box filter).

    ``R`` is ``R_b^n`` (3, 3); ``pos`` the ENU camera centre; ``f, cx, cy`` the pinhole intrinsics
    (camera.py conventions). Rounding is half-up of the float mean, deterministic.
    """
    params = world[10]
    H = out.shape[0]
    W = out.shape[1]
    mpp = params[P_MPP]
    ox = (pos[0] - params[P_E0]) / mpp
    oy = (pos[1] - params[P_N0]) / mpp
    oz = pos[2]
    pix_angle = 1.0 / (f * ss)
    inv = 1.0 / (ss * ss)
    for i in range(H):
        for j in range(W):
            acc0 = 0.0
            acc1 = 0.0
            acc2 = 0.0
            for a in range(ss):
                for b in range(ss):
                    u = j + (b + 0.5) / ss - 0.5
                    v = i + (a + 0.5) / ss - 0.5
                    bx = u - cx
                    by = f
                    bz = cy - v
                    n = math.sqrt(bx * bx + by * by + bz * bz)
                    bx /= n
                    by /= n
                    bz /= n
                    ex = R[0, 0] * bx + R[0, 1] * by + R[0, 2] * bz
                    ey = R[1, 0] * bx + R[1, 1] * by + R[1, 2] * bz
                    ez = R[2, 0] * bx + R[2, 1] * by + R[2, 2] * bz
                    col = trace(ox, oy, oz, ex / mpp, ey / mpp, ez, pix_angle, world)
                    acc0 += col[0]
                    acc1 += col[1]
                    acc2 += col[2]
            for c in range(3):
                val = (acc0 if c == 0 else (acc1 if c == 1 else acc2)) * inv + 0.5
                if val < 0.0:
                    val = 0.0
                if val > 255.0:
                    val = 255.0
                out[i, j, c] = np.uint8(int(val))
