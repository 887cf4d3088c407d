"""Which 16-bit precisions a device runs fast, for the benchmarks (``uavbench bench ...``).

``torch.autocast`` accepts bf16 on any CPU, but oneDNN has bf16 convolution kernels only for CPUs
with AVX-512 (native bf16 arithmetic with AVX-512 BF16 or AMX; converted in registers on plain
AVX-512): elsewhere, as on AVX2-only CPUs, bf16 convolutions fall back to slow reference code.
``torch.ops.mkldnn._is_mkldnn_bf16_supported()`` is PyTorch's own test of that. On CUDA bf16 needs
compute capability 8.0 or newer (``torch.cuda.is_bf16_supported()``); MPS supports it from macOS 14.
A benchmark measures bf16 by default only where it is supported and says why it is skipped
otherwise; an explicit ``--precision bf16`` measures it anyway.
"""

from __future__ import annotations

from pathlib import Path

import torch

BENCH_PRECISIONS = ("fp32", "bf16")


def cpu_flags() -> set[str]:
    """The CPU feature flags of ``/proc/cpuinfo`` (empty where there is none, e.g. macOS)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith(("flags", "Features")):
                return set(line.split(":", 1)[1].split())
    except OSError:
        pass
    return set()


def bf16_unsupported_reason(device: torch.device) -> str | None:
    """None when ``device`` runs bf16 convolutions natively or in oneDNN kernels; else why not."""
    if device.type == "cuda":
        if torch.cuda.is_bf16_supported():
            return None
        name = torch.cuda.get_device_name(device)
        return f"{name} has no bf16 support (needs compute capability >= 8.0)"
    if device.type == "mps":
        try:
            torch.ones(2, dtype=torch.bfloat16, device=device).sum().item()
        except (RuntimeError, TypeError) as error:
            return f"MPS has no bf16 here ({str(error).splitlines()[0]}; needs macOS 14)"
        return None
    if device.type != "cpu":
        return f"no bf16 check for device type {device.type!r}"
    if torch.ops.mkldnn._is_mkldnn_bf16_supported():
        return None
    flags = cpu_flags()
    have = sorted(f for f in flags if f.startswith(("avx", "amx")))
    return (
        "this CPU has no bf16 convolution kernels in oneDNN (needs AVX-512, natively AVX-512 BF16 "
        f"or AMX; it has {', '.join(have) or 'none of them'}): autocast bf16 would run slow "
        "reference code"
    )


def precision_plan(device: torch.device, spec: str | None) -> tuple[list[str], list[str]]:
    """``(precisions to measure, notes to print)`` for a ``--precision`` value.

    ``spec`` None: fp32, plus bf16 where :func:`bf16_unsupported_reason` finds no reason (the
    reason becomes a note otherwise). A comma list (``"fp32,bf16"``) is measured as given, with a
    note for a bf16 the device does not support. Unknown names raise ValueError.
    """
    reason = bf16_unsupported_reason(device)
    if spec is None:
        if reason is None:
            return ["fp32", "bf16"], []
        return ["fp32"], [f"bf16 skipped: {reason} (--precision fp32,bf16 measures it anyway)"]
    names = [s.strip() for s in spec.split(",") if s.strip()]
    bad = [n for n in names if n not in BENCH_PRECISIONS]
    if bad or not names or len(set(names)) != len(names):
        raise ValueError(
            f"--precision {spec!r}: expected a comma list of distinct {', '.join(BENCH_PRECISIONS)}"
        )
    notes = []
    if "bf16" in names and reason is not None:
        notes.append(f"bf16 measured although unsupported: {reason}")
    return names, notes
