"""The CPU flag sets (as ``/proc/cpuinfo`` lists them) of the machine kinds the suite must pass
on, and the one way tests pretend to be one of them.

Imported as ``tests.cpu_kinds`` (the project root is on ``sys.path``, pyproject's ``pythonpath``).
"""

from __future__ import annotations

import pytest

from benchmark.models import precision_support

AVX2_ONLY = frozenset({"fpu", "sse4_2", "avx", "avx2", "fma", "f16c"})
AVX512_NO_BF16 = AVX2_ONLY | {"avx512f", "avx512bw", "avx512vl", "avx512dq", "avx512_vnni"}
ZEN4 = AVX512_NO_BF16 | {"avx512_bf16"}
SAPPHIRE_RAPIDS = AVX512_NO_BF16 | {"avx512_bf16", "amx_tile", "amx_bf16", "amx_int8"}


def fake_cpu(monkeypatch: pytest.MonkeyPatch, flags: frozenset[str] | set[str]) -> None:
    """Pretend to be a CPU with ``flags`` and an uncapped oneDNN (the run's own cap, e.g. the
    emulation of an AVX2 machine by ``tox -e avx2``, would lower every faked level)."""
    monkeypatch.setattr(precision_support, "cpu_flags", lambda: set(flags))
    for name in precision_support.ONEDNN_ISA_ENV:
        monkeypatch.delenv(name, raising=False)
