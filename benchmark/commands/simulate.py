"""``uavbench simulate``: render the UAV/satellite pair dataset of a profile (resumable, parallel).

    uavbench simulate --profile {smoke,quick,paper} [--size N] [--out DIR] [--workers K] [--seed S]

What it does, resumes and refuses: :mod:`benchmark.data.simulate`.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from benchmark.data.profiles import DATA_PROFILES, get_data_profile
from benchmark.data.simulate import SimulateConfig, default_out, simulate
from benchmark.errors import UsageError
from benchmark.progress import status_to, to_stderr

HELP = "render the UAV/satellite pair dataset (profiles smoke/quick/paper; resumable, parallel)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--profile",
        choices=sorted(DATA_PROFILES),
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
        profile = get_data_profile(args.profile, args.size)
    except ValueError as err:
        raise UsageError(str(err)) from err
    out = args.out if args.out is not None else default_out(args.profile, args.size, args.seed)
    config = SimulateConfig(
        profile=profile,
        seed=args.seed,
        out=out,
        workers=args.workers,
        city_cache=args.city_cache,
        wait=not args.no_wait,
        progress=not args.quiet,
    )
    # The summary alone on stdout; what simulate notices while it works (a lock it waits for or
    # takes over, a file rendered again) on stderr beside the progress bar, as the command always
    # printed it.
    with status_to(to_stderr):
        result = simulate(config)
    for line in result.warnings():
        print(line, file=sys.stderr)
    for line in result.lines():
        print(line)
    return 0
