"""``uavbench bench isa``: the dataset's manifest digest with each library's SIMD level forced
down, side by side (:mod:`benchmark.bench.isa`)."""

from __future__ import annotations

import argparse
import os

from benchmark.bench import isa as lib

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


def run(args: argparse.Namespace) -> int:
    config = lib.IsaBenchConfig(
        profile=args.profile,
        size=args.size,
        workers=args.workers,
        seed=args.seed,
        only=None if args.only is None else tuple(args.only),
        strict=args.strict,
    )
    return lib.bench_isa(config)
