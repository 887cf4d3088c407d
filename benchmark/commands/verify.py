"""``uavbench verify DATASET``: check every file of a dataset against its manifest, in full.

    uavbench verify data/quick [--quiet]

Exit 0 when all is good, 1 naming each bad file and the fix, 2 for a path that is not a dataset
(:mod:`benchmark.data.verify`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from benchmark.data.verify import verify_and_report

HELP = "check every file of a dataset against its manifest (sha256, shapes, counts); exit 1 if bad"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("dataset", type=Path, help="dataset directory (written by simulate)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    report = verify_and_report(args.dataset, progress=not args.quiet)
    # all good: the OK line on stdout; else each problem and the fix on stderr
    stream = sys.stdout if report.ok else sys.stderr
    for line in report.lines():
        print(line, file=stream)
    return 0 if report.ok else 1
