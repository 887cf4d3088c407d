"""``uavbench continuity``: paper Fig. 2 and Eq. 6, the continuity of attitude representations
(:mod:`benchmark.analysis.continuity`)."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from benchmark.errors import UsageError

HELP = "reproduce paper Fig. 2: continuity of attitude representations vs heading"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--pitch", type=float, default=-20.0, help="pitch theta, deg (paper: -20)")
    parser.add_argument("--roll", type=float, default=-10.0, help="roll gamma, deg (paper: -10)")
    parser.add_argument(
        "--step", type=float, default=0.1, help="heading step of the table, deg (jumps are refined)"
    )
    parser.add_argument(
        "--attitude",
        choices=("uav", "relative"),
        default="uav",
        help="uav: R_b^n as in the paper's analysis; relative: the label R_uav^sat (Eq. 2)",
    )
    parser.add_argument("--out", type=Path, default=Path("reports/continuity"), help="output dir")


def run(args: argparse.Namespace) -> int:
    from benchmark.analysis.continuity import ContinuityConfig, continuity_report

    for name in ("pitch", "roll"):
        value = getattr(args, name)
        if not math.isfinite(value) or abs(value) > 90:
            raise UsageError(f"--{name} must be a finite angle in [-90, 90] deg, got {value}")
    config = ContinuityConfig(args.pitch, args.roll, args.step, args.attitude, args.out)
    for line in continuity_report(config).lines():
        print(line)
    return 0
