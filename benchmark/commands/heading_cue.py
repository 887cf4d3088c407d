"""``uavbench heading-cue DATASET``: the "no global heading cue" audit of issue 9
(:mod:`benchmark.analysis.heading_cue_report`)."""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "audit: how well image-wide UAV statistics alone read the yaw (issue 9)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "dataset",
        type=Path,
        nargs="+",
        help="dataset directory written by uavbench simulate (several: audited and pooled)",
    )
    parser.add_argument("--train", default="standard/train", help="split the probe is fitted on")
    parser.add_argument(
        "--val", default="standard/val", help="split the ridge strength is chosen on"
    )
    parser.add_argument(
        "--test",
        action="append",
        default=None,
        help="split to score (repeatable; default standard/test)",
    )
    parser.add_argument("--json", action="store_true", help="print the result as JSON")


def run(args: argparse.Namespace) -> int:
    from benchmark.analysis.heading_cue_report import HeadingCueConfig, heading_cue_audit_report

    config = HeadingCueConfig(
        datasets=tuple(args.dataset),
        train=args.train,
        val=args.val,
        test=tuple(args.test or ["standard/test"]),
        as_json=args.json,
    )
    for line in heading_cue_audit_report(config).lines():
        print(line)
    return 0
