"""``uavbench train``: train one variant from a config, evaluate it, track it in MLflow.

    uavbench train --set data.root=data/quick-s0 --set model.attitude=re_net_r --set optim.epochs=5

Every head and encoder option is settable, e.g. ``--set model.attitude_options.hidden=512``.
The config's device and precision are resolved here once and passed down; what is trained,
written and tracked: :mod:`benchmark.training.tracked_run`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

HELP = "train one variant from a config (--set a.b=value), evaluate it and track it in MLflow"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", type=Path, help="YAML file with TrainConfig fields")
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a config field, e.g. --set optim.lr=0.01 (repeatable)",
    )
    parser.add_argument("--out", type=Path, help="output directory (default runs/train-<run key>)")
    parser.add_argument(
        "--eval-split",
        action="append",
        dest="eval_splits",
        help="split(s) to evaluate after training (default: standard/test)",
    )
    parser.add_argument("--experiment", default="train", help="MLflow experiment (default train)")
    parser.add_argument("--tracking-uri", help="MLflow tracking URI (default ./mlflow.db)")
    parser.add_argument("--no-track", action="store_true", help="do not log to MLflow")
    parser.add_argument(
        "--force", action="store_true", help="run even if a finished run of this config exists"
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    """Check the flags, resolve the placement once, train; print the metrics (or the failure on
    stderr). Exit 0, 1 when the run diverged."""
    from benchmark.config import ConfigError
    from benchmark.errors import UsageError
    from benchmark.models.device import resolve_placement
    from benchmark.progress import status_to, to_stderr
    from benchmark.training.config import load_train_config
    from benchmark.training.encoded import resolve_pretrained
    from benchmark.training.tracked_run import TrainRunConfig, train_tracked

    try:
        # A frozen pretrained encoder is named by its checkpoint's digest in the run's identity.
        cfg = resolve_pretrained(load_train_config(args.config, args.overrides))
    except ConfigError as err:
        raise UsageError(str(err)) from None
    if not cfg.data.root:
        raise UsageError(
            "no dataset: pass --set data.root=DIR (a directory from uavbench simulate)"
        )
    try:  # once: training, evaluation, the run key and the tags take this placement
        # bf16 on a CPU without native bf16 (models/precision_support.py), before any work
        placement = resolve_placement(cfg.device, cfg.precision)
    except ValueError as err:  # e.g. device=cuda on a machine (or a torch build) without CUDA
        raise UsageError(str(err)) from None
    config = TrainRunConfig(
        cfg=cfg,
        placement=placement,
        eval_splits=tuple(args.eval_splits or ["standard/test"]),
        out=args.out,
        experiment=args.experiment,
        tracking_uri=args.tracking_uri,
        track=not args.no_track,
        force=args.force,
        progress=not args.quiet,
    )
    # What tracking says while the run goes on (a path taken as a sqlite store, runs only kept
    # locally, MLflow failing mid-run) on stderr, as the command always printed it: stdout keeps
    # the metrics.
    with status_to(to_stderr):
        result = train_tracked(config)
    if not result.ok:  # the run diverged (marked FAILED when tracked): exit 1, one line
        print(f"uavbench train: {result.failure}", file=sys.stderr)
        return 1
    lines = result.lines()
    if result.finished_before is not None:  # the flag that reruns it is the command's to name
        lines = [f"{lines[0]}; --force reruns"]
    for line in lines:
        print(line)
    return 0
