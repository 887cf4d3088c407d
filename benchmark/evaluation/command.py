"""``uavbench evaluate``: a trained checkpoint over dataset splits -> predictions CSV + metrics.

    uavbench evaluate --checkpoint runs/train-XXXX/checkpoint.pt --split standard/test \\
        --split generalized/test

The dataset defaults to the one the checkpoint was trained on (its config's ``data.root``).
``--satellite swap`` is the satellite-swap probe: each pair is shown the satellite image of another
place (``benchmark.data.swap``), labels unchanged; its files are ``<split>__swap.csv`` and
``metrics__swap.json``.

The dataset's files are checked against its manifest's sha256 by default (``--verify sha256``:
hashed once per file and cached, later opens cost a stat; ``benchmark.data.integrity``), whatever
the checkpoint was trained with. Errors end in one line (exit 2): a missing, truncated or corrupted
dataset file (named, with ``uavbench verify`` as the way to a full report), disk full or no
permission for ``--out`` (the path and the fix). ``--device`` / ``--precision`` as in
``uavbench train`` (``benchmark.models.device``): the checkpoint loads on any device.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

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
    from benchmark.errors import UsageError

    if not args.checkpoint.is_file():
        raise UsageError(f"--checkpoint {args.checkpoint}: no such file")
    if args.batch_size < 1:
        raise UsageError(f"--batch-size must be >= 1, got {args.batch_size}")
    from benchmark.data import DatasetError, list_splits, os_error_message
    from benchmark.models.checkpoint import load_checkpoint, load_trained_model
    from benchmark.models.device import (
        check_precision_supported,
        resolve_device,
        resolve_precision,
    )

    try:
        device = resolve_device(args.device)
        args.precision = resolve_precision(args.precision, device)
        check_precision_supported(args.precision, device)  # bf16: native on a CPU, or the env
    except ValueError as err:
        raise UsageError(f"--device/--precision: {err}") from None
    try:
        ckpt = load_checkpoint(args.checkpoint)
        model = load_trained_model(args.checkpoint, device)
    except ValueError as err:
        raise UsageError(str(err)) from None
    data_cfg = ckpt["config"]["data"]
    root = args.data_root or Path(data_cfg["root"])
    splits = args.splits or ["standard/test"]
    try:
        available = list_splits(root)
    except (DatasetError, OSError) as err:
        raise UsageError(f"dataset {root}: {err}") from None
    for split in splits:
        if split not in available:
            raise UsageError(
                f"--split {split!r} is not in {root}; available: {', '.join(available)}"
            )
    out = args.out or args.checkpoint.parent / "predictions"
    try:
        bad = _evaluate_splits(args, model, ckpt, root, splits, out)
    except DatasetError as err:
        raise UsageError(f"{err} (`uavbench verify {root}` checks every file)") from None
    except OSError as err:
        if err.filename is None:  # a bare write error (e.g. ENOSPC from a CSV writer): name --out
            err = OSError(err.errno, err.strerror, str(out))
        message = os_error_message(err)
        if message is None:
            raise
        raise UsageError(message) from None
    if bad:  # a diverged model: a failure (exit 1), not a user error
        print(f"uavbench evaluate: {bad}; the checkpoint's model diverged (retrain it with a "
              "lower optim.lr)", file=sys.stderr)  # fmt: skip
        return 1
    return 0


def _evaluate_splits(
    args: argparse.Namespace, model: Any, ckpt: dict, root: Path, splits: list[str], out: Path
) -> str | None:
    """Evaluate and write every split; the non-finite metrics found (``"split: keys"``) or None."""
    from benchmark.data import PairDataset, atomic_write_bytes
    from benchmark.evaluation.evaluate import evaluate, non_finite_metrics

    shared = bool(ckpt["config"]["model"].get("shared_satellite", True))
    results, bad = {}, []
    suffix = "" if args.satellite == "true" else "__swap"
    for split in splits:
        dataset = PairDataset(root, split, verify=args.verify, satellite=args.satellite)
        summary, _ = evaluate(
            model,
            dataset,
            out_csv=out / (split.replace("/", "_") + suffix + ".csv"),
            batch_size=args.batch_size,
            shared_satellite=shared,
            progress=not args.quiet,
            desc=f"eval {split}",
            precision=args.precision,
        )
        results[split] = summary
        if non_finite_metrics(summary):
            bad.append(f"{split}: non-finite " + ", ".join(non_finite_metrics(summary)))
        keys = ("dtheta_deg", "dgamma_deg", "dpsi_deg", "dphi_deg", "dE_m", "dN_m", "dU_m")
        print(
            f"{split} ({args.satellite} satellite): n={int(summary['n'])} "
            + ", ".join(f"{k}={summary[k]:.3f}" for k in keys)
        )
    metrics = out / f"metrics{suffix}.json"
    atomic_write_bytes(metrics, (json.dumps(results, indent=1, sort_keys=True) + "\n").encode())
    print(f"predictions and metrics{suffix}.json in {out}", file=sys.stderr)
    return "; ".join(bad) or None
