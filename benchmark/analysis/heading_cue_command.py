"""``uavbench heading-cue DATASET``: the "no global heading cue" audit of issue 9.

Fits :mod:`benchmark.analysis.heading_cue`'s probe (image-wide UAV statistics -> ridge -> yaw) on
``--train`` with the regularisation chosen on ``--val``, and prints its mean absolute yaw error
beside the constant predictor's on ``--val`` and each ``--test`` split. A ratio near 1 means the
UAV images carry no heading cue that needs no satellite image; issue 9 asks >= 0.85 on
standard/test.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from benchmark.errors import UsageError

HELP = "audit: how well image-wide UAV statistics alone read the yaw (issue 9)"
THRESHOLD = 0.85  # issue 9 acceptance: probe error >= 0.85 x the constant predictor's


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("dataset", type=Path, help="dataset directory written by uavbench simulate")
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


def _check_splits(root: Path, names: list[tuple[str, str]]) -> None:
    from benchmark.data import DatasetError, list_splits

    try:
        available = list_splits(root)
    except (DatasetError, OSError) as err:
        raise UsageError(f"dataset {root}: {err}") from None
    for flag, split in names:
        if split not in available:
            raise UsageError(
                f"{flag} {split!r} is not in {root}; available: {', '.join(available)}"
            )


def format_result(result: dict) -> str:
    """The audit as a small text table (degrees)."""
    lines = [
        f"probe fitted on {result['train']} (n={result['n_train']}, {result['n_features']} "
        f"features, ridge {result['ridge']:.3g} chosen on {result['val']}); constant predictor "
        f"yaw {result['constant_yaw_deg']:.1f} deg",
        f"{'split':<24} {'n':>6} {'probe deg':>10} {'const deg':>10} {'ratio':>7}",
    ]
    for split, r in result["splits"].items():
        verdict = "" if split == result["val"] else ("  ok" if r["ratio"] >= THRESHOLD else "  CUE")
        lines.append(
            f"{split:<24} {r['n']:>6d} {r['probe_deg']:>10.2f} {r['constant_deg']:>10.2f} "
            f"{r['ratio']:>7.3f}{verdict}"
        )
    lines.append(
        f"ratio = probe / constant yaw error; issue 9 asks >= {THRESHOLD} "
        "(CUE: the UAV image alone gives the heading)"
    )
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from benchmark.analysis.heading_cue import heading_cue_audit

    tests = args.test or ["standard/test"]
    names = [("--train", args.train), ("--val", args.val), *(("--test", t) for t in tests)]
    _check_splits(args.dataset, names)
    result = heading_cue_audit(args.dataset, train=args.train, val=args.val, test=tests)
    print(json.dumps(result, indent=1) if args.json else format_result(result))
    return 0
