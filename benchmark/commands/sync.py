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
    """Sync, print the summary (or, on stderr, why the copy stopped); exit 0 when every ended
    run is in the store, 1 when runs were left out or the copy failed midway."""
    import sys

    from benchmark.tracking.sync_report import sync_and_report

    result = sync_and_report(args.source, args.target, quiet=args.quiet)
    if result.failure:
        print(f"uavbench sync: {result.failure}", file=sys.stderr)
        return 1
    for line in result.lines():
        print(line)
    return 0 if result.ok else 1
