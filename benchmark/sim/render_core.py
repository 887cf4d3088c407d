"""Numba kernels of the height-field ray caster (internal; use ``benchmark.sim.render``).

The world is a 2.5D height field: every texel of the city grid is a flat-topped column of height
``h`` (terrain + buildings + trees + cars, metres, absolute). A ray is marched through a max-mip
pyramid (Tevs et al. 2008, "Maximum mipmaps for fast, accurate, and scalable dynamic height field
rendering"): a cell of level k holds the maximum of its 2^k x 2^k texels, so a ray that stays above
that maximum while crossing the cell skips it at once; otherwise the ray descends a level. The
grid is mirror-tiled to infinity (texel index i maps to i mod 2W, reflected), so the world never
ends and a pitch-0 camera sees a horizon; with dimensions divisible by 2^L the mirror maps aligned
level-k cells onto aligned cells and one pyramid serves every copy.

A hit on a texel top is coloured by the ortho texture (baked sun shading and shadows), sampled
trilinearly from its mip pyramid at the level matching the pixel footprint (footprint
``t * pixel_angle / sqrt(|cos incidence|)``), so distant ground does not shimmer. A hit on a texel's
side is a wall: entering a building from outside gives a facade (palette colour + window grid +
Lambert shading with the wall normal), other steps (terrain, gable steps, cars) reuse the texture.
Windows fade to their mean colour when the pixel footprint approaches the window spacing (the
procedural equivalent of a mip level). Fog: ``c = c e^{-t/V} + haze (1 - e^{-t/V})``.

Grid coordinates: ``gx = (E - E0) / mpp`` and ``gy = (N - N0) / mpp``; texel ``[j, i]`` covers
``gx in [i, i+1)``, ``gy in [j, j+1)`` (row 0 is the southern edge). Everything here is float64,
serial and free of fastmath, so a frame is bit-identical across runs and machines with the same
numba/LLVM.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from benchmark.sim.render_shading import (  # noqa: F401  (re-exported constants)
    MAT_BUILDING,
    MAT_GROUND,
    MAT_SMALL,
    MAT_TREE,
    MAT_WATER,
    MAX_ITER,
    N_PARAMS,
    P_AMB,
    P_DIF,
    P_E0,
    P_GMAX,
    P_GMIN,
    P_GSCALE,
    P_HAZE,
    P_MPP,
    P_N0,
    P_SUN,
    P_TMAX,
    P_VIS,
    P_ZENITH,
    WALL_STEP_M,
    _facade,
    _fog,
    _height,
    _mirror,
    _sky,
    _trilinear_rgb,
    ground_bilinear,
)


@njit(cache=True)
def trace(
    ox,
    oy,
    oz,
    dx,
    dy,
    dz,
    pix_angle,
    hpyr,
    hoff,
    hdims,
    tex,
    toff,
    tdims,
    mat,
    orient,
    ground,
    palette,
    params,
):
    """Colour (0..255, float64 ``(3,)``) seen along one ray.

    ``(ox, oy)`` and ``(dx, dy)`` are in grid units (texels, and texels per metre of ray length),
    ``oz``/``dz`` in metres; ``t`` is the ray length in metres (the direction is unit in metres).
    """
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
    for _ in range(MAX_ITER):
        if t > tmax:
            break
        px = ox + t * dx
        py = oy + t * dy
        s = float(1 << level)
        ci = math.floor(px / s)
        cj = math.floor(py / s)
        if dx > 0.0:
            tx = ((ci + 1) * s - ox) / dx
        elif dx < 0.0:
            tx = (ci * s - ox) / dx
        else:
            tx = inf
        if dy > 0.0:
            ty = ((cj + 1) * s - oy) / dy
        elif dy < 0.0:
            ty = (cj * s - oy) / dy
        else:
            ty = inf
        texit = min(tx, ty)
        h = _height(hpyr, hoff, hdims, level, ci, cj)
        zin = oz + t * dz
        zout = oz + texit * dz
        if zin > h and zout > h:
            axis = 0 if tx < ty else 1
            t = texit + 1e-7
            if dz >= 0.0 and zout > gmax:
                return _sky(dz, params)
            if level < L:
                # Ascend only when the step also leaves the parent cell.
                nci = math.floor((ox + t * dx) / s)
                ncj = math.floor((oy + t * dy) / s)
                if (nci >> 1) != (ci >> 1) or (ncj >> 1) != (cj >> 1):
                    level += 1
            continue
        if level > 0:
            if zin > h:
                t = max(t, (oz - h) / (-dz))
                axis = -1
            level -= 1
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
        # Side face: which texel did the ray come from?
        if axis == 0:
            pi_ = ci - (1 if dx > 0 else -1)
            pj_ = cj
        else:
            pi_ = ci
            pj_ = cj - (1 if dy > 0 else -1)
        hh0 = hdims[0, 0]
        ww0 = hdims[0, 1]
        m_here = mat[_mirror(cj, hh0), _mirror(ci, ww0)]
        m_prev = mat[_mirror(pj_, hh0), _mirror(pi_, ww0)]
        h_prev = _height(hpyr, hoff, hdims, 0, pi_, pj_)
        hx = ox + t * dx
        hy = oy + t * dy
        if m_here >= MAT_BUILDING and (m_prev < MAT_BUILDING or h - h_prev > WALL_STEP_M):
            col = _facade(
                hx * mpp,
                hy * mpp,
                zin,
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
            )
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


@njit(cache=True)
def render_image(
    out,
    R,
    pos,
    f,
    cx,
    cy,
    ss,
    hpyr,
    hoff,
    hdims,
    tex,
    toff,
    tdims,
    mat,
    orient,
    ground,
    palette,
    params,
):
    """Fill ``out`` (H, W, 3) uint8 by casting ``ss x ss`` rays per pixel (box filter).

    ``R`` is ``R_b^n`` (3, 3); ``pos`` the ENU camera centre; ``f, cx, cy`` the pinhole intrinsics
    (camera.py conventions). Rounding is half-up of the float mean, deterministic.
    """
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
                    col = trace(
                        ox,
                        oy,
                        oz,
                        ex / mpp,
                        ey / mpp,
                        ez,
                        pix_angle,
                        hpyr,
                        hoff,
                        hdims,
                        tex,
                        toff,
                        tdims,
                        mat,
                        orient,
                        ground,
                        palette,
                        params,
                    )
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
