"""``uavbench bench verify DATASET``: what checksum verification by default costs, side by side.

    uavbench bench verify data/quick [--split standard/train] [--repeats 5]

Opens ``PairDataset(DATASET, split)`` (and checks every file of the dataset) with

- ``size``: existence and sizes only (the old default),
- ``sha256`` first open: an empty verification cache, every file hashed,
- ``sha256`` later open, same process: the cache in memory, a stat per file,
- ``sha256`` later open, new process: the cache read from its file, a stat per file,
- ``full``: always hash (what ``uavbench verify`` does),

and prints the times and the ratios first/later and later/size. The cache used is a temporary
directory, so the user's cache is neither read nor changed.
"""

from __future__ import annotations

import os
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path


def _time(fn: Callable[[], object]) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def bench_verify(dataset: Path, split: str = "standard/train", repeats: int = 5) -> int:
    """Time the ways of opening ``dataset`` (``split``; median of ``repeats`` later opens) and
    print them; exit code 0 (UsageError: ``repeats`` < 1)."""
    from benchmark.data import PairDataset
    from benchmark.data import integrity as integ
    from benchmark.data.format import read_manifest
    from benchmark.errors import UsageError

    if repeats < 1:
        raise UsageError("bench verify: --repeats must be >= 1")
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
            rows.append((what, size, first, same, statistics.median(fresh), full))
    print(
        f"uavbench bench verify: {dataset} ({len(names)} files, {total_mb:.0f} MB), "
        f"median of {repeats} later opens"
    )
    head = ("target", "size", "sha256 1st", "later", "later(new proc)", "full", "1st/later",
            "later/size")  # fmt: skip
    print(f"{head[0]:28s}" + "".join(f"{h:>16s}" for h in head[1:]))
    for what, size, first, same, fresh, full in rows:
        cells = [f"{t * 1e3:.1f} ms" for t in (size, first, same, fresh, full)]
        cells += [f"{first / fresh:.0f}x", f"{fresh / size:.2f}x"]
        print(f"{what:28s}" + "".join(f"{c:>16s}" for c in cells))
    print(f"hashing rate (full check of all files): {total_mb / rows[-1][5]:.0f} MB/s")
    return 0
