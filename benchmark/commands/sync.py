"""``uavbench sync [--from DIR] --to URI``: send the runs kept in a local fallback directory to an
MLflow store (:mod:`benchmark.tracking.sync_report`; exit 0 all copied, 1 runs left out or a
failed copy, 2 bad input)."""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "copy runs kept locally (./tracking-fallback) into an MLflow store; idempotent"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--from",
        dest="source",
        type=Path,
        default=Path("tracking-fallback"),
        metavar="DIR",
        help="local tracking directory (default ./tracking-fallback, where uavbench keeps runs "
        "when MLflow fails; ./tracking-local for --tracker local)",
    )
    parser.add_argument(
        "--to",
        dest="target",
        required=True,
        metavar="URI",
        help="the MLflow store: a server URL (http://host:5000), a sqlite:/// URI or a path "
        "ending in .db",
    )
    parser.add_argument("--quiet", action="store_true", help="print only the summary")


def run(args: argparse.Namespace) -> int:
    from benchmark.tracking.sync_report import sync_and_report

    return sync_and_report(args.source, args.target, quiet=args.quiet)
