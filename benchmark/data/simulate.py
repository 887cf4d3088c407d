"""``uavbench simulate``: render the UAV/satellite pair dataset of a profile (resumable, parallel).

    uavbench simulate --profile {smoke,quick,paper} [--size N] [--out DIR] [--workers K] [--seed S]

Rerunning the same command after an interruption continues where it stopped and produces the
same bytes as an uninterrupted run; rerunning it on a finished dataset confirms it (a cached
checksum check) and renders again any file that no longer matches its manifest. Shards found on
disk that this code's journal does not vouch for are rendered again and compared byte for byte.
An ``--out`` holding a dataset of another profile, size or seed is refused without touching it.

One process renders into a directory at a time (``DIR/.simulate.lock``): a second invocation waits
for the first, saying who holds the lock, then finds the dataset finished; with ``--no-wait`` it
exits 2 instead, naming the holder (pid, host, start). A lock left by a killed process is taken
over. Disk full and permission errors end in one line naming the path and the fix (exit 2).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from benchmark.data.profiles import PROFILES, get_profile
from benchmark.errors import UsageError

HELP = "render the UAV/satellite pair dataset (profiles smoke/quick/paper; resumable, parallel)"


def default_out(profile: str, size: int | None, seed: int) -> Path:
    name = profile + (f"-n{size}" if size is not None else "") + (f"-s{seed}" if seed else "")
    return Path("data") / name


def single_thread_env() -> None:
    """One thread per process for numba/OpenMP/BLAS: parallelism comes from the workers.

    Must run before numba is imported (it reads NUMBA_NUM_THREADS once).
    """
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ.setdefault(var, "1")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--profile",
        choices=sorted(PROFILES),
        default="quick",
        help="dataset profile (default: quick)",
    )
    parser.add_argument(
        "--size",
        type=int,
        default=None,
        help="pairs in the standard split (other sets scale along)",
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="dataset directory (default: data/<profile>[-n<size>][-s<seed>])",
    )
    parser.add_argument(
        "--workers",
        type=int,
        default=os.cpu_count() or 1,
        help="rendering processes (default: all cores)",
    )
    parser.add_argument("--seed", type=int, default=0, help="dataset seed (default: 0)")
    parser.add_argument(
        "--city-cache",
        type=Path,
        default=None,
        help="where built cities are cached (default: $UAVBENCH_CACHE or ~/.cache/uavbench/cities)",
    )
    parser.add_argument(
        "--no-wait",
        action="store_true",
        help="exit 2 if another process is rendering into --out (default: wait for it)",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    if args.size is not None and args.size < 3:
        raise UsageError(f"--size must be >= 3 pairs (train, val, test), got {args.size}")
    if args.workers < 1:
        raise UsageError(f"--workers must be >= 1, got {args.workers}")
    if args.seed < 0:
        raise UsageError(f"--seed must be >= 0, got {args.seed}")
    try:
        profile = get_profile(args.profile, args.size)
    except ValueError as err:
        raise UsageError(str(err)) from err
    out = args.out if args.out is not None else default_out(args.profile, args.size, args.seed)
    single_thread_env()
    from benchmark.data.format import DatasetError, os_error_message
    from benchmark.data.writer import ConfigMismatchError, simulate_dataset
    from benchmark.locks import LockBusyError

    try:
        stats = simulate_dataset(
            out,
            profile,
            args.seed,
            workers=args.workers,
            cache_dir=args.city_cache,
            progress=not args.quiet,
            wait=not args.no_wait,
        )
    except (ConfigMismatchError, LockBusyError, DatasetError) as err:
        raise UsageError(str(err)) from err
    except OSError as err:
        message = os_error_message(err)
        if message is None:
            raise
        raise UsageError(message) from None
    if stats.get("replaced"):
        print(f"{out}: replaced {len(stats['replaced'])} corrupted shard(s): "
              + ", ".join(stats["replaced"]), file=sys.stderr)  # fmt: skip
    if stats["state"] == "complete":
        print(f"{out}: already complete (profile {profile.name}, seed {args.seed}); nothing to do")
    else:
        n = stats["rendered_uav"] + stats["rendered_sat"]
        rate = n / stats["render_s"] if stats["render_s"] > 0 else float("nan")
        print(
            f"{out}: {stats['state']}; cities {stats['cities_s']:.1f} s, "
            f"plan {stats['plan_s']:.1f} s, "
            f"rendered {stats['rendered_uav']} UAV + {stats['rendered_sat']} satellite images in "
            f"{stats['render_s']:.1f} s ({rate:.1f} img/s, {args.workers} workers)",
            file=sys.stdout,
        )
    return 0
