"""``uavbench bench simulate``: measured simulator throughput against the issue's targets
(:mod:`benchmark.bench.simulate`)."""

from __future__ import annotations

import argparse
import os

from benchmark.bench import simulate as lib
from benchmark.errors import UsageError

HELP = "pairs/s at 96 and 224 px with all workers, and the time to build a city"
DESCRIPTION = lib.__doc__
FORMATTER = argparse.RawDescriptionHelpFormatter


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    p.add_argument("--sizes", type=int, nargs="+", default=[96, 224])
    p.add_argument(
        "--pairs",
        type=int,
        default=None,
        help="pairs rendered per size (default: 800 below 150 px, else 240)",
    )
    p.add_argument("--style", default="oxford", help="city style rendered (default: oxford)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--strict", action="store_true", help="exit 1 if a target is missed")


def run(args: argparse.Namespace) -> int:
    """Measure, print the city line and a line per size; exit 1 with ``--strict`` and a missed
    target, else 0."""
    pairs_bad = args.pairs is not None and args.pairs < 1
    if args.workers < 1 or any(s < 8 for s in args.sizes) or pairs_bad:
        raise UsageError("bench simulate: --workers >= 1, --sizes >= 8 and --pairs >= 1 expected")
    config = lib.SimulateBenchConfig(
        workers=args.workers,
        sizes=tuple(args.sizes),
        pairs=args.pairs,
        style=args.style,
        seed=args.seed,
    )
    result = lib.bench_simulate(config)
    for line in result.lines():
        print(line)
    return 1 if args.strict and not result.ok else 0
