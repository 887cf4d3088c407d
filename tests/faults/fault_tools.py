"""Helpers of the fault-injection tests (a module of its own: conftest files are not imported)."""

from __future__ import annotations

import sys
from pathlib import Path

# `python -c` and not `-m benchmark.cli`: the latter imports cli twice and misses UsageError.
CLI = [
    sys.executable,
    "-c",
    "import sys; from benchmark.cli import main; sys.exit(main(sys.argv[1:]))",
]


def all_files(root: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()
    }


def flip_byte(path: Path, offset: int = -7) -> None:
    """One pixel changed, same size (a bit flip, a bad sector, a stray write)."""
    data = bytearray(path.read_bytes())
    data[offset] ^= 0xFF
    path.write_bytes(bytes(data))
