"""Devices and numeric precision for training, evaluation and ``model-info`` latency (issue 11).

``device``: ``"auto"`` (CUDA if available, else Apple MPS, else the CPU), or an explicit
``"cpu"``, ``"cuda"``, ``"cuda:N"``, ``"mps"``. ``precision``: ``"fp32"``; ``"bf16"`` or
``"fp16"`` (mixed precision: ``torch.autocast`` runs the convolutions and matrix products in 16
bits, the weights, optimiser state and losses stay float32; fp16 also needs a gradient scaler, see
:func:`grad_scaler`); ``"auto"``: bf16 on a CUDA device that supports it, fp32 otherwise. On a CPU
``auto`` is always fp32, even one with native bf16: the default numbers must not depend on the
CPU's instruction sets, and bf16 there is an explicit choice.

bf16 on a CPU runs only where the CPU has native bf16 (``avx512_bf16`` or ``amx_bf16``; the
levels are defined once in :mod:`benchmark.models.precision_support`): elsewhere
:func:`check_precision_supported` refuses it in one line naming what is missing, unless
``UAVBENCH_ALLOW_SLOW_BF16=1`` accepts the emulation. An environment variable, not a precision
name such as ``bf16-emulated``: the arithmetic and the trained model are the same bf16 autocast
(same run key, tag ``precision=bf16``, a checkpoint resumes on a native machine); only whether
this machine may run it slowly differs, which is a property of the machine, not of the run.

Nothing here changes what runs on the CPU in fp32: :func:`autocast` is then a no-op context and
tensors already on the CPU are not copied.
"""

from __future__ import annotations

import contextlib
import re
from contextlib import AbstractContextManager
from dataclasses import dataclass

import torch

from benchmark.config import ConfigError
from benchmark.machine import cpu_model

DEVICE_CHOICES = "'auto', 'cpu', 'cuda', 'cuda:N' or 'mps'"
PRECISIONS = ("auto", "fp32", "bf16", "fp16")
DTYPES = {"bf16": torch.bfloat16, "fp16": torch.float16}
_DEVICE_RE = re.compile(r"^(auto|cpu|mps|cuda(:\d+)?)$")


def check_device_name(name: str) -> None:
    """ValueError unless ``name`` is one of :data:`DEVICE_CHOICES` (syntax only)."""
    if not isinstance(name, str) or not _DEVICE_RE.match(name):
        raise ValueError(f"device must be {DEVICE_CHOICES}, got {name!r}")


def check_precision_name(name: str) -> None:
    if name not in PRECISIONS:
        raise ValueError(f"precision must be one of {', '.join(PRECISIONS)}, got {name!r}")


def resolve_device(name: str = "auto") -> torch.device:
    """The ``torch.device`` of ``name``; a device this machine lacks is a ValueError naming what
    it has (a CPU-only torch build has no CUDA even on a machine with a GPU)."""
    check_device_name(name)
    if name == "auto":
        if torch.cuda.is_available():
            return torch.device("cuda", torch.cuda.current_device())
        if torch.backends.mps.is_available():
            return torch.device("mps")
        return torch.device("cpu")
    device = torch.device(name)
    if device.type == "cuda":
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        if count == 0:
            raise ValueError(
                f"device={name!r}: no CUDA device here (torch {torch.__version__}, CUDA build: "
                f"{torch.version.cuda or 'no'}); use device=cpu or auto"
            )
        index = 0 if device.index is None else device.index
        if index >= count:
            raise ValueError(f"device={name!r}: only {count} CUDA device(s) (cuda:0..{count - 1})")
        return torch.device("cuda", index)
    if device.type == "mps" and not torch.backends.mps.is_available():
        raise ValueError(f"device={name!r}: MPS is not available here; use device=cpu or auto")
    return device


class PrecisionUnsupportedError(ConfigError):
    """A precision this machine cannot run (well): the message is one line naming what it lacks
    and how to proceed anyway. A ``ConfigError`` (so a ``ValueError``): the commands print it as
    a usage error (exit 2)."""


def resolve_precision(name: str, device: torch.device) -> str:
    """``"fp32"``, ``"bf16"`` or ``"fp16"`` for ``name`` on ``device`` (``"auto"``: bf16 on a
    CUDA device with bf16 support, fp32 otherwise, on every CPU). Pure name resolution: whether
    the machine runs it well is :func:`check_precision_supported`."""
    check_precision_name(name)
    if name != "auto":
        return name
    if device.type == "cuda" and torch.cuda.is_bf16_supported():
        return "bf16"
    return "fp32"


def check_precision_supported(precision: str, device: torch.device) -> None:
    """:class:`PrecisionUnsupportedError` when ``precision`` (resolved: fp32/bf16/fp16) is bf16
    on a CPU without native bf16 (``avx512_bf16``/``amx_bf16``, and oneDNN not capped below them:
    ``precision_support.onednn_bf16_level``) and ``UAVBENCH_ALLOW_SLOW_BF16``
    is not 1; also bf16 on a CUDA/MPS device without bf16 support. Nothing else is checked (fp32
    runs anywhere; fp16 on a CPU is left as it was)."""
    if precision != "bf16":
        return
    from benchmark.models import precision_support as support

    reason = support.bf16_unsupported_reason(device, native=True)
    if reason is None:
        return
    if device.type == "cpu":
        if support.slow_bf16_allowed():
            return
        raise PrecisionUnsupportedError(
            f"precision=bf16: {reason}; use precision=fp32 (or auto), or set "
            f"{support.ALLOW_SLOW_BF16_ENV}=1 to emulate bf16 slowly"
        )
    raise PrecisionUnsupportedError(f"precision=bf16: {reason}; use precision=fp32 or auto")


@dataclass(frozen=True)
class Placement:
    """Where and in what precision a model computes, resolved once (by the command) and passed
    down: ``device`` a ``torch.device`` this machine has, ``precision`` ``"fp32"``, ``"bf16"``
    or ``"fp16"`` (never ``"auto"``)."""

    device: torch.device
    precision: str

    def __post_init__(self) -> None:
        if self.precision not in DTYPES and self.precision != "fp32":
            raise ValueError(f"Placement precision must be resolved, got {self.precision!r}")


def resolve_placement(
    device: str = "auto", precision: str = "auto", *, check: bool = True
) -> Placement:
    """``device`` and ``precision`` names (``"auto"`` allowed) resolved on this machine; with
    ``check``, bf16 where this machine cannot run it is refused (:func:`check_precision_supported`).
    ValueError (a ``PrecisionUnsupportedError`` for the precision) naming what is missing."""
    where = resolve_device(device)
    resolved = resolve_precision(precision, where)
    if check:
        check_precision_supported(resolved, where)
    return Placement(where, resolved)


def autocast(device: torch.device, precision: str) -> AbstractContextManager[object]:
    """The mixed-precision context for a forward pass: ``torch.autocast`` with the device's type
    and the 16-bit dtype, or a no-op for fp32. Compute losses outside it (in float32)."""
    if precision == "fp32":
        return contextlib.nullcontext()
    return torch.autocast(device_type=device.type, dtype=DTYPES[precision])


def grad_scaler(device: torch.device, precision: str) -> torch.amp.GradScaler:
    """A gradient scaler, enabled for fp16 only (bf16 has float32's exponent range: no
    underflowing gradients to rescue); disabled it is a pass-through."""
    return torch.amp.GradScaler(device.type, enabled=precision == "fp16")


def accelerator_name(device: torch.device) -> str:
    """What the run ran on: the CUDA device's name, ``"Apple MPS"``, or the CPU's model (from
    ``/proc/cpuinfo`` on Linux, else ``platform.processor()``)."""
    if device.type == "cuda":
        return torch.cuda.get_device_name(device)
    if device.type == "mps":
        return "Apple MPS"
    return cpu_model()


def to_device(batch: dict[str, torch.Tensor], device: torch.device) -> dict[str, torch.Tensor]:
    """``batch``'s tensors on ``device`` (non-blocking from pinned memory); the same dict when
    the device is the CPU (no copy: CPU runs do exactly what they did before devices)."""
    if device.type == "cpu":
        return batch
    return {
        k: v.to(device, non_blocking=True) if isinstance(v, torch.Tensor) else v
        for k, v in batch.items()
    }


def outputs_to_float(obj: object) -> object:
    """``obj`` (a ``PoseOutput``, tensor, dict, tuple or list of them) with every floating tensor
    cast to float32: autocast leaves the heads' raw outputs in 16 bits; losses, decoding and
    densities are computed from float32 copies (softmaxes over 4096 cells and the alpha = 8e7
    distribution loss would lose most of their digits in bf16)."""
    import dataclasses

    if isinstance(obj, torch.Tensor):
        return obj.float() if obj.is_floating_point() and obj.dtype != torch.float64 else obj
    if isinstance(obj, dict):
        return {k: outputs_to_float(v) for k, v in obj.items()}
    if isinstance(obj, (tuple, list)):
        return type(obj)(outputs_to_float(v) for v in obj)
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        fields = {f.name: outputs_to_float(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
        return dataclasses.replace(obj, **fields)
    return obj
