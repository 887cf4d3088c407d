"""``uavbench bench isa``: the dataset's manifest digest with each library's SIMD level forced
down, side by side (:mod:`benchmark.bench.isa`)."""

from __future__ import annotations

import argparse
import os

from benchmark.bench import isa as lib
from benchmark.errors import UsageError

HELP = "dataset manifest digest with each library's SIMD level forced down, side by side"
DESCRIPTION = lib.__doc__
FORMATTER = argparse.RawDescriptionHelpFormatter


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--profile", default="smoke", help="dataset profile (default: smoke)")
    p.add_argument("--size", type=int, default=None, help="standard pairs (simulate --size)")
    p.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1))
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--only",
        nargs="+",
        default=None,
        help="settings to run besides default (numpy openblas numba torch opencv arrow libjpeg "
        "all); default: every one",
    )
    p.add_argument("--strict", action="store_true", help="exit 1 if any digest differs")


def check_flags(args: argparse.Namespace) -> None:
    """UsageError naming the flag: an unknown ``--profile`` or ``--only`` setting, ``--workers``
    below 1 (the library refuses them too, naming its config's fields)."""
    from benchmark.data.profiles import DATA_PROFILES

    if args.profile not in DATA_PROFILES:
        raise UsageError(
            f"bench isa: unknown --profile {args.profile!r}; one of {sorted(DATA_PROFILES)}"
        )
    if args.workers < 1:
        raise UsageError(f"bench isa: --workers must be >= 1, got {args.workers}")
    if args.only is not None:
        rows = lib.isa_rows()
        unknown = sorted(set(args.only) - set(rows))
        if unknown:
            raise UsageError(f"bench isa: unknown --only {unknown}; expected some of {list(rows)}")


def run(args: argparse.Namespace) -> int:
    """Render once per setting, print the rows and the verdict; exit 1 with ``--strict`` when a
    digest differs, else 0."""
    check_flags(args)
    config = lib.IsaBenchConfig(
        profile=args.profile,
        size=args.size,
        workers=args.workers,
        seed=args.seed,
        only=None if args.only is None else tuple(args.only),
    )
    result = lib.bench_isa(config)
    for line in result.lines():
        print(line)
    return 1 if args.strict and not result.same else 0
