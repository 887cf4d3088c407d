"""Which 16-bit precisions a device runs, and how fast: one place for the benchmarks (``uavbench
bench ...``) and for the training/evaluation check of ``precision: bf16`` (``models/device.py``).

**bf16 on a CPU has three levels** (:func:`cpu_bf16_level`); "native" means the first only:

- ``"native"``: the CPU has bf16 arithmetic instructions, ``avx512_bf16`` (AVX-512 BF16:
  ``vdpbf16ps`` dot products, Cooper Lake, Zen 4 and later) or ``amx_bf16`` (AMX tiles, Sapphire
  Rapids and later); on Arm, ``bf16`` (Armv8.6 BFDOT/BFMMLA). oneDNN's bf16 convolutions and matrix
  products run on them: fewer bytes moved and, with AMX, several times fp32's throughput.
- ``"converted"``: AVX-512 without bf16 instructions (``avx512bw`` + ``avx512vl`` + ``avx512dq``,
  Skylake-SP/Ice Lake). This is what ``torch.ops.mkldnn._is_mkldnn_bf16_supported()`` checks
  (ATen's ``mkldnn_bf16_device_check()``: cpuinfo's avx512bw, avx512vl and avx512dq, no bf16
  flag): oneDNN has bf16 kernels there, but they widen bf16 to fp32 in registers and multiply in
  fp32, so bf16 gains little or nothing over fp32 and only rounds more.
- ``"reference"``: no AVX-512 (e.g. AVX2-only CPUs like this project's dev machine). oneDNN has
  no bf16 kernels; autocast bf16 convolutions fall back to reference code (``bench train``
  measured 0.14x fp32's pairs/s on an AVX2 EPYC).

The level is the hardware's (:func:`cpu_bf16_level`, from the CPU flags) unless oneDNN is told
to use less: ``ONEDNN_MAX_CPU_ISA`` (or its old name ``DNNL_MAX_CPU_ISA``) below ``AVX512_CORE``
leaves it no bf16 kernels, below ``AVX512_CORE_BF16`` none that use the bf16 instructions.
:func:`onednn_bf16_level` is the level oneDNN actually runs here, and what every decision below
uses (a cap is how one emulates an older CPU, and how one pins oneDNN's numerics across
machines).

``torch.autocast`` accepts bf16 on any CPU, so nothing stops a slow run but this module:
``bf16_unsupported_reason(device)`` keeps its benchmark meaning (None from ``"converted"`` up:
oneDNN has kernels, PyTorch's own test), ``bf16_unsupported_reason(device, native=True)`` is
None only for ``"native"`` (the training/evaluation check). On CUDA bf16 needs compute
capability 8.0 or newer (``torch.cuda.is_bf16_supported()``); MPS supports it from macOS 14.
A benchmark measures bf16 by default only where it is supported and says why it is skipped
otherwise; an explicit ``--precision bf16`` measures it anyway.
"""

from __future__ import annotations

import os

import torch

from benchmark.errors import InputError
from benchmark.machine import cpu_model, read_cpuinfo

BENCH_PRECISIONS = ("fp32", "bf16")
NATIVE_BF16_FLAGS = ("avx512_bf16", "amx_bf16", "bf16")  # x86 (Linux names), Arm (Features)
ONEDNN_BF16_FLAGS = ("avx512bw", "avx512vl", "avx512dq")  # mkldnn_bf16_device_check()
ONEDNN_ISA_ENV = ("ONEDNN_MAX_CPU_ISA", "DNNL_MAX_CPU_ISA")  # oneDNN reads the first set
# oneDNN's x86 ISA names that cap its bf16 support (the higher ones, ALL and DEFAULT, do not):
# no AVX-512, no bf16 kernels; AVX-512 without its BF16 extension, converted kernels only.
_ONEDNN_CAPS = {
    **dict.fromkeys(("SSE41", "AVX", "AVX2", "AVX2_VNNI", "AVX2_VNNI_2"), "reference"),
    **dict.fromkeys(("AVX512_CORE", "AVX512_CORE_VNNI"), "converted"),
}
_LEVELS = ("reference", "converted", "native")
# Set to 1 to run precision=bf16 on a CPU without native bf16 anyway (emulated, slow).
ALLOW_SLOW_BF16_ENV = "UAVBENCH_ALLOW_SLOW_BF16"

# torch.cpu.get_capabilities() (cpuinfo) names -> /proc/cpuinfo names, for machines without
# /proc/cpuinfo (macOS, Windows): the same instruction sets under the kernel's spelling.
_CAPABILITY_FLAGS = {
    "avx": "avx",
    "avx2": "avx2",
    "avx512_f": "avx512f",
    "avx512_bw": "avx512bw",
    "avx512_vl": "avx512vl",
    "avx512_dq": "avx512dq",
    "avx512_bf16": "avx512_bf16",
    "amx_bf16": "amx_bf16",
    "amx_tile": "amx_tile",
}


def cpu_flags() -> set[str]:
    """The CPU feature flags of ``/proc/cpuinfo`` (Linux spelling: ``avx2``, ``avx512f``,
    ``avx512_bf16``, ``amx_bf16``, ...); where there is no ``/proc/cpuinfo`` (macOS, Windows),
    the x86 ones torch's cpuinfo reports (``torch.cpu.get_capabilities()``), translated to the
    same names; empty if neither answers."""
    for line in (read_cpuinfo() or "").splitlines():
        if line.startswith(("flags", "Features")):
            return set(line.split(":", 1)[1].split())
    try:
        capabilities = torch.cpu.get_capabilities()
    except (AttributeError, RuntimeError):  # an older torch, or cpuinfo failed to initialise
        return set()
    return {name for key, name in _CAPABILITY_FLAGS.items() if capabilities.get(key) is True}


def cpu_bf16_level(flags: set[str] | None = None) -> str:
    """``"native"``, ``"converted"`` or ``"reference"`` (module docstring) for the CPU with
    ``flags`` (default :func:`cpu_flags`). Without flags the answer is PyTorch's oneDNN test:
    ``"converted"`` if it passes, else ``"reference"`` (never ``"native"`` unproven)."""
    flags = cpu_flags() if flags is None else flags
    if any(f in flags for f in NATIVE_BF16_FLAGS):
        return "native"
    if flags:
        return "converted" if all(f in flags for f in ONEDNN_BF16_FLAGS) else "reference"
    return "converted" if torch.ops.mkldnn._is_mkldnn_bf16_supported() else "reference"


def onednn_isa_cap() -> str | None:
    """The ISA oneDNN is capped at by ``$ONEDNN_MAX_CPU_ISA`` (or ``$DNNL_MAX_CPU_ISA``),
    upper case, e.g. ``"AVX2"``; None when neither is set."""
    for name in ONEDNN_ISA_ENV:
        value = os.environ.get(name, "").strip()
        if value:
            return value.upper()
    return None


def onednn_bf16_level(flags: set[str] | None = None) -> str:
    """The bf16 level oneDNN runs on this machine: :func:`cpu_bf16_level` of its ``flags``
    (default :func:`cpu_flags`), lowered to what :func:`onednn_isa_cap` leaves (``"reference"``
    under ``AVX2``, at most ``"converted"`` under ``AVX512_CORE``). What the checks and labels of
    this module use."""
    level = cpu_bf16_level(flags)
    ceiling = _ONEDNN_CAPS.get(onednn_isa_cap() or "", "native")
    return min(level, ceiling, key=_LEVELS.index)


def _cap_note(flags: set[str], level: str) -> str:
    """``" (oneDNN capped at X by $ONEDNN_MAX_CPU_ISA)"`` when the cap lowered the hardware's
    level (``cpu_bf16_level(flags)``) to ``level``, or ``""``."""
    if level == cpu_bf16_level(flags):
        return ""
    return f" (oneDNN capped at {onednn_isa_cap()} by ${ONEDNN_ISA_ENV[0]})"


def _vector_units(flags: set[str]) -> str:
    """The CPU's AVX/AMX/bf16 flags, for a message: ``"avx, avx2"`` or ``"none of them"``."""
    have = sorted(f for f in flags if f.startswith(("avx", "amx")) or f == "bf16")
    return ", ".join(have) or "none of them"


def bf16_unsupported_reason(device: torch.device, *, native: bool = False) -> str | None:
    """None when ``device`` runs bf16 well enough; else one sentence why not.

    ``native=False`` (the benchmarks): a CPU qualifies when oneDNN has bf16 kernels for it
    (PyTorch's ``torch.ops.mkldnn._is_mkldnn_bf16_supported()``: AVX-512, natively or converted).
    ``native=True`` (training and evaluation in ``precision: bf16``): only a CPU with bf16
    instructions (``avx512_bf16``, ``amx_bf16``; Arm ``bf16``) qualifies. CUDA and MPS answer the
    same either way.
    """
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
    flags = cpu_flags()
    level = onednn_bf16_level(flags)
    note = _cap_note(flags, level)
    if native:
        if level == "native":
            return None
        how = (
            "oneDNN widens bf16 to fp32 in AVX-512 registers there: no faster than fp32"
            if level == "converted"
            else "without AVX-512 oneDNN has no bf16 kernels: autocast bf16 runs slow reference "
            "code"
        )
        if note:
            return (
                f"oneDNN is capped at {onednn_isa_cap()} by ${ONEDNN_ISA_ENV[0]}, below the bf16 "
                f"instructions of this CPU ({cpu_model()}; {how})"
            )
        return (
            f"this CPU ({cpu_model()}) has no native bf16: needs avx512_bf16 or amx_bf16, it has "
            f"{_vector_units(flags)} ({how})"
        )
    if torch.ops.mkldnn._is_mkldnn_bf16_supported():
        return None
    return (
        "this CPU has no bf16 convolution kernels in oneDNN (needs AVX-512, natively AVX-512 BF16 "
        f"or AMX; it has {_vector_units(flags)}{note}): autocast bf16 would run slow "
        "reference code"
    )


def bf16_support_label(device: torch.device) -> str:
    """How ``device`` runs bf16, in a few words for a benchmark line: ``"native (amx_bf16)"``,
    ``"converted to fp32 in AVX-512 registers (not native)"``, ``"reference code (no AVX-512)"``;
    on CUDA/MPS ``"native"`` or ``"unsupported"``. Call "native" only what this calls native."""
    if device.type != "cpu":
        return "native" if bf16_unsupported_reason(device) is None else "unsupported"
    flags = cpu_flags()
    level = onednn_bf16_level(flags)
    note = _cap_note(flags, level)
    if level == "native":
        which = [f for f in NATIVE_BF16_FLAGS if f in flags]
        return f"native ({', '.join(which)})"
    if level == "converted":
        return f"converted to fp32 in AVX-512 registers (not native){note}"
    return f"reference code{note or ' (no AVX-512)'}"


def slow_bf16_allowed() -> bool:
    """True when ``$UAVBENCH_ALLOW_SLOW_BF16`` is set to 1 (or yes/true/on): the user accepts
    bf16 emulated on a CPU without native bf16."""
    return os.environ.get(ALLOW_SLOW_BF16_ENV, "").strip().lower() in ("1", "yes", "true", "on")


def precision_plan(device: torch.device, spec: str | None) -> tuple[list[str], list[str]]:
    """``(precisions to measure, notes to print)`` for a ``--precision`` value.

    ``spec`` None: fp32, plus bf16 where :func:`bf16_unsupported_reason` finds no reason (the
    reason becomes a note otherwise). A comma list (``"fp32,bf16"``) is measured as given, with a
    note for a bf16 the device does not support. Unknown names raise InputError (a ValueError).
    """
    reason = bf16_unsupported_reason(device)
    if spec is None:
        if reason is None:
            return ["fp32", "bf16"], []
        return ["fp32"], [f"bf16 skipped: {reason} (--precision fp32,bf16 measures it anyway)"]
    names = [s.strip() for s in spec.split(",") if s.strip()]
    bad = [n for n in names if n not in BENCH_PRECISIONS]
    if bad or not names or len(set(names)) != len(names):
        raise InputError(
            f"precision {spec!r}: expected a comma list of distinct {', '.join(BENCH_PRECISIONS)}"
        )
    notes = []
    if "bf16" in names and reason is not None:
        notes.append(f"bf16 measured although unsupported: {reason}")
    return names, notes
