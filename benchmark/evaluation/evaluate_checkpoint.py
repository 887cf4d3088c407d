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

:func:`evaluate_checkpoint` returns what it measured and wrote (:class:`EvaluateResult`);
``benchmark.commands.evaluate`` prints it and picks the exit code (1 for a diverged model).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from benchmark.models.device import Placement


@dataclass(frozen=True)
class EvaluateConfig:
    """One ``uavbench evaluate``: the ``checkpoint`` (an existing file) on ``splits`` (empty:
    standard/test) of ``data_root`` (None: the run's dataset), outputs in ``out`` (None:
    ``predictions/`` beside the checkpoint), ``satellite`` ``"true"`` or ``"swap"``, files
    checked by ``verify``, batches of ``batch_size`` on ``placement``."""

    checkpoint: Path
    placement: Placement
    splits: tuple[str, ...] = ()
    data_root: Path | None = None
    out: Path | None = None
    satellite: str = "true"
    verify: str = "sha256"
    batch_size: int = 64
    progress: bool = True


# The headline metrics of a split, in the order they are printed.
HEADLINE_KEYS = ("dtheta_deg", "dgamma_deg", "dpsi_deg", "dphi_deg", "dE_m", "dN_m", "dU_m")


@dataclass(frozen=True)
class EvaluateResult:
    """What one :func:`evaluate_checkpoint` measured and wrote: ``metrics`` (split -> summary)
    with the ``satellite`` images, the predictions CSVs and ``metrics_file`` in ``out``;
    ``non_finite``: the non-finite metrics found (``"split: non-finite keys"``, ``""`` when
    none), i.e. the checkpoint's model diverged."""

    out: Path
    metrics_file: Path
    satellite: str
    metrics: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    non_finite: str = ""

    @property
    def ok(self) -> bool:
        """Every metric is finite."""
        return not self.non_finite

    def lines(self) -> list[str]:
        """The headline metrics, one line per split (what ``uavbench evaluate`` prints)."""
        return [
            f"{split} ({self.satellite} satellite): n={int(summary['n'])} "
            + ", ".join(f"{k}={summary[k]:.3f}" for k in HEADLINE_KEYS)
            for split, summary in self.metrics.items()
        ]

    def written(self) -> str:
        """Where the files are (one line)."""
        return f"predictions and {self.metrics_file.name} in {self.out}"

    def failure(self) -> str:
        """Why the result is not usable (``""`` when :attr:`ok`): one line with the fix."""
        if self.ok:
            return ""
        return (
            f"{self.non_finite}; the checkpoint's model diverged (retrain it with a lower optim.lr)"
        )


def evaluate_checkpoint(config: EvaluateConfig) -> EvaluateResult:
    """Evaluate and write every split of ``config`` (predictions CSV per split, metrics JSON).
    Returns the metrics and where they are (:class:`EvaluateResult`; not ``ok`` for a diverged
    model, whose metrics are not finite). Raises :class:`~benchmark.errors.InputError` for an
    unreadable checkpoint, a missing split, a damaged dataset or a disk error."""
    from benchmark.data import DatasetError, list_splits, os_error_message
    from benchmark.errors import InputError
    from benchmark.models.checkpoint import load_checkpoint, load_trained_model

    try:
        ckpt = load_checkpoint(config.checkpoint)
        model = load_trained_model(config.checkpoint, config.placement.device)
    except ValueError as err:
        raise InputError(str(err)) from None
    data_cfg = ckpt["config"]["data"]
    root = config.data_root or Path(data_cfg["root"])
    splits = list(config.splits) or ["standard/test"]
    try:
        available = list_splits(root)
    except (DatasetError, OSError) as err:
        raise InputError(f"dataset {root}: {err}") from None
    for split in splits:
        if split not in available:
            raise InputError(
                f"splits: {split!r} is not in {root}; available: {', '.join(available)}"
            )
    out = config.out or config.checkpoint.parent / "predictions"
    try:
        result = _evaluate_splits(config, model, ckpt, root, splits, out)
    except DatasetError as err:
        raise InputError(f"{err} (`uavbench verify {root}` checks every file)") from None
    except OSError as err:
        if err.filename is None:  # a bare write error (e.g. ENOSPC from a CSV writer): name out
            err = OSError(err.errno, err.strerror, str(out))
        message = os_error_message(err)
        if message is None:
            raise
        raise InputError(message) from None
    return result  # a diverged model is a failure (exit 1), not a user error: not raised


def _evaluate_splits(
    config: EvaluateConfig, model: Any, ckpt: dict, root: Path, splits: list[str], out: Path
) -> EvaluateResult:
    """Evaluate and write every split; the metrics, with the non-finite ones found."""
    from benchmark.data import PairDataset, atomic_write_bytes
    from benchmark.evaluation.evaluate import evaluate, non_finite_metrics

    shared = bool(ckpt["config"]["model"].get("shared_satellite", True))
    results, bad = {}, []
    suffix = "" if config.satellite == "true" else "__swap"
    for split in splits:
        dataset = PairDataset(root, split, verify=config.verify, satellite=config.satellite)
        summary, _ = evaluate(
            model,
            dataset,
            out_csv=out / (split.replace("/", "_") + suffix + ".csv"),
            batch_size=config.batch_size,
            shared_satellite=shared,
            progress=config.progress,
            desc=f"eval {split}",
            precision=config.placement.precision,
        )
        results[split] = summary
        if non_finite_metrics(summary):
            bad.append(f"{split}: non-finite " + ", ".join(non_finite_metrics(summary)))
    metrics = out / f"metrics{suffix}.json"
    atomic_write_bytes(metrics, (json.dumps(results, indent=1, sort_keys=True) + "\n").encode())
    return EvaluateResult(out, metrics, config.satellite, results, "; ".join(bad))
