"""``flop_count``: the FLOP formulas the benchmarks add to torch's counter (complex matrix
products, complex elementwise products, bilinear sampling), against closed forms; the matching
encoder's DFT correlation against the closed form of the matrix products it does."""

from __future__ import annotations

import torch
import torch.nn.functional as nnf

from benchmark.models.flop_count import KINDS, count_flops_by_kind
from benchmark.models.matching_ops import correlate_dft, fft_size


def _kinds(**nonzero: int) -> dict[str, int]:
    out = dict.fromkeys(KINDS, 0)
    out.update(nonzero)
    out["total"] = sum(nonzero.values())
    return out


def test_real_and_complex_matrix_products():
    a, b = torch.randn(5, 7), torch.randn(7, 3)
    assert count_flops_by_kind(lambda: a @ b) == _kinds(matmul=2 * 5 * 7 * 3)
    ac, bc = a.to(torch.complex64), b.to(torch.complex64)
    # A complex multiply-add is 4 real multiplies and 4 real adds.
    assert count_flops_by_kind(lambda: ac @ bc) == _kinds(dft=8 * 5 * 7 * 3)
    batched = torch.randn(2, 5, 7, dtype=torch.complex64)
    assert count_flops_by_kind(lambda: batched @ bc) == _kinds(dft=8 * 2 * 5 * 7 * 3)


def test_complex_elementwise():
    x, y = torch.randn(4, 6, dtype=torch.complex64), torch.randn(4, 6, dtype=torch.complex64)
    real = torch.randn(4, 6)
    assert count_flops_by_kind(lambda: x * y) == _kinds(spectrum=6 * 24)  # 4 mul + 2 add
    assert count_flops_by_kind(lambda: x * real) == _kinds(spectrum=2 * 24)
    assert count_flops_by_kind(lambda: x + y) == _kinds(spectrum=2 * 24)
    assert count_flops_by_kind(lambda: x.sum(0)) == _kinds(spectrum=2 * (24 - 6))
    assert count_flops_by_kind(lambda: real * real + real) == _kinds()  # real: not counted


def test_bilinear_sampling_forward_and_gradients():
    n, c, h, w, ho, wo = 2, 3, 8, 9, 4, 5
    cells = n * c * ho * wo
    inp = torch.randn(n, c, h, w, requires_grad=True)
    grid = (torch.rand(n, ho, wo, 2) * 2 - 1).requires_grad_(True)

    def step(grid: torch.Tensor) -> None:
        nnf.grid_sample(inp, grid, mode="bilinear", align_corners=True).sum().backward()

    # Forward 4 taps x (mul + add); input gradient 4 scattered multiply-adds; grid gradient
    # 4 taps x 2 coordinates x (2 multiplies + 1 add).
    assert count_flops_by_kind(lambda: step(grid)) == _kinds(sampling=(8 + 8 + 24) * cells)
    assert count_flops_by_kind(lambda: step(grid.detach())) == _kinds(sampling=(8 + 8) * cells)
    with torch.no_grad():
        got = count_flops_by_kind(lambda: nnf.grid_sample(inp, grid, align_corners=True))
    assert got == _kinds(sampling=8 * cells)


def test_dft_correlation_is_its_matrix_products():
    """``correlate_dft`` forward: the half spectra of templates and grid (two GEMMs each), the
    per-channel products summed over channels, and the inverse at the kept outputs (two GEMMs),
    from the shapes alone."""
    b, k, c, t, g = 2, 3, 4, 5, 11
    sat, templates = torch.randn(b, c, g, g), torch.randn(b, k, c, t, t)
    L = fft_size(g)
    v, m = L // 2 + 1, g - t + 1
    spectra = (b * k * c) * (t * t * v + v * t * L) + (b * c) * (g * g * v + v * g * L)
    inverse = (b * k) * (v * L * m + m * v * m)
    products = (b * k * v * L) * (6 * c + 2 * (c - 1))  # c complex products, c - 1 sums
    with torch.no_grad():
        correlate_dft(sat, templates)  # builds (and caches) the DFT matrices: not counted below
        got = count_flops_by_kind(lambda: correlate_dft(sat, templates))
    assert got == _kinds(dft=8 * (spectra + inverse), spectrum=products)
