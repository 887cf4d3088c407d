"""``uavbench preview DATASET``: a contact sheet PNG of UAV/satellite pairs with their poses
(:mod:`benchmark.data.preview`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from benchmark.data.preview import PreviewConfig, preview
from benchmark.errors import UsageError

HELP = "write a contact sheet PNG of UAV/satellite pairs with their poses"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("dataset", type=Path, help="dataset directory written by simulate")
    parser.add_argument("--split", default="standard/train", help="split (default: standard/train)")
    parser.add_argument("--n", type=int, default=8, help="number of pairs (default: 8)")
    parser.add_argument(
        "--out", type=Path, default=None, help="PNG path (default: DATASET/preview_<split>.png)"
    )
    parser.add_argument("--seed", type=int, default=0, help="which pairs: seed of the pick")


def run(args: argparse.Namespace) -> int:
    if args.n < 1:
        raise UsageError(f"--n must be >= 1, got {args.n}")
    result = preview(PreviewConfig(args.dataset, args.split, args.n, args.out, args.seed))
    for line in result.lines():
        print(line)
    return 0
