"""``uavbench evaluate``: a trained checkpoint over dataset splits -> predictions CSV + metrics.

    uavbench evaluate --checkpoint runs/train-XXXX/checkpoint.pt --split standard/test \\
        --split generalized/test

What it writes and how it fails: :mod:`benchmark.evaluation.evaluate_checkpoint`. ``--device`` /
``--precision`` are resolved here once (``benchmark.models.device.resolve_placement``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from benchmark.errors import UsageError

HELP = "evaluate a trained checkpoint on dataset splits: per-sample CSV and the paper's metrics"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--checkpoint", type=Path, required=True, help="checkpoint.pt of a run")
    parser.add_argument(
        "--split", action="append", dest="splits", help="split to evaluate (repeatable)"
    )
    parser.add_argument("--data-root", type=Path, help="dataset directory (default: the run's)")
    parser.add_argument(
        "--out",
        type=Path,
        help="directory for <split>.csv and metrics.json (default: beside "
        "the checkpoint, in predictions/)",
    )
    parser.add_argument(
        "--satellite",
        choices=("true", "swap"),
        default="true",
        help="true: each pair's own satellite image; swap: another place's (the swap probe)",
    )
    parser.add_argument(
        "--verify",
        choices=("sha256", "size", "full"),
        default="sha256",
        help="dataset file check: sha256 (default; hashed once, cached), size, full (always hash)",
    )
    parser.add_argument(
        "--device",
        default="auto",
        help="auto (CUDA, else MPS, else CPU), cpu, cuda, cuda:N or mps (default auto)",
    )
    parser.add_argument(
        "--precision",
        choices=("auto", "fp32", "bf16", "fp16"),
        default="auto",
        help="autocast precision; auto = bf16 on CUDA devices that support it, else fp32",
    )
    parser.add_argument("--batch-size", type=int, default=64)
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    """Check the flags, resolve the placement once, evaluate; print the headline metrics (where
    the files are and a divergence on stderr). Exit 0, 1 for a diverged model."""
    if not args.checkpoint.is_file():
        raise UsageError(f"--checkpoint {args.checkpoint}: no such file")
    if args.batch_size < 1:
        raise UsageError(f"--batch-size must be >= 1, got {args.batch_size}")
    from benchmark.evaluation.evaluate_checkpoint import EvaluateConfig, evaluate_checkpoint
    from benchmark.models.device import resolve_placement

    try:
        placement = resolve_placement(args.device, args.precision)  # bf16: native on a CPU
    except ValueError as err:
        raise UsageError(f"--device/--precision: {err}") from None
    config = EvaluateConfig(
        checkpoint=args.checkpoint,
        placement=placement,
        splits=tuple(args.splits or ()),
        data_root=args.data_root,
        out=args.out,
        satellite=args.satellite,
        verify=args.verify,
        batch_size=args.batch_size,
        progress=not args.quiet,
    )
    result = evaluate_checkpoint(config)
    for line in result.lines():
        print(line)
    print(result.written(), file=sys.stderr)  # on stderr, as before: stdout keeps the metrics
    if not result.ok:  # a diverged model: a failure (exit 1), not a user error
        print(f"uavbench evaluate: {result.failure()}", file=sys.stderr)
        return 1
    return 0
