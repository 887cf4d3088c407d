"""``uavbench bench verify DATASET``: what checksum verification by default costs, side by side.

    uavbench bench verify data/quick [--split standard/train] [--repeats 5]

Opens ``PairDataset(DATASET, split)`` (and checks every file of the dataset) with

- ``size``: existence and sizes only (the old default),
- ``sha256`` first open: an empty verification cache, every file hashed,
- ``sha256`` later open, same process: the cache in memory, a stat per file,
- ``sha256`` later open, new process: the cache read from its file, a stat per file,
- ``full``: always hash (what ``uavbench verify`` does),

and returns the times (``uavbench bench verify`` prints them with the ratios first/later and
later/size). The cache used is a temporary
directory, so the user's cache is neither read nor changed.
"""

from __future__ import annotations

import os
import statistics
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path


def _time(fn: Callable[[], object]) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


@dataclass(frozen=True)
class OpenTimes:
    """The seconds of one target (``what``: opening the split, or checking all files) in each
    way: ``size`` check (median), ``sha256`` ``first`` open, later open in the ``same`` process
    (median), later open in a ``fresh`` process (median) and ``full`` hashing."""

    what: str
    size: float
    first: float
    same: float
    fresh: float
    full: float


@dataclass(frozen=True)
class VerifyBenchResult:
    """What :func:`bench_verify` measured on ``dataset`` (``files`` files, ``total_mb`` MB;
    medians of ``repeats`` later opens): one :class:`OpenTimes` per target, the last one all the
    files."""

    dataset: Path
    files: int
    total_mb: float
    repeats: int
    rows: tuple[OpenTimes, ...]

    @property
    def hashing_mb_per_s(self) -> float:
        """The hashing rate of the full check of all files."""
        return self.total_mb / self.rows[-1].full

    def lines(self) -> list[str]:
        """The heading, the table (times, 1st/later, later/size) and the hashing rate."""
        lines = [
            f"uavbench bench verify: {self.dataset} ({self.files} files, "
            f"{self.total_mb:.0f} MB), median of {self.repeats} later opens"
        ]
        head = ("target", "size", "sha256 1st", "later", "later(new proc)", "full", "1st/later",
                "later/size")  # fmt: skip
        lines.append(f"{head[0]:28s}" + "".join(f"{h:>16s}" for h in head[1:]))
        for r in self.rows:
            cells = [f"{t * 1e3:.1f} ms" for t in (r.size, r.first, r.same, r.fresh, r.full)]
            cells += [f"{r.first / r.fresh:.0f}x", f"{r.fresh / r.size:.2f}x"]
            lines.append(f"{r.what:28s}" + "".join(f"{c:>16s}" for c in cells))
        lines.append(f"hashing rate (full check of all files): {self.hashing_mb_per_s:.0f} MB/s")
        return lines


def bench_verify(
    dataset: Path, split: str = "standard/train", repeats: int = 5
) -> VerifyBenchResult:
    """Time the ways of opening ``dataset`` (``split``; median of ``repeats`` later opens);
    returns the times (InputError: ``repeats`` < 1)."""
    from benchmark.data import PairDataset
    from benchmark.data import integrity as integ
    from benchmark.data.format import read_manifest
    from benchmark.errors import InputError

    if repeats < 1:
        raise InputError(f"bench verify: repeats must be >= 1, got {repeats}")
    manifest = read_manifest(dataset)
    names = list(manifest["files"])
    total_mb = sum(int(e["bytes"]) for e in manifest["files"].values()) / 1e6

    def open_split(mode: str) -> Callable[[], object]:
        return lambda: PairDataset(dataset, split, verify=mode)

    def check_all(mode: str) -> Callable[[], object]:
        return lambda: integ.check_files(dataset, manifest, names, mode=mode)

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        os.environ["UAVBENCH_VERIFY_CACHE"] = tmp
        for what, make in (("open " + split, open_split), ("all files", check_all)):
            integ._MEMO.clear()
            size = statistics.median(_time(make("size")) for _ in range(repeats))
            first = _time(make("sha256"))
            same = statistics.median(_time(make("sha256")) for _ in range(repeats))
            fresh = []
            for _ in range(repeats):
                integ._MEMO.clear()  # as a new process: read the cache file, stat every file
                fresh.append(_time(make("sha256")))
            full = _time(make("full"))
            for f in Path(tmp).iterdir():
                f.unlink()  # the next target starts from an empty cache too
            rows.append(OpenTimes(what, size, first, same, statistics.median(fresh), full))
    return VerifyBenchResult(dataset, len(names), total_mb, repeats, tuple(rows))
