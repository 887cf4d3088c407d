"""``uavbench reference``: evaluate a non-learned reference on a split like a model.

    uavbench reference geometry_oracle --data data/quick --split standard/test
    uavbench reference gravity_template --data data/quick --split towns/test --satellite swap \\
        --out runs/ref/towns_test__swap.csv

What it prints and writes: :mod:`benchmark.references.report`. ``--set key=value`` passes a
reference option (a YAML scalar).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from benchmark.errors import UsageError

HELP = "evaluate a non-learned reference (oracle, template, feature+PnP) on a split like a model"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("name", help="reference: geometry_oracle, gravity_template, feature_pnp")
    parser.add_argument("--data", type=Path, required=True, help="dataset directory")
    parser.add_argument("--split", required=True, help="split to evaluate, e.g. standard/test")
    parser.add_argument(
        "--satellite",
        choices=("true", "swap"),
        default="true",
        help="true: each pair's own satellite image; swap: another place's (the swap probe)",
    )
    parser.add_argument("--out", type=Path, help="per-frame CSV (the summary goes to .json)")
    parser.add_argument(
        "--train-split", help="split whose mean pose failed frames get (default: by family)"
    )
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        dest="options",
        metavar="KEY=VALUE",
        help="reference option, e.g. --set step_deg=2 (repeatable)",
    )
    parser.add_argument("--limit", type=int, help="evaluate only the first N pairs")
    parser.add_argument(
        "--stride",
        type=int,
        default=1,
        help="evaluate every K-th pair (0, K, 2K, ...: every flight keeps frames); default 1",
    )
    parser.add_argument(
        "--verify",
        choices=("sha256", "size", "full"),
        default="sha256",
        help="dataset file check (default sha256: hashed once, cached)",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def _parse_options(items: list[str]) -> dict[str, object]:
    """``["step_deg=2"]`` -> ``{"step_deg": 2}``: the one KEY=VALUE reader and converter
    (``benchmark.config.split_assignment`` and ``parse_scalar``, as ``model-info --set`` and
    ``train --set``)."""
    from benchmark.config import ConfigError, parse_scalar, split_assignment
    from benchmark.errors import UsageError

    out: dict[str, object] = {}
    for item in items:
        try:
            key, value = split_assignment(item, "step_deg=2")
        except ConfigError as err:
            raise UsageError(f"--set {err}") from None
        out[key] = parse_scalar(value)
    return out


def run(args: argparse.Namespace) -> int:
    """Check the flags, evaluate the reference, print its headline metrics; exit 0."""
    from benchmark.references.report import ReferenceRunConfig, evaluate_and_report

    if args.limit is not None and args.limit < 1:
        raise UsageError(f"--limit must be >= 1, got {args.limit}")
    if args.stride < 1:
        raise UsageError(f"--stride must be >= 1, got {args.stride}")
    config = ReferenceRunConfig(
        name=args.name,
        data=args.data,
        split=args.split,
        satellite=args.satellite,
        out=args.out,
        train_split=args.train_split,
        options=_parse_options(args.options),
        limit=args.limit,
        stride=args.stride,
        verify=args.verify,
        progress=not args.quiet,
    )
    report = evaluate_and_report(config)
    for line in report.lines():
        print(line)
    if report.out is not None:  # on stderr, as before: stdout keeps only the metrics
        print(f"per-frame predictions in {report.out}", file=sys.stderr)
    return 0
