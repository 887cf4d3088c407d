"""``uavbench bench ray``: parse the flags into a
:class:`benchmark.bench.ray_cluster.BenchRayConfig` and run
:func:`benchmark.bench.ray_cluster.bench_ray` (the smoke reproduction through the process pool
and through a local Ray, side by side)."""

from __future__ import annotations

import argparse
from pathlib import Path

from benchmark.bench import ray_cluster as lib
from benchmark.commands.reproduce import add_workers_argument

HELP = "smoke reproduction through the process pool and a local Ray: wall times, ratio"
DESCRIPTION = lib.__doc__


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--profile", default="smoke")
    parser.add_argument("--only", default="table3", help="tables to reproduce (default table3)")
    add_workers_argument(parser, "worker processes (units at once), for both executors")
    parser.add_argument("--repeats", type=int, default=1, help="alternating runs of each executor")
    parser.add_argument("--tracker", choices=("mlflow", "local", "null"), default="mlflow")
    parser.add_argument(
        "--dir", type=Path, default=None, help="keep everything here (default: a temporary dir)"
    )


def check_arguments(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    if args.workers < 1 or args.repeats < 1:
        parser.error("--workers and --repeats must be >= 1")


def run(args: argparse.Namespace) -> int:
    """Time both executors and print the table; exit 0 if both computed the same numbers, 1
    otherwise."""
    result = lib.bench_ray(
        lib.BenchRayConfig(
            profile=args.profile,
            only=args.only,
            workers=args.workers,
            repeats=args.repeats,
            tracker=args.tracker,
            dir=args.dir,
        )
    )
    for line in result.lines():
        print(line)
    return 0 if result.same else 1
