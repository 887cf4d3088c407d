"""Run a model over a split: per-sample predictions (CSV) and the metric summary.

Heads are used only through the contract (``benchmark.models.heads``): ``decode`` for every head;
``log_prob`` when the head declares ``is_probabilistic`` or ``gives_log_prob``, ``uncertainty`` when
it declares ``is_probabilistic`` or ``gives_uncertainty``. Nothing here knows which head it is
running.

Per-sample tables of a ``PairDataset`` (or a ``Subset`` of one) carry its ``city``, ``centre`` and
``flight`` columns and the satellite image each pair was shown (``sat_index``, the swapped one under
``satellite="swap"``), so that paired comparisons can resample whole flights
(``benchmark.evaluation.paired``).

The library behind every model evaluation (training's validation, ``uavbench evaluate`` through
``benchmark.evaluation.evaluate_checkpoint``); not the command module
``benchmark.commands.evaluate`` nor ``benchmark.references.evaluate``, which runs a non-learned
reference over a split.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch
from torch.utils.data import DataLoader, Dataset, Subset

from benchmark.evaluation.metrics import (
    ACCURACY_THRESHOLDS_DEG,
    ERROR_COLUMNS,
    predictions_frame,
    summarize,
    write_predictions_csv,
)
from benchmark.models.device import autocast, outputs_to_float, to_device
from benchmark.progress import Progress


@dataclass
class Predictions:
    """Everything one pass produced. Rotations ``(N, 3, 3)`` are ``R_uav^sat``; translations
    ``(N, 3)`` metres; ``log_likelihood`` / ``uncertainty`` ``(N,)`` or None (regression heads);
    ``loss`` is the mean over samples of each term of ``PoseModel.loss`` (final level only)."""

    index: torch.Tensor
    R_hat: torch.Tensor
    R_gt: torch.Tensor
    T_hat: torch.Tensor
    T_gt: torch.Tensor
    log_likelihood: torch.Tensor | None
    uncertainty: torch.Tensor | None
    loss: dict[str, float]
    beliefs: torch.Tensor | None = None  # (N, ...) from ``predict``'s ``beliefs``, or None


# (attitude head, its raw output for a batch, decoded R_hat (B, 3, 3)) -> (B, ...) per-frame
# beliefs, e.g. ``benchmark.evaluation.beliefs.yaw_beliefs`` on a grid (issue 39).
BeliefFn = Callable[[torch.nn.Module, Any, torch.Tensor], torch.Tensor]


def make_loader(
    dataset: Dataset, batch_size: int, num_workers: int = 0, pin_memory: bool = False
) -> DataLoader:
    """Sequential loader (evaluation order = dataset order, so outputs are reproducible);
    ``pin_memory`` for a CUDA device (faster, asynchronous copies)."""
    return DataLoader(
        dataset,
        batch_size=batch_size,
        shuffle=False,
        num_workers=num_workers,
        pin_memory=pin_memory,
    )


def forward_batch(model: torch.nn.Module, batch: dict[str, Any], shared_satellite: bool) -> Any:
    """``model``'s output for one collated batch: the heads alone on a frozen encoder's cached
    ``features`` (``benchmark.training.encoded``), else the whole model on the images (with the
    items' ``context`` for pair encoders)."""
    # The items' per-sample geometry goes to the model unread here (pair encoders use it).
    if "features" in batch:
        return model.forward_features(batch["features"])
    sat_ids = batch["sat_id"] if shared_satellite else None
    context = {"context": batch["context"]} if "context" in batch else {}  # pair encoders
    return model(batch["uav"], batch["sat"], sat_ids, **context)


@torch.no_grad()
def model_outputs(
    model: torch.nn.Module,
    dataset: Dataset | DataLoader,
    *,
    batch_size: int = 64,
    shared_satellite: bool = True,
    precision: str = "fp32",
    num_workers: int = 0,
    progress: bool = False,
    desc: str = "pass",
) -> Iterator[tuple[dict[str, Any], Any]]:
    """``(batch, output)`` of every batch of ``dataset`` (or of a ready ``DataLoader``) in
    order: eval mode (restored when the iteration ends or stops), no autograd, the batch on the
    model's device (the CPU for a parameter-free model), the forward under autocast for
    ``precision`` and its outputs back in float32. :func:`predict` runs on it, and so does any
    pass that keeps something else (a pose volume's marginals, a head's raw outputs)."""
    weight = next(iter(model.parameters()), None)
    device = weight.device if weight is not None else torch.device("cpu")
    loader = (
        dataset
        if isinstance(dataset, DataLoader)
        else make_loader(dataset, batch_size, num_workers, device.type == "cuda")
    )
    was_training = model.training
    model.eval()
    try:
        with Progress(len(loader), desc, unit="batch", enabled=progress) as bar:
            for batch in loader:
                batch = to_device(batch, device)  # the same dict on the CPU
                with autocast(device, precision):
                    out = forward_batch(model, batch, shared_satellite)
                if precision != "fp32":
                    out = outputs_to_float(out)
                yield batch, out
                bar.update(1)
    finally:
        model.train(was_training)


@torch.no_grad()
def predict(
    model: torch.nn.Module,
    dataset: Dataset | DataLoader,
    *,
    batch_size: int = 64,
    shared_satellite: bool = True,
    progress: bool = False,
    desc: str = "eval",
    precision: str = "fp32",
    num_workers: int = 0,
    beliefs: BeliefFn | None = None,
) -> Predictions:
    """Predict every item of ``dataset`` (items as ``PairDataset`` gives them) in eval mode.

    Batches go to the model's device; the forward pass runs under autocast for ``precision``
    ``"bf16"``/``"fp16"`` (resolved, not ``"auto"``), decoding, losses and densities in float32
    on its outputs; results come back to the CPU in float64. The model's train/eval mode is
    restored afterwards. ``beliefs`` (optional) is called on every batch with the attitude
    head, its float32 raw output and ``R_hat``; its outputs are concatenated in
    ``Predictions.beliefs`` (float64, CPU).
    """
    head = model.attitude_head
    probabilistic = bool(getattr(head, "is_probabilistic", False))
    with_log_prob = probabilistic or bool(getattr(head, "gives_log_prob", False))
    with_uncertainty = probabilistic or bool(getattr(head, "gives_uncertainty", False))
    parts: dict[str, list[torch.Tensor]] = {
        k: []
        for k in (
            "index",
            "R_hat",
            "R_gt",
            "T_hat",
            "T_gt",
            "log_likelihood",
            "uncertainty",
            "beliefs",
        )
    }
    loss_sums: dict[str, float] = {}
    count = 0
    passes = model_outputs(
        model, dataset, batch_size=batch_size, shared_satellite=shared_satellite,
        precision=precision, num_workers=num_workers, progress=progress, desc=desc,
    )  # fmt: skip
    for batch, out in passes:
        R_gt, T_gt = batch["R"], batch["T"]
        R_hat, T_hat = model.decode(out)
        n = R_gt.shape[0]
        for key, value in model.loss(out, R_gt, T_gt).items():
            loss_sums[key] = loss_sums.get(key, 0.0) + float(value) * n
        count += n
        parts["index"].append(batch["index"].cpu())
        parts["R_hat"].append(R_hat.double().cpu())
        parts["R_gt"].append(R_gt.double().cpu())
        parts["T_hat"].append(T_hat.double().cpu())
        parts["T_gt"].append(T_gt.double().cpu())
        if with_log_prob:
            parts["log_likelihood"].append(head.log_prob(out.attitude, R_gt).double().cpu())
        if with_uncertainty:
            parts["uncertainty"].append(head.uncertainty(out.attitude).double().cpu())
        if beliefs is not None:
            parts["beliefs"].append(beliefs(head, out.attitude, R_hat).double().cpu())
    if count == 0:
        raise ValueError("predict: the dataset is empty")
    cat = {k: torch.cat(v) if v else None for k, v in parts.items()}
    return Predictions(
        index=cat["index"],
        R_hat=cat["R_hat"],
        R_gt=cat["R_gt"],
        T_hat=cat["T_hat"],
        T_gt=cat["T_gt"],
        log_likelihood=cat["log_likelihood"],
        uncertainty=cat["uncertainty"],
        loss={k: v / count for k, v in loss_sums.items()},
        beliefs=cat["beliefs"],
    )


def predictions_to_frame(
    pred: Predictions, extra: Mapping[str, Sequence[Any]] | None = None
) -> pd.DataFrame:
    return predictions_frame(
        pred.R_hat,
        pred.R_gt,
        pred.T_hat,
        pred.T_gt,
        index=pred.index,
        log_likelihood=pred.log_likelihood,
        uncertainty=pred.uncertainty,
        extra=extra,
    )


GROUP_COLUMNS = ("city", "centre", "flight")


def pair_columns(dataset: Dataset) -> dict[str, Sequence[Any]]:
    """``city``, ``centre``, ``flight`` and ``sat_index`` (the satellite image served) of each item
    of a ``PairDataset`` or a ``Subset`` of one, in item order; ``{}`` for any other dataset."""
    base, rows = dataset, None
    if isinstance(dataset, Subset):
        base, rows = dataset.dataset, list(dataset.indices)
    poses = getattr(base, "poses", None)
    if not isinstance(poses, pd.DataFrame) or not set(GROUP_COLUMNS) <= set(poses.columns):
        return {}
    picked = poses if rows is None else poses.iloc[rows]
    out: dict[str, Sequence[Any]] = {c: picked[c].tolist() for c in GROUP_COLUMNS}
    served = getattr(base, "served_sat_index", None)
    if served is not None:
        out["sat_index"] = [int(served[i]) for i in (range(len(poses)) if rows is None else rows)]
    return out


def evaluate(
    model: torch.nn.Module,
    dataset: Dataset,
    *,
    out_csv: str | Path | None = None,
    batch_size: int = 64,
    shared_satellite: bool = True,
    extra: Mapping[str, Sequence[Any]] | None = None,
    progress: bool = False,
    desc: str = "eval",
    precision: str = "fp32",
    num_workers: int = 0,
    beliefs: BeliefFn | None = None,
    out_beliefs: str | Path | None = None,
) -> tuple[dict[str, float], pd.DataFrame]:
    """Predict ``dataset``, write the per-sample CSV to ``out_csv`` (if given) and return
    ``(summary, frame)``: the :func:`~benchmark.evaluation.metrics.summarize` metrics (plus the
    mean losses as ``loss_<term>``) and the per-sample table. ``extra`` columns default to
    :func:`pair_columns` of the dataset. The model runs on its device in ``precision``
    (:func:`predict`). With ``beliefs`` (see :func:`predict`), the same pass records every
    frame's belief and saves it to ``out_beliefs`` (``.npy``, float64, rows in the order of the
    CSV), so that fusing the split along its flights needs no second pass of the model."""
    if (beliefs is None) != (out_beliefs is None):
        raise ValueError("evaluate: beliefs and out_beliefs go together")
    pred = predict(
        model,
        dataset,
        batch_size=batch_size,
        shared_satellite=shared_satellite,
        progress=progress,
        desc=desc,
        precision=precision,
        num_workers=num_workers,
        beliefs=beliefs,
    )
    if extra is None:
        extra = pair_columns(dataset)
    frame = predictions_to_frame(pred, extra)
    if out_beliefs is not None:
        assert pred.beliefs is not None
        save_beliefs(pred.beliefs.numpy(), out_beliefs)  # before the CSV: see _evaluate_split
    if out_csv is not None:
        write_predictions_csv(frame, out_csv)
    summary = summarize(frame)
    summary.update({f"loss_{k}": v for k, v in pred.loss.items()})
    return summary, frame


def save_beliefs(beliefs: np.ndarray, path: str | Path) -> None:
    """Write ``beliefs (N, ...)`` to ``path`` (``.npy``) whole or not at all (a temporary file
    replaced at the end: an interrupted run leaves no half-written belief behind)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with tmp.open("wb") as f:
        np.save(f, beliefs, allow_pickle=False)
    tmp.replace(path)


def load_beliefs(path: str | Path, rows: int) -> np.ndarray:
    """The beliefs :func:`save_beliefs` wrote, checked to hold ``rows`` frames."""
    beliefs = np.load(Path(path), allow_pickle=False)
    if beliefs.ndim < 2 or beliefs.shape[0] != rows:
        raise ValueError(
            f"{path}: expected beliefs of {rows} frames (rows, bins), got shape {beliefs.shape}"
        )
    return beliefs


def finite_keys(summary: Mapping[str, float]) -> list[str]:
    """Keys of an :func:`evaluate` summary that are finite for every model with finite outputs:
    mean and median errors, accuracies and loss terms. (``loglik`` may be -inf for a very sharp
    density, ``spearman_unc_err`` is NaN for a constant uncertainty: neither means divergence.)"""
    wanted = [*ERROR_COLUMNS, *(f"median_{c}" for c in ERROR_COLUMNS)]
    wanted += [f"acc{t:g}" for t in ACCURACY_THRESHOLDS_DEG]
    wanted += [k for k in summary if k.startswith("loss_")]
    return [k for k in wanted if k in summary]


def non_finite_metrics(summary: Mapping[str, float]) -> list[str]:
    """The :func:`finite_keys` of ``summary`` whose value is NaN or inf (a diverged model)."""
    return [k for k in finite_keys(summary) if not math.isfinite(float(summary[k]))]
