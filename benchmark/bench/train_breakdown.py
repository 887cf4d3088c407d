"""Where one training step's time goes, by kind of work (``uavbench bench train --profile N``).

``torch.profiler`` records one step; every recorded event's *self* CPU time (its own time, not its
children's) goes to one kind:

- ``convolution``: oneDNN/ATen convolutions, forward and backward (``mkldnn_convolution``,
  ``convolution_backward``, the reference ``_slow_conv2d_*``, cuDNN's);
- ``matmul``: ``mm``/``addmm``/``bmm``/``baddbmm`` (the dense layers: the heads' lattice decoders,
  the fusion's linear layers; the matching encoder's complex DFT products, which the profiler
  names alike);
- ``sampling``: ``grid_sampler_2d`` forward and backward (the matching encoder's bird's-eye
  templates and satellite grid);
- ``normalisation``: GroupNorm/BatchNorm forward and backward;
- ``pooling``: max/average pooling forward and backward;
- ``optimizer``: everything inside ``Optimizer.step``/``zero_grad`` and the gradient clipping
  (``bench train`` marks it with :data:`CLIP_LABEL`);
- ``other``: the rest (activations, elementwise arithmetic, copies, concatenation, indexing, the
  losses' small ops, the autograd engine's own bookkeeping).

With the step's convolution, matmul (real and complex: ``matmul`` + ``dft``) and sampling FLOPs
(``train.step_flops``) this gives each one's achieved rate; the line puts the convolutions' rate
beside the ceiling (``benchmark.bench.ceiling``). The matching encoder's complex elementwise
products (``spectrum``) fall in ``other``. The profiler adds a few microseconds per op, so the
shares are those of a slightly slowed step: they locate the time, the timed rounds give the speed.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

import torch

KINDS = ("convolution", "matmul", "sampling", "normalisation", "pooling", "optimizer", "other")
# The FLOP kinds (benchmark.models.flop_count.KINDS) whose work each timed kind does.
RATE_FLOPS = {
    "convolution": ("convolution",),
    "matmul": ("matmul", "dft"),
    "sampling": ("sampling",),
}
CLIP_LABEL = "uavbench.clip_grad_norm"
_CONV = ("convolution", "conv2d", "conv_depthwise")
_MATMUL = {"aten::mm", "aten::addmm", "aten::bmm", "aten::baddbmm", "aten::_addmm_activation"}
_NORM = ("group_norm", "batch_norm", "layer_norm", "native_norm")


def kind_of(name: str) -> str:
    """The kind of an ATen op's own work, by its profiler name (``aten::mm`` -> ``matmul``);
    ``other`` for anything not listed, including record-function labels."""
    if not name.startswith("aten::"):
        return "other"
    if any(k in name for k in _CONV):
        return "convolution"
    if name in _MATMUL:
        return "matmul"
    if "grid_sampler" in name:
        return "sampling"
    if any(k in name for k in _NORM):
        return "normalisation"
    if "pool" in name:
        return "pooling"
    return "other"


def _in_optimizer(event: Any) -> bool:
    """True when ``event`` or one of its ancestors is an optimiser step, zero_grad or the
    gradient clipping."""
    while event is not None:
        if event.name.startswith("Optimizer.") or event.name == CLIP_LABEL:
            return True
        event = event.cpu_parent
    return False


def time_by_kind(events: Iterable[Any]) -> dict[str, float]:
    """Self CPU seconds per kind (:data:`KINDS`) of the profiler's ``events``
    (``torch.profiler.profile().events()``), plus ``"ops"``: the number of ATen op calls."""
    out = dict.fromkeys(KINDS, 0.0)
    ops = 0
    for e in events:
        kind = "optimizer" if _in_optimizer(e) else kind_of(e.name)
        out[kind] += e.self_cpu_time_total / 1e6  # microseconds
        ops += e.name.startswith("aten::")
    out["ops"] = float(ops)
    return out


def profile_step(step: Callable[[], float], rows: int) -> tuple[str, dict[str, float]]:
    """Profile one call of ``step``: ``(table, seconds by kind)``. The table lists the ``rows``
    ops of most self time (on CUDA the device's time too)."""
    from torch.profiler import ProfilerActivity, profile

    activities = [ProfilerActivity.CPU]
    if torch.cuda.is_available():
        activities.append(ProfilerActivity.CUDA)
    with profile(activities=activities) as prof:
        step()
    key = "self_cuda_time_total" if len(activities) > 1 else "self_cpu_time_total"
    return prof.key_averages().table(sort_by=key, row_limit=rows), time_by_kind(prof.events())


def breakdown_line(kinds: dict[str, float], flops: dict[str, int], ceiling: float | None) -> str:
    """``kinds`` (:func:`time_by_kind`) as one line of percentages; convolution, matmul and
    sampling with their achieved GFLOP/s (``flops``: ``bench.step_flops``; :data:`RATE_FLOPS`),
    the convolutions' also as a share of ``ceiling`` (GFLOP/s of the same precision; None: not
    measured)."""
    total = sum(kinds.get(k, 0.0) for k in KINDS) or float("nan")
    parts = []
    for kind in KINDS:
        seconds = kinds.get(kind, 0.0)
        text = f"{kind} {100 * seconds / total:.0f}%"
        counted = sum(flops.get(k, 0) for k in RATE_FLOPS.get(kind, ()))
        if seconds > 0 and counted:
            rate = counted / seconds / 1e9
            conv = kind == "convolution" and ceiling
            extra = f", {100 * rate / ceiling:.0f}% of the conv ceiling" if conv else ""
            text += f" ({rate:.1f} GFLOP/s{extra})"
        parts.append(text)
    return (
        f"time by kind (self CPU time of one profiled step, {1e3 * total:.0f} ms, "
        f"{kinds['ops']:.0f} ATen op calls): " + ", ".join(parts)
    )
