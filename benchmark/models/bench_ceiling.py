"""The convolution throughput ceiling of a device: ``uavbench bench ceiling`` (and ``bench train``).

The ceiling is the best rate (GFLOP/s) at which the device runs a training convolution: forward,
input gradient and weight gradient of a 3x3 convolution in channels_last (the encoder's format), at
shapes taken from GoogLeNet's heavy layers at 224 px and width 1.0 with a batch of 24 images (20
UAV frames + 4 distinct satellite images, what ``bench train`` encodes per step):

========= ==================== ======= ======================================
name      channels in -> out   px      where
========= ==================== ======= ======================================
stem3x3   64 -> 192            56x56   the stem's 3x3 (the step's largest conv)
3b-3x3    128 -> 192           28x28   inception 3b, 3x3 branch
4e-3x3    160 -> 320           14x14   inception 4e/5a, 3x3 branch
========= ==================== ======= ======================================

FLOPs = 2 x multiply-adds: ``2 N H W C_out C_in 9`` per pass, three passes (forward, grad input,
grad weight) per step; bias-free like the encoder's convolutions. Each shape is timed ``repeats``
times after a warm-up; the rate of a shape is its median, the ceiling is the best shape. A
training step can approach it only where it is made of such convolutions: normalisation,
activations, pooling, concatenation and the optimiser cost time and no counted FLOPs.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import nn

# name: (batch, c_in, c_out, side px) at 224 px, width 1.0, 20 pairs over 4 satellite images
SHAPES: dict[str, tuple[int, int, int, int]] = {
    "stem3x3": (24, 64, 192, 56),
    "3b-3x3": (24, 128, 192, 28),
    "4e-3x3": (24, 160, 320, 14),
}


@dataclass(frozen=True)
class CeilingResult:
    """``gflops``: the best shape's rate; ``per_shape``: every shape's median rate (GFLOP/s)."""

    precision: str
    gflops: float
    best_shape: str
    per_shape: dict[str, float]

    @classmethod
    def of(cls, precision: str, rates: dict[str, float]) -> CeilingResult:
        best = max(rates, key=rates.__getitem__)
        return cls(precision, rates[best], best, dict(rates))


def synchronize(device: torch.device) -> None:
    """Wait for the device's queued kernels (CUDA and MPS run asynchronously) before a clock."""
    if device.type == "cuda":
        torch.cuda.synchronize(device)
    elif device.type == "mps":
        torch.mps.synchronize()


def conv_step_flops(batch: int, c_in: int, c_out: int, side: int, kernel: int = 3) -> int:
    """FLOPs (2 x multiply-adds) of forward + grad input + grad weight of one stride-1 'same'
    convolution: three passes of ``2 N H W C_out C_in k^2`` each."""
    return 3 * 2 * batch * side * side * c_out * c_in * kernel * kernel


def conv_job(
    shape: tuple[int, int, int, int],
    device: torch.device,
    precision: str = "fp32",
    batch: int | None = None,
) -> tuple[Callable[[], float], int]:
    """``(run, flops)``: ``run()`` times (seconds) one training convolution of ``shape`` (a
    :data:`SHAPES` entry; ``batch`` replaces its batch) on ``device`` in ``precision`` (fp32, or
    bf16/fp16 under autocast with float32 weights, as in training); ``flops`` is its count."""
    from benchmark.models.device import autocast

    n, c_in, c_out, side = shape
    n = n if batch is None else batch
    g = torch.Generator().manual_seed(0)
    conv = nn.Conv2d(c_in, c_out, 3, padding=1, bias=False).to(device)
    conv = conv.to(memory_format=torch.channels_last)
    x = torch.randn(n, c_in, side, side, generator=g).to(device)
    x = x.contiguous(memory_format=torch.channels_last).requires_grad_(True)
    grad = torch.randn(n, c_out, side, side, generator=g).to(device)
    grad = grad.contiguous(memory_format=torch.channels_last)

    def run() -> float:
        x.grad = None
        conv.weight.grad = None
        synchronize(device)
        start = time.perf_counter()
        with autocast(device, precision):
            y = conv(x)
        y.backward(grad.to(y.dtype))
        synchronize(device)
        return time.perf_counter() - start

    return run, conv_step_flops(n, c_in, c_out, side)


def measure_ceiling(
    device: torch.device, precision: str = "fp32", repeats: int = 3, batch: int | None = None
) -> CeilingResult:
    """The convolution ceiling of ``device`` in ``precision``: the best of :data:`SHAPES`, each
    the median of ``repeats`` timed runs after one warm-up (oneDNN / cuDNN picks its kernels)."""
    rates = {}
    for name, shape in SHAPES.items():
        run, flops = conv_job(shape, device, precision, batch)
        run()
        rates[name] = flops / statistics.median(run() for _ in range(repeats)) / 1e9
    return CeilingResult.of(precision, rates)


def main(argv: list[str]) -> int:
    """``uavbench bench ceiling [--device D] [--precision fp32,bf16] [--repeats N]``."""
    import argparse

    from benchmark.models.device import resolve_device
    from benchmark.models.precision_support import precision_plan

    p = argparse.ArgumentParser(prog="uavbench bench ceiling", description=__doc__.split("\n")[0])
    p.add_argument("--device", default="auto", help="auto, cpu, cuda, cuda:N or mps")
    p.add_argument("--precision", default=None, help="comma list of fp32,bf16 (default: both "
                   "where the device supports bf16)")  # fmt: skip
    p.add_argument("--repeats", type=int, default=3, help="timed runs per shape (median)")
    p.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    p.add_argument("--batch", type=int, default=None, help="images per convolution (default 24)")
    args = p.parse_args(argv)
    if args.repeats < 1 or (args.batch is not None and args.batch < 1):
        p.error("--repeats and --batch must be >= 1")
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    device = resolve_device(args.device)
    precisions, notes = precision_plan(device, args.precision)
    for note in notes:
        print(note)
    for precision in precisions:
        r = measure_ceiling(device, precision, args.repeats, args.batch)
        shapes = ", ".join(f"{k} {v:.1f}" for k, v in r.per_shape.items())
        print(
            f"conv ceiling {precision}: {r.gflops:.1f} GFLOP/s ({r.best_shape}; {shapes}) on "
            f"{device}, {torch.get_num_threads()} thread(s)"
        )
    return 0
