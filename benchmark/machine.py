"""Facts about this machine that several layers report (the CPU's model). A leaf: imports nothing
of ours, so data (``bench isa``) and models (``accelerator_name``, the bf16 check) share it."""

from __future__ import annotations

import platform
from pathlib import Path


def read_cpuinfo() -> str | None:
    """The text of ``/proc/cpuinfo``, or None where there is none (macOS, Windows) or it cannot
    be read: the one place that reads it (model name, signature, flags)."""
    try:
        return Path("/proc/cpuinfo").read_text()
    except OSError:
        return None


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo`` on Linux, else ``platform.processor()``), or the
    machine type, or ``"unknown CPU"``."""
    for line in (read_cpuinfo() or "").splitlines():
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return platform.processor() or platform.machine() or "unknown CPU"


_SIGNATURE_FIELDS = ("cpu family", "model", "stepping", "microcode", "cache size")


def cpu_signature(cpuinfo: str | None = None) -> str:
    """The first processor's family, model, stepping, microcode and cache size from
    ``/proc/cpuinfo`` (or the text ``cpuinfo``), e.g. ``"cpu family 6, model 143, stepping 8,
    microcode 0x2b000590, cache size 491520 KB"``; ``"unknown"`` where there is no such file.

    Why beside the model name and flags: the library code paths MKL and oneDNN choose can depend
    on what this line tells apart (``MKL_CBWR`` branches give the matching encoder other bits;
    DEVELOPERS.md, Machine), so two reports that disagree can be checked for it."""
    if cpuinfo is None:
        cpuinfo = read_cpuinfo() or ""
    found: dict[str, str] = {}
    for line in cpuinfo.splitlines():
        if not line.strip():
            if found:
                break  # the end of the first processor's block
            continue
        key, _, value = line.partition(":")
        key = key.strip()
        if key in _SIGNATURE_FIELDS and key not in found:
            found[key] = value.strip()
    parts = [f"{k} {found[k]}" for k in _SIGNATURE_FIELDS if k in found]
    return ", ".join(parts) if parts else "unknown"
