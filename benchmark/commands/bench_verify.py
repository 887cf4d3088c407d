"""``uavbench bench verify DATASET``: what checksum verification by default costs, side by side
(:mod:`benchmark.bench.verify`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from benchmark.bench import verify as lib

HELP = "cost of opening a dataset: size check, first sha256, cached sha256, side by side"
DESCRIPTION = lib.__doc__.split("\n")[0]


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("dataset", type=Path, help="a finished dataset directory")
    p.add_argument("--split", default="standard/train", help="split to open (default: %(default)s)")
    p.add_argument("--repeats", type=int, default=5, help="later opens timed (median; default 5)")


def check_arguments(p: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    if args.repeats < 1:
        p.error("--repeats must be >= 1")


def run(args: argparse.Namespace) -> int:
    """Time the ways of opening the dataset and print the table; exit 0."""
    for line in lib.bench_verify(args.dataset, args.split, args.repeats).lines():
        print(line)
    return 0
