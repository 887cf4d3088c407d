"""The C allocator's policy for large blocks, set once per process (issue 40, item 3).

Tensors of a few MB come from glibc's ``malloc``. By default glibc serves a block above its mmap
threshold (128 KiB, raised as mapped blocks are freed, up to 32 MiB) with a fresh ``mmap`` and
returns the heap's free top to the system above its trim threshold. Either way, the next tensor
of that size starts on pages the kernel must fault in and zero: on these 2-core VMs a fresh 2 MB
buffer cost ~10x its copy (stop 49). The fusion's float64 grids (a few MB each, a dozen
temporaries per step) and the matcher's step allocate such blocks all the time.

:func:`tune_allocator` raises the mmap threshold to :data:`MMAP_THRESHOLD` (256 MiB) and the trim
threshold to :data:`TRIM_THRESHOLD` (1 GiB) with ``mallopt``, so freed blocks stay in the heap
and are reused warm, and exports the same figures as ``MALLOC_MMAP_THRESHOLD_`` /
``MALLOC_TRIM_THRESHOLD_`` for the processes this one starts (spawned workers, Ray's local
workers), whose glibc reads them at start-up. The cost is memory: a process keeps up to 1 GiB
of freed heap instead of returning it (24 GiB machines, 2 workers). Numbers do not change: only
where a block lives.

``UAVBENCH_ALLOCATOR=default`` leaves glibc's policy alone (``uavbench bench allocator`` runs
each side in a fresh process that way). Not glibc (macOS, musl, Windows): nothing to do.
"""

from __future__ import annotations

import ctypes
import os
import platform
from dataclasses import dataclass

MMAP_THRESHOLD = 256 * 1024 * 1024  # bytes: blocks below come from the heap
TRIM_THRESHOLD = 1024 * 1024 * 1024  # bytes of free heap top kept before returning any
ENV_SWITCH = "UAVBENCH_ALLOCATOR"  # "default": leave glibc's policy alone
ALLOCATOR_ENV = {
    "MALLOC_MMAP_THRESHOLD_": str(MMAP_THRESHOLD),
    "MALLOC_TRIM_THRESHOLD_": str(TRIM_THRESHOLD),
}
# glibc's mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3


@dataclass(frozen=True)
class AllocatorStatus:
    """What :func:`tune_allocator` did: ``tuned`` whether this process's policy was changed,
    ``detail`` one line for logs and bench headers."""

    tuned: bool
    detail: str


_STATUS: AllocatorStatus | None = None


def _glibc() -> ctypes.CDLL | None:
    """This process's C library if it is glibc (it has ``gnu_get_libc_version`` and
    ``mallopt``), else None."""
    if platform.system() != "Linux":
        return None
    try:
        libc = ctypes.CDLL(None)
        libc.gnu_get_libc_version.restype = ctypes.c_char_p
        libc.gnu_get_libc_version()
        libc.mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
        libc.mallopt.restype = ctypes.c_int
    except (OSError, AttributeError):
        return None
    return libc


def tune_allocator() -> AllocatorStatus:
    """Keep freed large blocks in the heap (module docstring), once per process; later calls
    return the first call's status. Refused by ``UAVBENCH_ALLOCATOR=default`` or a C library
    other than glibc (status says which)."""
    global _STATUS
    if _STATUS is not None:
        return _STATUS
    switch = os.environ.get(ENV_SWITCH, "").strip().lower()
    if switch == "default":
        _STATUS = AllocatorStatus(False, f"allocator: glibc default ({ENV_SWITCH}=default)")
        return _STATUS
    if switch not in ("", "tuned"):
        raise ValueError(f"{ENV_SWITCH} must be 'default' or 'tuned', got {switch!r}")
    libc = _glibc()
    if libc is None:
        _STATUS = AllocatorStatus(False, "allocator: the platform's own (not glibc)")
        return _STATUS
    ok = libc.mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD) == 1
    ok = libc.mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD) == 1 and ok
    for name, value in ALLOCATOR_ENV.items():
        os.environ.setdefault(name, value)  # a user's own figures win in the children
    version = libc.gnu_get_libc_version().decode()
    if not ok:
        _STATUS = AllocatorStatus(False, f"allocator: glibc {version} refused mallopt")
        return _STATUS
    _STATUS = AllocatorStatus(
        True,
        f"allocator: glibc {version}, mmap threshold {MMAP_THRESHOLD >> 20} MiB, "
        f"trim threshold {TRIM_THRESHOLD >> 20} MiB",
    )
    return _STATUS


def allocator_status() -> AllocatorStatus:
    """This process's allocator policy as :func:`tune_allocator` left it (untouched if it was
    never called)."""
    return _STATUS or AllocatorStatus(False, "allocator: glibc default (not tuned)")


def block_in_heap(nbytes: int) -> bool | None:
    """Whether a block of ``nbytes`` that ``malloc`` serves now lies in the process's heap
    (the ``[heap]`` mapping of ``/proc/self/maps``) rather than in a mapping of its own: the
    policy as the kernel sees it. The block is freed before returning. None off glibc/Linux."""
    libc = _glibc()
    if libc is None:
        return None
    libc.malloc.restype = ctypes.c_void_p
    libc.malloc.argtypes = [ctypes.c_size_t]
    libc.free.argtypes = [ctypes.c_void_p]
    address = libc.malloc(nbytes)
    if not address:
        raise MemoryError(f"malloc({nbytes}) failed")
    try:
        with open("/proc/self/maps") as maps:
            for line in maps:
                if line.rstrip().endswith("[heap]"):
                    low, high = (int(x, 16) for x in line.split()[0].split("-"))
                    if low <= address < high:
                        return True
        return False
    finally:
        libc.free(address)


def allocator_probe() -> dict[str, object]:
    """This process's policy in one dict (for a fresh process to report back): the status of
    :func:`tune_allocator`, the ``MALLOC_*`` figures in its environment, and whether a 4 MiB
    block comes from the heap (:func:`block_in_heap`)."""
    status = tune_allocator()
    return {
        "tuned": status.tuned,
        "detail": status.detail,
        "env": {name: os.environ.get(name) for name in ALLOCATOR_ENV},
        "in_heap": block_in_heap(4 * 1024 * 1024),
    }


__all__ = [
    "ALLOCATOR_ENV",
    "ENV_SWITCH",
    "MMAP_THRESHOLD",
    "TRIM_THRESHOLD",
    "AllocatorStatus",
    "allocator_probe",
    "allocator_status",
    "block_in_heap",
    "tune_allocator",
]
