"""FLOPs of a forward or training step, by kind of work: what ``bench train`` and ``model-info``
count (FLOPs = 2 x multiply-adds, or real arithmetic operations for the complex ones below).

``torch.utils.flop_counter.FlopCounterMode`` counts convolutions (forward and both gradients)
and matrix products by their shapes only. Two gaps matter for the matching encoder
(``benchmark.models.matching``), and are closed here with its ``custom_mapping``:

- **complex matrix products** (the DFT correlation, ``matching_ops.correlate_dft``, is a few
  large complex64 GEMMs): torch counts ``2 m n k`` whatever the dtype, but a complex
  multiply-add is 4 real multiplies and 4 real adds, so they count ``8 m n k`` here;
- **the spectra's per-channel products** (``prod + x * y`` summed over channels in the frequency
  domain: the correlation's own multiply-adds) and their gradients: complex ``mul`` is 6 real
  FLOPs per element (2 if one factor is real), complex ``add``/``sub`` 2, a complex ``sum`` 2 per
  element folded away. Real elementwise ops stay uncounted, as for every encoder;
- **bilinear sampling** (``grid_sample``: the bird's-eye templates and the satellite grid) is not
  counted by torch at all. Per output cell and channel, as ATen's CPU kernel computes it: forward
  4 taps x (multiply + add) = 8; gradient of the input 4 scattered multiply-adds = 8; gradient of
  the sampling grid 4 taps x 2 coordinates x (2 multiplies + 1 add) = 24 (each only when asked
  for: ``output_mask``). Nearest sampling is 0, bicubic 16 taps (32 / 32 / 96).

Still not counted (for every encoder alike): normalisation, activations, pooling, softmax and
losses, the optimiser, copies and indexing; FFTs (``correlation="fft"``; the default ``"dft"`` is
counted as above).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch
from torch.utils.flop_counter import FlopCounterMode, flop_registry

__all__ = ["KINDS", "count_flops_by_kind"]

aten = torch.ops.aten
# convolution: forward and both gradients; matmul: real matrix products (dense layers, the small
# 3 x 3 camera rotations); dft: complex matrix products (the transforms); spectrum: complex
# elementwise products and sums (the per-channel products of the spectra); sampling: grid_sample
# forward and backward.
KINDS = ("convolution", "matmul", "dft", "spectrum", "sampling")
_CONV = (
    *(aten.convolution, aten._convolution, aten.convolution_backward, aten.cudnn_convolution),
    *(aten._slow_conv2d_forward, aten.convolution_overrideable),
)
_MATMUL = (aten.mm, aten.addmm, aten.bmm, aten.baddbmm)
_ELEMENTWISE = (aten.mul, aten.add, aten.sub, aten.sum)
_TAPS = {0: 4, 1: 0, 2: 16}  # grid_sample interpolation_mode: bilinear, nearest, bicubic


def _tensors(args: tuple[Any, ...]) -> list[torch.Tensor]:
    return [a for a in args if isinstance(a, torch.Tensor)]


def _is_complex(args: tuple[Any, ...]) -> bool:
    return any(t.is_complex() for t in _tensors(args))


class _Tally:
    """FLOPs per :data:`KINDS`, filled by the formulas while the counter runs."""

    def __init__(self) -> None:
        self.flops = dict.fromkeys(KINDS, 0)

    def mapping(self) -> dict[Any, Callable[..., int]]:
        """``custom_mapping`` of ``FlopCounterMode``: raw-argument formulas (``_get_raw``)."""
        out: dict[Any, Callable[..., int]] = {}
        for op in _CONV:
            out[op] = self._wrap("convolution", flop_registry[op])
        for op in _MATMUL:
            out[op] = self._matmul(flop_registry[op])
        for op in _ELEMENTWISE:
            out[op] = self._wrap("spectrum", _complex_elementwise(op))
        out[aten.grid_sampler_2d] = self._wrap("sampling", _grid_sample_forward)
        out[aten.grid_sampler_2d_backward] = self._wrap("sampling", _grid_sample_backward)
        return out

    def _wrap(self, kind: str, formula: Callable[..., int]) -> Callable[..., int]:
        def count(*args: Any, out_val: Any = None, **kwargs: Any) -> int:
            n = int(formula(*args, out_val=out_val, **kwargs))
            self.flops[kind] += n
            return n

        count._get_raw = True  # type: ignore[attr-defined]
        return count

    def _matmul(self, formula: Callable[..., int]) -> Callable[..., int]:
        def count(*args: Any, out_val: Any = None, **kwargs: Any) -> int:
            n = int(formula(*args, out_val=out_val, **kwargs))  # 2 m n k
            if _is_complex(args):
                n *= 4  # a complex multiply-add: 4 real multiplies + 4 real adds
                self.flops["dft"] += n
            else:
                self.flops["matmul"] += n
            return n

        count._get_raw = True  # type: ignore[attr-defined]
        return count


def _complex_elementwise(op: Any) -> Callable[..., int]:
    """Real FLOPs of a complex ``mul``/``add``/``sub``/``sum``; 0 for real operands."""

    def formula(*args: Any, out_val: Any = None, **kwargs: Any) -> int:
        if not _is_complex(args) or not isinstance(out_val, torch.Tensor):
            return 0
        if op is aten.sum:
            return 2 * (args[0].numel() - out_val.numel())
        if op is aten.mul:
            both = sum(t.is_complex() for t in _tensors(args)) >= 2
            return (6 if both else 2) * out_val.numel()
        return 2 * out_val.numel()

    return formula


def _grid_sample_forward(inp: torch.Tensor, grid: torch.Tensor, mode: int, *args: Any,
                         out_val: Any = None, **kwargs: Any) -> int:  # fmt: skip
    n, c = inp.shape[:2]
    return 2 * _TAPS.get(int(mode), 4) * n * c * grid.shape[1] * grid.shape[2]


def _grid_sample_backward(grad: torch.Tensor, inp: torch.Tensor, grid: torch.Tensor, mode: int,
                          padding: int, align: bool, mask: Any, *args: Any, out_val: Any = None,
                          **kwargs: Any) -> int:  # fmt: skip
    taps = _TAPS.get(int(mode), 4)
    cells = grad.numel()  # N C H_out W_out
    want_input, want_grid = (bool(m) for m in mask)
    return want_input * 2 * taps * cells + want_grid * 6 * taps * cells


def count_flops_by_kind(fn: Callable[[], object]) -> dict[str, int]:
    """Run ``fn()`` once under the counter: FLOPs per :data:`KINDS` and ``total`` (their sum;
    also ``FlopCounterMode``'s total with these formulas). Count before timing: ``fn`` runs."""
    tally = _Tally()
    with FlopCounterMode(display=False, custom_mapping=tally.mapping()) as counter:
        fn()
    total = int(counter.get_total_flops())
    out = dict(tally.flops)
    out["total"] = sum(out.values())
    if out["total"] != total:  # an op of torch's registry without a formula here: attention's
        out["matmul"] += total - out["total"]  # (scaled dot products), matrix products too
        out["total"] = total
    return out
