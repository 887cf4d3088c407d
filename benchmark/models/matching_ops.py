"""The matching encoder's differentiable operators: the bird's-eye templates of the UAV view at
every yaw, the satellite features on the same metric grid, and their exhaustive correlation.

Shapes: ``B`` pairs, ``C`` feature channels, ``K`` yaw candidates, templates ``t x t`` cells
(``t = 2 r + 1``), satellite grid ``G x G`` cells (``G = 2 (n + r) + 1`` for ``2 n + 1``
candidate positions per axis). Metres and radians throughout.
"""

from __future__ import annotations

import functools
import math
import threading
from collections import OrderedDict
from typing import Any

import torch
import torch.nn.functional as nnf
from torch import Tensor

from benchmark.models.matching_geometry import (
    ground_to_uav_pixel,
    offset_grid,
    pixel_to_grid,
    rotate_to_level,
    sat_pixel_of_offset,
)
from benchmark.models.matching_options import CORRELATIONS

__all__ = [
    "CORRELATIONS",
    "bev_templates",
    "bev_templates_planes",
    "correlate",
    "correlate_conv",
    "correlate_dft",
    "correlate_fft",
    "correlate_xdft",
    "fft_size",
    "sat_grid",
    "unit_channels",
]


# grid_sample coordinate of a masked template cell: three map widths left of and above the map,
# so none of its four bilinear neighbours is inside (their weights multiply zero padding).
OUTSIDE_GRID = -7.0


def _template_cells(
    like: Tensor, yaws: Tensor, radius: int, cell_m: float
) -> tuple[Tensor, Tensor]:
    """The template cells of every yaw in the UAV's level frame, ``(B, K, t, t, 2)`` (B and the
    dtype and device from ``like``), and the disc of radius ``radius`` cells, ``(t, t)`` bool."""
    b, k = like.shape[0], yaws.shape[0]
    grid = offset_grid(radius, cell_m, dtype=like.dtype).to(like.device)
    t = grid.shape[0]
    level = rotate_to_level(grid.unsqueeze(0), yaws.view(k, 1, 1))  # (K, t, t, 2)
    disc = grid.square().sum(-1) <= (radius * cell_m) ** 2 + 1e-6
    return level.unsqueeze(0).expand(b, k, t, t, 2), disc


def bev_templates(
    uav_features: Tensor,
    stride: tuple[int, int],
    size: int,
    yaws: Tensor,
    radius: int,
    cell_m: float,
    pitch: Tensor,
    roll: Tensor,
    altitude: Tensor,
    fov: Tensor,
) -> tuple[Tensor, Tensor]:
    """North-up bird's-eye templates of the UAV features, one per candidate yaw.

    Each template cell is an ENU offset ``(dE, dN)`` from the point below the UAV (rows north
    first, :func:`~benchmark.models.matching_geometry.offset_grid`). For yaw ``psi`` the cell is
    turned into the level frame, projected into the UAV image with the camera model and sampled
    (bilinear) from ``uav_features (B, C, h, w)`` of stride ``stride``: one interpolation per
    cell, no image rotation. Cells outside the image, behind the camera or farther than
    ``radius`` cells (a disc, so every yaw sees the same support) are masked.

    Returns ``templates (B, K, C, t, t)`` (zero where masked) and ``mask (B, K, t, t)`` bool.
    """
    b, c = uav_features.shape[:2]
    k = yaws.shape[0]
    level, disc = _template_cells(uav_features, yaws, radius, cell_m)
    t = disc.shape[0]
    uv, valid = ground_to_uav_pixel(level, pitch, roll, altitude, fov, size)
    mask = valid & disc
    coords = pixel_to_grid(uv, size, stride)
    # A masked cell samples far outside the map, where zero padding gives exactly 0 and no
    # gradient (to the features or the geometry): the same templates as multiplying by the
    # mask, without a pass over them and its backward.
    coords = torch.where(mask.unsqueeze(-1), coords, coords.new_tensor(OUTSIDE_GRID))
    sampled = nnf.grid_sample(
        uav_features, coords.reshape(b, k * t, t, 2), mode="bilinear", padding_mode="zeros",
        align_corners=True,
    )  # (B, C, K t, t)  # fmt: skip
    return sampled.view(b, c, k, t, t).permute(0, 2, 1, 3, 4), mask


def bev_templates_planes(
    uav_features: Tensor,
    plane_logits: Tensor,
    plane_heights: Tensor,
    stride: tuple[int, int],
    size: int,
    yaws: Tensor,
    radius: int,
    cell_m: float,
    pitch: Tensor,
    roll: Tensor,
    altitude: Tensor,
    fov: Tensor,
) -> tuple[Tensor, Tensor]:
    """Height-aware bird's-eye templates: :func:`bev_templates` on ``P`` horizontal planes.

    A flat-ground view puts a roof ``h`` metres up at ``altitude / (altitude - h)`` times its
    true distance (1.4x for a 30 m roof seen from 100 m), and in a city of tall blocks most of a
    shallow view is roofs and facades. Here every pixel carries a distribution over the planes
    ``plane_heights (P,)`` (metres above the ground) and one more class, "on no plane" (sky,
    facades: what a nadir image does not show): ``softmax(plane_logits (B, P + 1, h, w))`` over
    channels, on the features' grid. The cell ``(dE, dN)`` at yaw ``psi`` is projected once per
    plane (the point ``h_p`` above the ground is ``altitude - h_p`` below the camera) to pixel
    ``u_p`` and collects ``sum_p q_p(u_p) F(u_p)``: a pixel contributes where the column it sees
    meets the plane it believes it is on (after OrienterNet's depth-distribution lifting, with
    heights instead of depths, since the satellite is nadir).

    Returns ``templates (B, K, C, t, t)`` and ``weight (B, K, t, t)``, the cell's total
    probability ``sum_p q_p(u_p)`` over the planes where it projects validly (float in
    ``[0, P]``; 0 outside the disc). Planes at or above the camera are refused.
    """
    b, c = uav_features.shape[:2]
    n_planes = plane_heights.shape[0]
    if (
        plane_logits.shape[:2] != (b, n_planes + 1)
        or plane_logits.shape[-2:] != uav_features.shape[-2:]
    ):
        raise ValueError(
            f"bev_templates_planes: plane_logits must be (B, P + 1, h, w) = ({b}, {n_planes + 1}, "
            f"{tuple(uav_features.shape[-2:])}), got {tuple(plane_logits.shape)}"
        )
    top = plane_heights.max()
    if bool((altitude <= top).any()):
        raise ValueError(
            f"bev_templates_planes: plane {float(top):g} m is not below every camera "
            f"(altitudes {altitude.min().item():.1f}..{altitude.max().item():.1f} m)"
        )
    prob = torch.softmax(plane_logits, dim=1)[:, :n_planes]  # (B, P, h, w)
    k = yaws.shape[0]
    level, disc = _template_cells(uav_features, yaws, radius, cell_m)
    t = disc.shape[0]
    templates = uav_features.new_zeros(b, k, c, t, t)
    weight = uav_features.new_zeros(b, k, t, t)
    for p in range(n_planes):
        below = altitude - plane_heights[p]  # the camera's height above plane p
        uv, valid = ground_to_uav_pixel(level, pitch, roll, below, fov, size)
        coords = pixel_to_grid(uv, size, stride).reshape(b, k * t, t, 2)
        both = torch.cat([uav_features, prob[:, p : p + 1]], dim=1)  # one interpolation pass
        sampled = nnf.grid_sample(
            both, coords, mode="bilinear", padding_mode="zeros", align_corners=True
        ).view(b, c + 1, k, t, t)
        q = sampled[:, c] * (valid & disc).to(sampled.dtype)  # (B, K, t, t)
        templates = templates + sampled[:, :c].permute(0, 2, 1, 3, 4) * q.unsqueeze(2)
        weight = weight + q
    return templates, weight


def unit_channels(x: Tensor, eps: float = 1e-12) -> Tensor:
    """``x (B, C, H, W)`` divided by its L2 norm over the channels (floored at ``eps``): what
    ``nnf.normalize(x, dim=1)`` gives, to float rounding, 3.5x faster forward and backward on
    contiguous NCHW maps here (its ``linalg.vector_norm`` over a strided dimension is slow)."""
    return x / x.square().sum(1, keepdim=True).sqrt().clamp_min(eps)


def sat_grid(
    sat_features: Tensor,
    stride: tuple[int, int],
    size: int,
    footprint_m: Tensor,
    radius: int,
    cell_m: float,
) -> Tensor:
    """Satellite features resampled to the metric grid ``(B, C, G, G)``, ``G = 2 radius + 1``,
    centred on the image centre, north up (zero outside the footprint). ``sat_features (B, C,
    h, w)`` (one per pair), ``footprint_m (B, 2)`` (E, N) metres."""
    b = sat_features.shape[0]
    grid = offset_grid(radius, cell_m, dtype=sat_features.dtype).to(sat_features.device)
    uv = sat_pixel_of_offset(grid.unsqueeze(0).expand(b, *grid.shape), footprint_m, size)
    coords = pixel_to_grid(uv, size, stride)
    return nnf.grid_sample(
        sat_features, coords, mode="bilinear", padding_mode="zeros", align_corners=True
    )


def correlate_conv(sat: Tensor, templates: Tensor) -> Tensor:
    """``out[b, k, y, x] = sum_{c, i, j} templates[b, k, c, i, j] sat[b, c, y + i, x + j]``:
    every template placed at every position where it fits (``(B, K, G - t + 1, G - t + 1)``),
    as one grouped ``conv2d`` (groups = B)."""
    b, k, c, t, _ = templates.shape
    g = sat.shape[-1]
    out = nnf.conv2d(sat.reshape(1, b * c, g, g), templates.reshape(b * k, c, t, t), groups=b)
    return out.view(b, k, g - t + 1, g - t + 1)


def fft_size(n: int) -> int:
    """The smallest ``m >= n`` whose prime factors are 2, 3 and 5 (pocketfft is fast there; a
    prime size such as 71 takes Bluestein's algorithm, about 10x slower here)."""
    m = max(1, n)
    while True:
        k = m
        for p in (2, 3, 5):
            while k % p == 0:
                k //= p
        if k == 1:
            return m
        m += 1


def correlate_fft(sat: Tensor, templates: Tensor) -> Tensor:
    """:func:`correlate_conv` by the FFT: ``conj(F(template)) F(sat)`` summed over channels is the
    circular cross-correlation; with an FFT size ``L >= G`` the kept outputs ``y, x <= G - t``
    read ``y + i <= G - 1 < L``, so nothing wraps around. Computed in float32 at least."""
    t = templates.shape[-1]
    g = sat.shape[-1]
    n = fft_size(g)
    dtype = torch.promote_types(sat.dtype, torch.float32)
    # Channels first, so that each channel's spectra are contiguous blocks.
    fs = torch.fft.rfft2(sat.to(dtype).transpose(0, 1), s=(n, n))  # (C, B, L, L//2+1)
    ft = torch.fft.rfft2(templates.to(dtype).permute(2, 0, 1, 3, 4), s=(n, n)).conj()
    # Sum over channels one at a time: a batched matmul over every frequency would run
    # B L (L/2 + 1) tiny (K x C) @ (C x 1) products, and the full broadcast product would hold
    # B K C L (L/2 + 1) complex numbers.
    # (unbind, not indexing: the backward of C selects would zero-fill C full-size gradients).
    ft_c, fs_c = ft.unbind(0), fs.unsqueeze(2).unbind(0)  # (B, K, L, L//2+1), (B, 1, ...)
    prod = ft_c[0] * fs_c[0]
    for a, b in zip(ft_c[1:], fs_c[1:], strict=True):
        prod = prod + a * b
    out = torch.fft.irfft2(prod, s=(n, n))
    m = g - t + 1
    return out[..., :m, :m].to(sat.dtype)


@functools.lru_cache(maxsize=8)
def _dft_matrices(t: int, g: int, device: str) -> tuple[Tensor, ...]:
    """complex64 DFT matrices of :func:`correlate_dft` (built in float64, then rounded)."""
    n = fft_size(g)
    half = n // 2 + 1
    m = g - t + 1
    f64 = torch.float64

    def e(a: int, b: int, sign: float) -> Tensor:
        i = torch.arange(a, dtype=f64)[:, None]
        j = torch.arange(b, dtype=f64)[None, :]
        return torch.polar(torch.ones(a, b, dtype=f64), sign * 2 * math.pi * i * j / n)

    weights = torch.full((half,), 2.0, dtype=f64)  # Hermitian half-spectrum: the other half
    weights[0] = 1.0  # v = 0 has no mirror
    if n % 2 == 0:
        weights[-1] = 1.0  # nor has v = n / 2
    mats = (
        e(t, half, -1.0),  # columns of a template -> half spectrum
        e(n, t, -1.0),  # rows of a template -> full spectrum
        e(g, half, -1.0),
        e(n, g, -1.0),
        e(m, n, 1.0) / n**2,  # inverse along rows, only the m kept outputs
        e(half, m, 1.0) * weights[:, None],  # inverse along columns (real part)
    )
    return tuple(x.to(device=device, dtype=torch.complex64) for x in mats)


def _spectrum_t(x: Tensor, cols: Tensor, rows: Tensor) -> Tensor:
    """``(N, s, s)`` real maps -> their (half) 2D DFTs *transposed*, ``(N, V, L)`` complex64: two
    plain GEMMs, ``(N s, s) @ (s, V)`` along the columns, then ``(N V, s) @ (s, L)`` along the
    rows (keeping the spectrum transposed avoids broadcasting the row matrix over N)."""
    n, size = x.shape[0], x.shape[-1]
    y = (x.to(torch.complex64).reshape(n * size, size) @ cols).view(n, size, -1)  # (N, i, V)
    y = y.transpose(1, 2).reshape(-1, size)  # (N V, i)
    return (y @ rows.transpose(0, 1)).view(n, -1, rows.shape[0])


def correlate_dft(sat: Tensor, templates: Tensor) -> Tensor:
    """:func:`correlate_fft` with the transforms as matrix products: the DFT of a template
    supported on ``t x t`` cells, padded to ``L x L``, is ``E_L,t T E_t,L/2+1`` (no work on the
    zero padding), and the inverse is evaluated only at the ``m x m`` kept outputs. A few large
    complex GEMMs instead of many small FFTs: 1.2-1.5x faster than :func:`correlate_fft` for a
    training step here (36 yaws, 8 channels, 25 x 25 templates on a 63 x 63 grid). complex64, so
    ~1e-6 relative error like the FFT in float32."""
    b, k, c, t, _ = templates.shape
    g = sat.shape[-1]
    cols_t, rows_t, cols_g, rows_g, inv_rows, inv_cols = _dft_matrices(t, g, str(sat.device))
    ft = _spectrum_t(templates.reshape(-1, t, t), cols_t, rows_t)
    ft = ft.view(b, k, c, *ft.shape[1:]).conj()  # (B, K, C, V, L)
    fs = _spectrum_t(sat.reshape(-1, g, g), cols_g, rows_g)
    fs = fs.view(b, 1, c, *fs.shape[1:])
    ft_c, fs_c = ft.unbind(2), fs.unbind(2)  # channel by channel (see correlate_fft)
    prod = ft_c[0] * fs_c[0]
    for x, y in zip(ft_c[1:], fs_c[1:], strict=True):
        prod = prod + x * y  # (B, K, V, L)
    half, n = prod.shape[-2:]
    m = inv_rows.shape[0]
    q = (prod.reshape(-1, n) @ inv_rows.transpose(0, 1)).view(b * k, half, m)  # rows -> y
    out = q.transpose(1, 2).reshape(-1, half) @ inv_cols  # columns -> x: (B K m, m)
    return out.real.view(b, k, m, m).to(sat.dtype)


@functools.lru_cache(maxsize=8)
def _xdft_matrices(t: int, g: int, device: str) -> tuple[Tensor, Tensor, Tensor]:
    """float64 real matrices of :func:`correlate_xdft` (``V = L // 2 + 1`` frequencies, ``a``
    0 for the real and 1 for the imaginary part):

    - ``conj_t (V 2, t)``: rows ``(v, a)``, the conjugate DFT along a template row,
      ``cos(2 pi v j / L)``, ``+sin(2 pi v j / L)``;
    - ``sat_x (g, 2 V)``: columns ``(a, v)``, the DFT along a satellite row, ``cos``, ``-sin``;
    - ``inv (2 V 2, m)``: rows ``(a_s, v, a_t)``, the inverse half-spectrum DFT at the ``m``
      kept columns applied to the four real products ``Q_{a_t} S_{a_s}`` (real part
      ``Q_0 S_0 - Q_1 S_1``, imaginary part ``Q_0 S_1 + Q_1 S_0``), Hermitian weights
      included (that row order makes a pair's products, ``(v a_t, k y a_s)``, one plain
      matrix transpose away from the inverse's input)."""
    n = fft_size(g)
    half = n // 2 + 1
    m = g - t + 1
    f64 = torch.float64
    v = torch.arange(half, dtype=f64)

    def phase(k: int) -> Tensor:  # (k, V)
        return 2 * math.pi * torch.arange(k, dtype=f64)[:, None] * v[None, :] / n

    pt, pg, px = phase(t), phase(g), phase(m).T  # px (V, m)
    conj_t = torch.stack([pt.cos().T, pt.sin().T], dim=1).reshape(2 * half, t)
    sat_x = torch.cat([pg.cos(), -pg.sin()], dim=1)
    weights = torch.full((half, 1), 2.0, dtype=f64)  # the mirrored half of the spectrum
    weights[0] = 1.0  # v = 0 has no mirror
    if n % 2 == 0:
        weights[-1] = 1.0  # nor has v = n / 2
    re, im = weights * px.cos() / n, -weights * px.sin() / n  # Re(X e^{+i..}) = Xr cos - Xi sin
    inv = torch.stack([torch.stack([re, im], 1), torch.stack([im, -re], 1)], 1)  # (v, a_t, a_s, m)
    inv = inv.permute(2, 0, 1, 3).reshape(4 * half, m)  # rows (a_s, v, a_t)
    return conj_t.to(device), sat_x.to(device), inv.to(device)


# Pairs per block of correlate_xdft: a block's template spectra and windows (about 2 MB each per
# pair at the quick shapes) stay in the cache through its three GEMMs. 2 pairs: in bf16 1.1x
# faster than 1 (fewer, larger calls), in float32 the same; 4 was slower in float32.
XDFT_BLOCK = 2


def correlate_xdft(sat: Tensor, templates: Tensor, block: int = XDFT_BLOCK) -> Tensor:
    """:func:`correlate_conv` with a DFT along the columns (east) only and the correlation along
    the rows (north) as one batched matrix product: per pair ``b`` and column frequency ``v``,

    ``X[v](k, y) = sum_{c, i} conj(T^[v])(k, c, i) S^[v](c, y + i)``

    (``^``: the DFT of a row, length ``L >= G``, so that the kept columns do not wrap), a
    ``(2 K, C t) @ (C t, 2 m)`` real GEMM holding the four products of real and imaginary parts,
    then the inverse half-spectrum DFT at the ``m`` kept columns. Along the rows the direct sum
    is cheaper than a transform: ``t m`` products per output row against ``~ 2 t L`` for the
    DFT of the template's rows alone (t = 25, m = 39, L = 64 here). Only real GEMMs: 1.05 G
    multiply-adds forward for the quick step's (B, K, C, t, G) = (20, 36, 8, 25, 63) against
    :func:`correlate_dft`'s 1.7 G in complex arithmetic (which also pays copies of its complex
    intermediates).

    Computed ``block`` pairs at a time, forward and backward (an ``autograd.Function`` that
    keeps its templates and the grid's row spectra, and recomputes a block's template spectra
    and windows in the backward pass: about 5 % more multiply-adds, and every intermediate
    stays in the cache instead of ~80 MB of them going through memory). A block's
    intermediates live in buffers kept per thread and shapes and reused by every block, call
    and step (:class:`_XdftWorkspace`): on this VM a fresh buffer costs ~10x its copy in page
    faults. The backward computes the windows' gradient transposed and adds it back onto the
    grid rows one output row at a time; the layouts are in :class:`_XdftCorrelation`. Same
    numbers as :func:`correlate_conv` to rounding (float64
    in tests); the GEMMs run in float32 at least, or in the autocast dtype when autocast is on
    (bf16 on a CPU with AMX), the result in ``sat``'s dtype."""
    dtype = torch.promote_types(sat.dtype, torch.float32)
    if torch.is_autocast_enabled(sat.device.type):
        dtype = torch.get_autocast_dtype(sat.device.type)
    return _XdftCorrelation.apply(sat, templates, dtype, max(1, int(block)))


class _XdftCorrelation(torch.autograd.Function):
    """:func:`correlate_xdft`, block by block. Layouts (``a``: real/imaginary part, ``v``:
    column frequency, ``i``/``j``: template row/column, ``r``: grid row, ``y``: output row):
    grid spectra ``(B, V, C, G, 2)``; template spectra ``q (n V, 2 K, C t)`` rows ``(a, k)``;
    grid windows ``(n V, C t, m 2)`` rows ``(c, i)``, columns ``(y, a)``; products
    ``(n V, 2 K, m 2)``; the windows' gradient transposed, ``(n V, m 2, C t)``, summed onto
    the grid rows ``(B, V, 2, C, G)`` (a, c, r) in float32 at least (the backward's
    accumulator whatever the GEMMs' dtype). Every block's intermediates go to the buffers of
    one :class:`_XdftWorkspace`."""

    @staticmethod
    def forward(ctx: Any, sat: Tensor, templates: Tensor, dtype: torch.dtype, block: int) -> Tensor:
        b, k, c, t, _ = templates.shape
        g = sat.shape[-1]
        m = g - t + 1
        with torch.autocast(sat.device.type, enabled=False):  # every cast explicit
            conj_t, sat_x, inv = _xdft_matrices_as(t, g, sat.device, dtype)
            half = conj_t.shape[0] // 2
            spec = _xdft_grid_spectra(sat.to(dtype), sat_x)
            ws = _xdft_workspace(b, min(block, b), half, k, c, t, m, dtype, sat.device)
            out = torch.empty((b, k, m, m), dtype=sat.dtype, device=sat.device)
            for lo in range(0, b, block):
                hi = min(b, lo + block)
                n = hi - lo
                q = _xdft_template_spectra(templates[lo:hi], conj_t, ws)
                windows = _xdft_windows(spec[lo:hi], t, ws.buffer("windows", n))
                prod = torch.bmm(q, windows, out=ws.buffer("prod", n))
                _xdft_inverse(prod, n, inv, ws, out[lo:hi])
        ctx.save_for_backward(spec, templates)
        ctx.dtype, ctx.block, ctx.sat_dtype = dtype, block, sat.dtype
        return out

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx: Any, grad: Tensor) -> tuple[Tensor | None, Tensor | None, None, None]:
        spec, templates = ctx.saved_tensors
        dtype, block = ctx.dtype, ctx.block
        b, k, c, t, _ = templates.shape
        g = spec.shape[3]
        m = g - t + 1
        want_sat, want_templates = ctx.needs_input_grad[:2]
        with torch.autocast(spec.device.type, enabled=False):
            conj_t, sat_x, inv = _xdft_matrices_as(t, g, spec.device, dtype)
            half = conj_t.shape[0] // 2
            ws = _xdft_workspace(b, min(block, b), half, k, c, t, m, dtype, spec.device)
            g_grid = ws.buffer("grid_acc", b).zero_() if want_sat else None  # (b, v, a, c, r)
            g_templates = torch.empty_like(templates) if want_templates else None
            for lo in range(0, b, block):
                hi = min(b, lo + block)
                n = hi - lo
                # d out / d prod: the inverse DFT's transpose, back into the product's layout
                g_out = grad[lo:hi].reshape(n * k * m, m).to(dtype)
                g_all = torch.mm(g_out, inv.T, out=ws.buffer("prod_t", n))  # (n k y, a_s v a_t)
                g_prod = ws.buffer("prod", n)
                _transpose_pairs(g_all.view(n, k * m * 2, 2 * half), g_prod.view(n, 2 * half, -1))
                if g_templates is not None:
                    windows = _xdft_windows(spec[lo:hi], t, ws.buffer("windows", n))
                    g_q = torch.bmm(g_prod, windows.transpose(1, 2), out=ws.buffer("q", n))
                    g_rows = torch.bmm(  # (n, j, k c i)
                        conj_t.T.expand(n, t, 2 * half),
                        g_q.view(n, 2 * half, k * c * t),
                        out=ws.buffer("rows", n),
                    )
                    g_templates[lo:hi] = g_rows.view(n, t, k, c, t).permute(0, 2, 3, 4, 1)
                if g_grid is not None:
                    q = _xdft_template_spectra(templates[lo:hi], conj_t, ws)
                    # the windows' gradient transposed, (n V, m 2, C t): 1.4x faster than
                    # (n V, C t, m 2) in float32 here, the same in bf16
                    g_win = torch.bmm(g_prod.transpose(1, 2), q, out=ws.buffer("windows_t", n))
                    if g_win.dtype != g_grid.dtype:
                        g_win = ws.buffer("windows_acc", n).copy_(g_win)
                    # output row y read the grid rows r = y + i: add its t rows back there
                    # (m slice adds, each of (n, V, 2, C, t) with contiguous runs of t)
                    g_win = g_win.view(n, half, m, 2, c, t)
                    part = g_grid[lo:hi]
                    for y in range(m):
                        part[..., y : y + t] += g_win[:, :, y]
            g_sat = None
            if g_grid is not None:
                # (b, v, a, c, r) -> (b c r, a v) @ the row DFT's transpose -> (b c r, x)
                flat = ws.buffer("grid_flat", b).copy_(g_grid.permute(0, 3, 4, 2, 1))
                g_sat = (flat.view(b * c * g, 2 * half) @ sat_x.T).view(b, c, g, g)
                g_sat = g_sat.to(ctx.sat_dtype)
        return g_sat, g_templates, None, None


class _XdftWorkspace:
    """The scratch buffers of :class:`_XdftCorrelation` for one set of shapes (``b`` pairs,
    blocks of ``n``), allocated on first use and reused by every block, call and training step:
    a fresh buffer of a few MB costs ~10x its copy here in page faults (0.6-0.8 ms against
    0.05 ms for 2 MB, measured on a 2-core VM), which made most of the old step's copy time."""

    def __init__(
        self, b: int, n: int, half: int, k: int, c: int, t: int, m: int, dtype: torch.dtype,
        device: torch.device,
    ) -> None:  # fmt: skip
        acc = torch.promote_types(dtype, torch.float32)
        self.shapes: dict[str, tuple[tuple[int, ...], torch.dtype]] = {
            "templates": ((n, k, c, t, t), dtype),  # a block's templates in the GEMMs' dtype
            "q": ((n * half, 2 * k, c * t), dtype),
            "windows": ((n * half, c * t, 2 * m), dtype),
            "windows_t": ((n * half, 2 * m, c * t), dtype),  # the same memory as windows
            "windows_acc": ((n * half, 2 * m, c * t), acc),
            "prod": ((n * half, 2 * k, 2 * m), dtype),
            "prod_t": ((n * k * m, 4 * half), dtype),
            "out": ((n * k * m, m), dtype),
            "rows": ((n, t, k * c * t), dtype),
            "grid_acc": ((b, half, 2, c, m + t - 1), acc),
            "grid_flat": ((b, c, m + t - 1, 2, half), dtype),
        }
        self.n, self.device = n, device
        self.memory: dict[str, Tensor] = {}

    def buffer(self, name: str, n: int) -> Tensor:
        """Buffer ``name`` for ``n <= self.n`` pairs (the ``grid_*`` ones: always all ``b``)."""
        shape, dtype = self.shapes[name]
        key = "windows" if name == "windows_t" else name
        if key not in self.memory:
            numel = math.prod(shape)
            self.memory[key] = torch.empty(numel, dtype=dtype, device=self.device)
        full = self.memory[key]
        if name.startswith("grid_"):
            return full.view(shape)
        part = (shape[0] // self.n) * n
        return full[: part * math.prod(shape[1:])].view(part, *shape[1:])


_WORKSPACES = threading.local()
_WORKSPACE_SHAPES = 4  # workspaces kept per thread (train and eval batches, ...)


def _xdft_workspace(
    b: int, n: int, half: int, k: int, c: int, t: int, m: int, dtype: torch.dtype,
    device: torch.device,
) -> _XdftWorkspace:  # fmt: skip
    """This thread's :class:`_XdftWorkspace` for these shapes (the least recently used of more
    than ``_WORKSPACE_SHAPES`` dropped). Per thread, so that concurrent calls never share a
    buffer; within a thread a call uses it only while it runs (no buffer outlives a forward or
    backward pass)."""
    cache: OrderedDict[tuple[Any, ...], _XdftWorkspace] | None = getattr(_WORKSPACES, "cache", None)
    if cache is None:
        cache = _WORKSPACES.cache = OrderedDict()
    key = (b, n, half, k, c, t, m, dtype, str(device))
    if key in cache:
        cache.move_to_end(key)
    else:
        cache[key] = _XdftWorkspace(b, n, half, k, c, t, m, dtype, device)
        while len(cache) > _WORKSPACE_SHAPES:
            cache.popitem(last=False)
    return cache[key]


def _xdft_matrices_as(
    t: int, g: int, device: torch.device, dtype: torch.dtype
) -> tuple[Tensor, Tensor, Tensor]:
    """:func:`_xdft_matrices` in ``dtype``."""
    conj_t, sat_x, inv = _xdft_matrices(t, g, str(device))
    return conj_t.to(dtype), sat_x.to(dtype), inv.to(dtype)


def _xdft_grid_spectra(sat: Tensor, sat_x: Tensor) -> Tensor:
    """``sat (B, C, G, G)`` -> the DFT of every grid row, ``(B, V, C, G, 2)`` (v, c, r, a)."""
    b, c, g, _ = sat.shape
    half = sat_x.shape[1] // 2
    spec = (sat.reshape(-1, g) @ sat_x).view(b, c, g, 2, half)  # (b, c, r, a, v)
    return spec.permute(0, 4, 1, 2, 3).contiguous()


def _xdft_template_spectra(templates: Tensor, conj_t: Tensor, ws: _XdftWorkspace) -> Tensor:
    """``templates (n, K, C, t, t)`` -> conjugate row spectra ``(n V, 2 K, C t)`` in
    ``conj_t``'s dtype: one GEMM per pair over every template's rows, ``(2 V, t) @ (t, K C t)``,
    the right operand the templates themselves read transposed (no copy of them but the cast
    to a lower GEMM dtype)."""
    n, k, c, t, _ = templates.shape
    if templates.dtype != conj_t.dtype:
        templates = ws.buffer("templates", n).copy_(templates)
    rows = templates.reshape(n, k * c * t, t).transpose(1, 2)  # (n, j, k c i)
    q = ws.buffer("q", n)
    torch.bmm(conj_t.expand(n, *conj_t.shape), rows, out=q.view(n, conj_t.shape[0], -1))
    return q


def _xdft_windows(spec: Tensor, t: int, out: Tensor) -> Tensor:
    """Grid row spectra ``(n, V, C, G, 2)`` -> their Toeplitz windows ``out (n V, C t, m 2)``:
    entry ``((c, i), (y, a))`` is row ``r = y + i`` (one copy with contiguous runs of ``m 2``)."""
    n, half, c, g, _ = spec.shape
    m = g - t + 1
    out.view(n, half, c, t, m, 2).copy_(spec.unfold(3, t, 1).permute(0, 1, 2, 5, 3, 4))
    return out


def _transpose_pairs(src: Tensor, out: Tensor) -> None:
    """``out[p] = src[p].T`` for every pair ``p``: each a 2-D copy, which ATen runs as a
    blocked transpose (2x faster here than the same copy as one 3-D permute of the block)."""
    for p in range(src.shape[0]):
        out[p].copy_(src[p].T)


def _xdft_inverse(prod: Tensor, n: int, inv: Tensor, ws: _XdftWorkspace, out: Tensor) -> None:
    """Products ``(n V, 2 K, m 2)`` -> the correlation ``out (n, K, m, m)``: the four products
    of real and imaginary parts combined and inverted at the kept columns by one GEMM (cast to
    ``out``'s dtype last)."""
    half = inv.shape[0] // 4
    k, m = out.shape[1], out.shape[2]
    buf = ws.buffer("prod_t", n)  # (n k y, a_s v a_t)
    _transpose_pairs(prod.view(n, 2 * half, k * m * 2), buf.view(n, k * m * 2, 2 * half))
    flat = out.view(n * k * m, m)
    if out.dtype == buf.dtype:
        torch.mm(buf, inv, out=flat)
    else:
        flat.copy_(torch.mm(buf, inv, out=ws.buffer("out", n)))


def correlate(sat: Tensor, templates: Tensor, method: str = "xdft") -> Tensor:
    """:func:`correlate_xdft` (``method="xdft"``), :func:`correlate_dft` (``"dft"``),
    :func:`correlate_fft` (``"fft"``) or :func:`correlate_conv` (``"conv"``): the same numbers
    (to float32 rounding)."""
    if sat.dim() != 4 or templates.dim() != 5 or sat.shape[-1] != sat.shape[-2]:
        raise ValueError(
            f"correlate: sat must be (B, C, G, G) and templates (B, K, C, t, t), got "
            f"{tuple(sat.shape)} and {tuple(templates.shape)}"
        )
    if templates.shape[-1] > sat.shape[-1]:
        raise ValueError(
            f"correlate: templates ({templates.shape[-1]} cells) larger than the grid "
            f"({sat.shape[-1]})"
        )
    if method == "xdft":
        return correlate_xdft(sat, templates)
    if method == "dft":
        return correlate_dft(sat, templates)
    if method == "fft":
        return correlate_fft(sat, templates)
    if method == "conv":
        return correlate_conv(sat, templates)
    raise ValueError(f"correlate: method must be one of {CORRELATIONS}, got {method!r}")
