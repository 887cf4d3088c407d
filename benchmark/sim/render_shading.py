"""Shading helpers of the ray caster: parameter layout, mirror addressing, texture sampling, sky,
fog and the procedural facade (internal; see render_core.py for the traversal).

The facade of a building texel: palette wall colour with a grid of windows (floor height, window
spacing and size from the palette row), laid out along the building's wall direction (``orient``,
snapped against a Sobel estimate of the outward normal) so the windows line up along oblique
staircase walls; windows fade to their mean colour as the pixel footprint reaches the window
spacing (a procedural mip level), and the wall is Lambert-shaded with its horizontal normal.
"""

from __future__ import annotations

import math

from numba import njit

# Indices into the float64 ``params`` vector handed to the kernels (built by render.py).
P_MPP, P_E0, P_N0, P_GMAX = 0, 1, 2, 3
P_SUN = 4  # 4, 5, 6: unit vector towards the sun (ENU)
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


@njit(cache=True)
def _mirror(i, n):
    if i >= 0 and i < n:
        return i
    m = i % (2 * n)  # numba keeps Python's sign convention: m in [0, 2n)
    if m >= n:
        m = 2 * n - 1 - m
    return m


@njit(cache=True)
def _height(hpyr, hoff, hdims, level, ci, cj):
    hh = hdims[level, 0]
    ww = hdims[level, 1]
    return hpyr[hoff[level] + _mirror(cj, hh) * ww + _mirror(ci, ww)]


@njit(cache=True)
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


@njit(cache=True)
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


@njit(cache=True)
def ground_bilinear(ground, gscale, gx, gy):
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


@njit(cache=True)
def _sky(dz, params):
    w = math.sqrt(max(dz, 0.0))
    w = min(1.0, w * 1.6)
    return (
        params[P_HAZE] * (1.0 - w) + params[P_ZENITH] * w,
        params[P_HAZE + 1] * (1.0 - w) + params[P_ZENITH + 1] * w,
        params[P_HAZE + 2] * (1.0 - w) + params[P_ZENITH + 2] * w,
    )


@njit(cache=True)
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


@njit(cache=True)
def _facade(
    hx,
    hy,
    hz,
    t,
    dx,
    dy,
    dz,
    axis,
    ci,
    cj,
    pix_angle,
    hpyr,
    hoff,
    hdims,
    mat,
    orient,
    ground,
    palette,
    params,
):
    """Colour of a facade hit at metres-space point (hx, hy, hz) on texel (ci, cj)."""
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
    if ((ci % (2 * ww)) >= ww) != ((cj % (2 * hh)) >= hh):
        theta = -theta
    best = -2.0
    bx = nx
    by = ny
    for k in range(4):
        a = theta + 0.5 * math.pi * k
        cx_ = math.cos(a)
        cy_ = math.sin(a)
        d = cx_ * nx + cy_ * ny
        if d > best:
            best = d
            bx = cx_
            by = cy_
    nx = bx
    ny = by
    # Along-wall coordinate (metres) and height above the terrain.
    s = hx * (-ny) + hy * nx
    mpp = params[P_MPP]
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
    lam = nx * params[P_SUN] + ny * params[P_SUN + 1]
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
