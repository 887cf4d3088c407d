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

:func:`cpu_kernel_report` says which kernels a training convolution really runs on the CPU, per
precision: ATen's vector ISA (``torch.backends.cpu.get_cpu_capability()``), oneDNN's ISA and the
oneDNN implementations (read from oneDNN's verbose output of one small convolution), or the ATen
reference convolution where oneDNN has no kernel (bf16 without AVX-512); :func:`cpu_bf16_line`
puts it in one line beside whether bf16 is native (``avx512_bf16`` / ``amx_bf16``).
"""

from __future__ import annotations

import contextlib
import functools
import os
import platform
import statistics
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
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


# ATen's wrappers around the convolution that really runs (not named in the report).
_CONV_WRAPPERS = {"aten::conv2d", "aten::convolution", "aten::_convolution", "aten::thnn_conv2d"}
_CONV_WRAPPERS |= {"aten::convolution_backward", "aten::convolution_overrideable"}


@dataclass(frozen=True)
class KernelReport:
    """What ran one training convolution (forward, grad input, grad weight; channels_last) on the
    CPU. ``aten_isa``: ATen's vectorised kernels (``"AVX2"``, ``"AVX512"``, ...); ``onednn_isa``:
    the ISA oneDNN dispatched to, from its verbose ``isa:`` line (None if it did not print one:
    oneDNN prints it once per process); ``conv``: precision -> ``"oneDNN <fwd> / <bwd data> /
    <bwd weights>"`` implementations, or ``"ATen <op>"`` when oneDNN did not run it."""

    aten_isa: str
    onednn_isa: str | None
    conv: dict[str, str]


@contextlib.contextmanager
def _captured_output() -> Iterator[list[str]]:
    """Redirect file descriptors 1 and 2 (where oneDNN's C code and the profiler print) into a
    temporary file; the list holds the captured lines after the block."""
    lines: list[str] = []
    with tempfile.TemporaryFile() as f:
        for stream in (sys.stdout, sys.stderr):
            stream.flush()
        saved = [os.dup(1), os.dup(2)]
        os.dup2(f.fileno(), 1)
        os.dup2(f.fileno(), 2)
        try:
            yield lines
        finally:
            with contextlib.suppress(OSError, AttributeError, TypeError):
                import ctypes

                ctypes.CDLL(None).fflush(None)  # C stdio buffers (no-op where libc has none)
            for fd, copy in zip((1, 2), saved, strict=True):
                os.dup2(copy, fd)
                os.close(copy)
            f.seek(0)
            lines += f.read().decode(errors="replace").splitlines()


def _trace_conv(precision: str) -> tuple[list[str], set[str]]:
    """oneDNN's verbose lines and the ATen op names of one training convolution on the CPU
    (4 x 32 -> 32 channels, 16 px, 3x3, channels_last: large enough for ATen to pick oneDNN)."""
    from torch.profiler import ProfilerActivity, profile

    from benchmark.models.device import autocast

    cpu = torch.device("cpu")
    g = torch.Generator().manual_seed(0)
    conv = nn.Conv2d(32, 32, 3, padding=1, bias=False).to(memory_format=torch.channels_last)
    x = torch.randn(4, 32, 16, 16, generator=g).contiguous(memory_format=torch.channels_last)
    x.requires_grad_(True)
    with _captured_output() as lines:
        with profile(activities=[ProfilerActivity.CPU]) as prof:
            with torch.backends.mkldnn.verbose(torch.backends.mkldnn.VERBOSE_ON):
                with autocast(cpu, precision):
                    y = conv(x)
                y.float().sum().backward()
    names = {e.key for e in prof.key_averages() if "conv" in e.key and e.key.startswith("aten::")}
    return lines, names - _CONV_WRAPPERS


def _conv_implementations(lines: list[str]) -> list[str]:
    """The implementation of each executed oneDNN convolution (``brg_conv_fwd:avx2``, ...), in
    order, from verbose lines ``onednn_verbose,v1,primitive,exec,cpu,convolution,<impl>,...``."""
    found = []
    for line in lines:
        fields = line.split(",")
        if "exec" in fields and "convolution" in fields[fields.index("exec") :]:
            at = fields.index("convolution", fields.index("exec"))
            if at + 1 < len(fields) and fields[at + 1] not in found:
                found.append(fields[at + 1])
    return found


_ONEDNN_ISA: dict[str, str] = {}  # oneDNN prints its ISA once per process: remembered here


@functools.cache
def _conv_kernels(precision: str) -> str:
    """``"oneDNN <impl> / ..."`` or ``"ATen <op> / ... (no oneDNN kernel)"`` for one training
    convolution in ``precision`` on the CPU (cached: the answer is a property of the machine)."""
    lines, aten = _trace_conv(precision)
    for line in lines:
        if ",info,cpu,isa:" in line:
            _ONEDNN_ISA.setdefault("isa", line.split(",info,cpu,isa:", 1)[1].strip())
    impls = _conv_implementations(lines)
    if impls:
        return "oneDNN " + " / ".join(impls)
    ops = sorted((n.removeprefix("aten::") for n in aten), key=lambda n: ("forward" not in n, n))
    return f"ATen {' / '.join(ops) or '(unknown op)'} (no oneDNN kernel)"


def cpu_kernel_report(precisions: tuple[str, ...] = ("fp32", "bf16")) -> KernelReport:
    """Which ISA and kernels ran a training convolution on this CPU in each of ``precisions``."""
    conv = {precision: _conv_kernels(precision) for precision in precisions}
    isa = _ONEDNN_ISA.get("isa")
    return KernelReport(torch.backends.cpu.get_cpu_capability(), isa, conv)


def native_bf16_flags() -> tuple[str, ...]:
    """The CPU flags that make bf16 native on this architecture: ``avx512_bf16``, ``amx_bf16``
    on x86; ``bf16`` (Armv8.6) on Arm."""
    from benchmark.models.precision_support import NATIVE_BF16_FLAGS

    arm = platform.machine().lower() in ("aarch64", "arm64")
    return tuple(f for f in NATIVE_BF16_FLAGS if (f == "bf16") == arm)


def cpu_bf16_line(precisions: tuple[str, ...] = ("fp32", "bf16")) -> str:
    """One line: is bf16 native on this CPU (each native-bf16 flag present or missing; how
    oneDNN runs bf16 otherwise), ATen's and oneDNN's ISA, and the kernels a training
    convolution ran in each of ``precisions`` (:func:`cpu_kernel_report`)."""
    from benchmark.models.precision_support import bf16_support_label, cpu_flags, onednn_bf16_level

    flags = cpu_flags()
    native = onednn_bf16_level(flags) == "native"
    named = ", ".join(f"{f} {'present' if f in flags else 'missing'}" for f in native_bf16_flags())
    how = "" if native else f": {bf16_support_label(torch.device('cpu'))}"
    report = cpu_kernel_report(tuple(precisions))
    kernels = "; ".join(f"{p} conv ran {k}" for p, k in report.conv.items())
    return (
        f"bf16 on this CPU: {'native' if native else 'not native'} ({named or 'no CPU flags'}"
        f"{how}); ATen ISA {report.aten_isa}, oneDNN ISA {report.onednn_isa or 'not reported'};"
        f" {kernels}"
    )


@dataclass(frozen=True)
class CeilingBenchResult:
    """What :func:`bench_ceiling` measured on ``device`` with ``threads`` torch threads: one
    :class:`CeilingResult` per precision; ``cpu_line`` (:func:`cpu_bf16_line`, on the CPU only,
    else None) and the precision plan's ``notes`` (a precision skipped, and why)."""

    device: torch.device
    threads: int
    ceilings: tuple[CeilingResult, ...]
    cpu_line: str | None
    notes: tuple[str, ...]

    def lines(self) -> list[str]:
        """The CPU's bf16 line (on the CPU), the notes, one line per precision."""
        lines = [self.cpu_line] if self.cpu_line is not None else []
        lines += self.notes
        for r in self.ceilings:
            shapes = ", ".join(f"{k} {v:.1f}" for k, v in r.per_shape.items())
            lines.append(
                f"conv ceiling {r.precision}: {r.gflops:.1f} GFLOP/s ({r.best_shape}; {shapes}) "
                f"on {self.device}, {self.threads} thread(s)"
            )
        return lines


def bench_ceiling(
    device_name: str = "auto",
    precision: str | None = None,
    repeats: int = 3,
    batch: int | None = None,
    threads: int | None = None,
) -> CeilingBenchResult:
    """Measure the ceiling on the device named ``device_name`` (``"auto"`` allowed) in each
    precision of the comma list ``precision`` (None: fp32 and, where the device supports it,
    bf16), ``repeats`` timed runs per shape of ``batch`` images (None: 24) on ``threads`` torch
    threads (None: torch's); returns the ceilings. InputError: a device or precision this machine
    lacks, or an unknown name."""
    from benchmark.errors import InputError
    from benchmark.models.device import resolve_device
    from benchmark.models.precision_support import precision_plan

    if threads is not None:
        torch.set_num_threads(threads)
    try:
        device = resolve_device(device_name)
        precisions, notes = precision_plan(device, precision)
    except ValueError as error:  # a typed error: the command exits 2, without a traceback
        raise InputError(str(error)) from None
    cpu_line = cpu_bf16_line(("fp32", "bf16")) if device.type == "cpu" else None
    ceilings = tuple(measure_ceiling(device, name, repeats, batch) for name in precisions)
    return CeilingBenchResult(device, torch.get_num_threads(), ceilings, cpu_line, tuple(notes))
