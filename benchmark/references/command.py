"""``uavbench reference``: evaluate a non-learned reference on a split like a model.

    uavbench reference geometry_oracle --data data/quick --split standard/test
    uavbench reference gravity_template --data data/quick --split towns/test --satellite swap \\
        --out runs/ref/towns_test__swap.csv

Prints the headline metrics (and the failure rate, the 3D position error and OrthoLoC's
(metres, degrees) accuracies), writes the per-frame CSV (the columns of ``uavbench evaluate``'s,
plus ``reference_failed`` and ``reference_score``) to ``--out`` and the summary beside it as JSON.
Failed frames get the constant predictor's pose from ``--train-split`` (default: the split the
models evaluated on ``--split`` train on). ``--set key=value`` passes a reference option.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

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
    import yaml

    from benchmark.errors import UsageError

    out: dict[str, object] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise UsageError(f"--set {item!r}: expected KEY=VALUE")
        out[key.strip()] = yaml.safe_load(value)
    return out


def run(args: argparse.Namespace) -> int:
    from benchmark.data import DatasetError, PairDataset, list_splits, os_error_message
    from benchmark.errors import UsageError
    from benchmark.references import (
        create_reference,
        default_train_split,
        evaluate_reference,
        fallback_pose,
        list_references,
    )

    if args.name not in list_references():
        raise UsageError(f"unknown reference {args.name!r}; known: {', '.join(list_references())}")
    if args.limit is not None and args.limit < 1:
        raise UsageError(f"--limit must be >= 1, got {args.limit}")
    if args.stride < 1:
        raise UsageError(f"--stride must be >= 1, got {args.stride}")
    options = _parse_options(args.options)
    try:
        reference = create_reference(args.name, **options)
    except (TypeError, ValueError) as err:
        raise UsageError(f"--set: {err}") from None
    try:
        available = list_splits(args.data)
    except (DatasetError, OSError) as err:
        raise UsageError(f"--data {args.data}: {err}") from None
    train_split = args.train_split or default_train_split(args.split, available)
    for flag, split in (("--split", args.split), ("--train-split", train_split)):
        if split not in available:
            raise UsageError(f"{flag} {split!r} is not in {args.data}; available: "
                             + ", ".join(available))  # fmt: skip
    try:
        dataset = PairDataset(args.data, args.split, verify=args.verify, satellite=args.satellite)
        fallback = fallback_pose(PairDataset(args.data, train_split, verify=args.verify))
        rows = list(range(0, len(dataset), args.stride))[: args.limit]
        summary, _ = evaluate_reference(
            reference,
            dataset,
            fallback=fallback,
            out_csv=args.out,
            rows=rows,
            progress=not args.quiet,
            desc=f"{args.name} {args.split}",
        )
        if args.out is not None:
            record = {
                "reference": args.name,
                "label": reference.label,
                "given": list(reference.given),
                "options": reference.options(),
                "split": args.split,
                "satellite": args.satellite,
                "train_split": train_split,
                "stride": args.stride,
                "summary": summary,
            }
            text = json.dumps(record, indent=1, sort_keys=True) + "\n"
            args.out.with_suffix(".json").write_text(text)
    except DatasetError as err:
        raise UsageError(f"{err} (`uavbench verify {args.data}` checks every file)") from None
    except OSError as err:
        message = os_error_message(err)
        if message is None:
            raise
        raise UsageError(message) from None
    keys = ("dtheta_deg", "dgamma_deg", "dpsi_deg", "median_dpsi_deg", "dphi_deg")
    print(
        f"{reference.label}\n{args.split} ({args.satellite} satellite): n={int(summary['n'])} "
        + ", ".join(f"{k}={summary[k]:.2f}" for k in keys)
        + f", dE_m={summary['dE_m']:.1f}, dN_m={summary['dN_m']:.1f}, dU_m={summary['dU_m']:.1f}"
        + f", median_pos_err_m={summary['median_pos_err_m']:.1f}"
        + "".join(f", {k}={summary[k]:.3f}" for k in summary if k.startswith("acc_"))
        + f", failure_rate={summary['failure_rate']:.3f}"
        + f", frames_per_s={summary.get('frames_per_s', float('nan')):.1f}"
        + f", cpu_ms_per_frame={summary['cpu_ms_per_frame']:.0f}"
    )
    if args.out is not None:
        print(f"per-frame predictions in {args.out}", file=sys.stderr)
    return 0
