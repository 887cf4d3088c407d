"""``uavbench bench simulate``: measured simulator throughput against the issue's targets
(:mod:`benchmark.bench.simulate`)."""

from __future__ import annotations

import argparse
import os

from benchmark.bench import simulate as lib

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
    config = lib.SimulateBenchConfig(
        workers=args.workers,
        sizes=tuple(args.sizes),
        pairs=args.pairs,
        style=args.style,
        seed=args.seed,
        strict=args.strict,
    )
    return lib.bench_simulate(config)
