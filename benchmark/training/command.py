"""``uavbench train``: train one variant from a config, evaluate it, track it in MLflow.

This is CLI glue: it connects the training loop (which knows nothing of tracking) to a tracker
through ``on_epoch_end``. Example::

    uavbench train --set data.root=data/quick-s0 --set model.attitude=re_net_r --set optim.epochs=5

The flattened config becomes the run's params; per-epoch metrics are logged in batches; the
predictions CSV of each evaluated split, the config and the history are artifacts. A non-finite
loss ends the run FAILED (exit code 1); Ctrl-C ends it KILLED, and the same command resumes from
the last epoch's checkpoint.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
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
    parser.add_argument(
        "--out", type=Path, help="output directory (default runs/train-<config hash>)"
    )
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
    from benchmark.config import ConfigError, config_hash, flatten, save_yaml
    from benchmark.errors import UsageError
    from benchmark.models.registry import head_versions
    from benchmark.training.config import load_train_config

    try:
        cfg = load_train_config(args.config, args.overrides)
    except ConfigError as err:
        raise UsageError(str(err)) from None
    if not cfg.data.root:
        raise UsageError(
            "no dataset: pass --set data.root=DIR (a directory from uavbench simulate)"
        )
    eval_splits = args.eval_splits or ["standard/test"]
    from benchmark.data import list_splits
    from benchmark.tracking import create_tracker, git_commit, manifest_sha256

    try:
        manifest = manifest_sha256(cfg.data.root)
    except FileNotFoundError as err:
        raise UsageError(f"data.root: {err}") from None
    available = list_splits(cfg.data.root)
    wanted = {"data.train_split": cfg.data.train_split, "data.val_split": cfg.data.val_split}
    wanted.update({f"--eval-split {s}": s for s in eval_splits})
    for what, split in wanted.items():
        if split is not None and split not in available:
            raise UsageError(
                f"{what}={split!r} is not a split of {cfg.data.root}; available: "
                f"{', '.join(available)}"
            )
    # The run's identity: config, evaluated splits, dataset content (not where it lives) and the
    # versions of the heads' maths.
    portable = dataclasses.replace(cfg, data=dataclasses.replace(cfg.data, root=""))
    try:
        versions = head_versions(cfg.model.attitude, cfg.model.translation)
    except ValueError as err:
        raise UsageError(f"model: {err}") from None
    identity = json.dumps([config_hash(portable), sorted(eval_splits), manifest, versions])
    run_key = hashlib.sha256(identity.encode()).hexdigest()[:16]
    out = args.out or Path("runs") / f"train-{config_hash(cfg)}"

    tracker = create_tracker("null" if args.no_track else "mlflow", args.tracking_uri)
    done = tracker.find_finished_run(args.experiment, run_key)
    if done is not None and not args.force:
        print(
            f"already finished: run {done.run_id} ({done.backend}) has this config, splits and "
            "dataset; --force reruns"
        )
        return 0
    tags = {
        "run_key": run_key,
        "config_hash": config_hash(cfg),
        "head": cfg.model.attitude,
        "translation_head": cfg.model.translation,
        "head_versions": json.dumps(versions),
        "encoder": f"{cfg.model.encoder}:{cfg.model.variant}",
        "seed": cfg.seed,
        "git_commit": git_commit() or "unknown",
        "dataset_manifest_sha256": manifest,
        "output_dir": str(out.resolve()),
    }
    variant = "plain" if cfg.model.variant == "/" else cfg.model.variant
    name = f"{cfg.model.attitude}/{variant}/seed{cfg.seed}"
    out.mkdir(parents=True, exist_ok=True)
    save_yaml(cfg, out / "config.yaml", header=f"uavbench train config {config_hash(cfg)}")
    from benchmark.data import DatasetError
    from benchmark.training.loop import NonFiniteLossError

    try:
        with tracker.start_run(args.experiment, name, tags=tags) as tracked:
            tracked.log_params(flatten(cfg))
            tracked.log_artifact(out / "config.yaml")
            summaries = _train_and_evaluate(cfg, out, eval_splits, tracked, quiet=args.quiet)
    except NonFiniteLossError as err:
        print(f"uavbench train: {err}", file=sys.stderr)
        print(f"the run is marked FAILED in {tracker.uri}", file=sys.stderr)
        return 1
    except (ConfigError, DatasetError) as err:
        raise UsageError(str(err)) from None
    for split, summary in summaries.items():
        keys = ("dtheta_deg", "dgamma_deg", "dpsi_deg", "dphi_deg", "dE_m", "dN_m", "dU_m")
        cells = ", ".join(f"{k}={summary[k]:.3f}" for k in keys)
        print(f"{split}: n={int(summary['n'])} {cells}")
    print(f"outputs in {out}; tracked in {tracker.uri}")
    return 0


def _train_and_evaluate(cfg, out: Path, eval_splits: list[str], tracked, *, quiet: bool) -> dict:
    from benchmark.training.build import train_and_evaluate

    _, summaries = train_and_evaluate(
        cfg,
        out,
        eval_splits,
        on_epoch_end=lambda epoch, m: tracked.log_metrics(m, step=epoch),
        progress=not quiet,
    )
    tracked.log_artifact(out / "history.json")
    for split, summary in summaries.items():
        tracked.log_metrics({f"{split}/{k}": v for k, v in summary.items()}, step=cfg.optim.epochs)
    if eval_splits:
        tracked.log_artifact(out / "predictions")
    return summaries
