"""From a ``TrainConfig`` to datasets and a model, and :func:`run_training` (no evaluation; the
train-then-evaluate path of ``uavbench train`` and ``uavbench reproduce`` is
``benchmark.training.pipeline``)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import torch
from torch.utils.data import ConcatDataset, Dataset, Subset

from benchmark.config import ConfigError
from benchmark.models.device import Placement
from benchmark.training.config import TrainConfig
from benchmark.training.loop import EpochCallback, TrainResult, train


def _limit(dataset: Dataset, limit: int | None) -> Dataset:
    if limit is None or limit >= len(dataset):
        return dataset
    return Subset(dataset, range(limit))


def train_splits(cfg: TrainConfig) -> list[str]:
    """The splits ``data.train_split`` names: one, or several joined by ``+``
    (``standard/train+towns/train``: their pairs in that order, one training set)."""
    return cfg.data.train_split.split("+")


def open_datasets(cfg: TrainConfig) -> tuple[Dataset, Dataset | None]:
    """``(train, val)`` ``PairDataset``s of ``cfg.data`` (val None when ``val_split`` is None)."""
    from benchmark.data import PairDataset

    if not cfg.data.root:
        raise ConfigError("data.root: no dataset directory given (set data.root=DIR)")
    root = Path(cfg.data.root)
    if not root.is_dir():
        raise ConfigError(f"data.root={cfg.data.root!r}: no such directory")
    parts = [PairDataset(root, s, verify=cfg.data.verify) for s in train_splits(cfg)]
    train_set = _limit(parts[0] if len(parts) == 1 else ConcatDataset(parts), cfg.data.limit_train)
    val_set = None
    if cfg.data.val_split is not None:
        val_set = _limit(
            PairDataset(root, cfg.data.val_split, verify=cfg.data.verify), cfg.data.limit_val
        )
    if len(train_set) == 0:
        raise ConfigError(
            f"data.train_split={cfg.data.train_split!r}: the split is empty in {root}"
        )
    return train_set, val_set


def image_size_of(dataset: Dataset) -> int:
    """Side of the (square) UAV images of ``dataset``, from its first item."""
    h, w = dataset[0]["uav"].shape[-2:]
    if h != w:
        raise ValueError(f"images must be square, got {h} x {w}")
    return int(h)


def model_factory(cfg: TrainConfig, input_size: int) -> Callable[[], torch.nn.Module]:
    """A zero-argument builder of the ``PoseModel`` of ``cfg.model`` at the dataset's
    ``input_size`` (px), called after seeding. A ``model.input_size`` that differs from the
    dataset's, or an option value the head refuses (e.g. ``kappa=0``), is a ConfigError."""
    from benchmark.models import build_model

    try:
        resolved = cfg.model.resolved(input_size)
    except ValueError as err:
        raise ConfigError(f"model.{err}") from None

    def build() -> torch.nn.Module:
        try:
            return build_model(resolved)
        except (TypeError, ValueError) as err:  # a head or encoder refusing an option's value
            raise ConfigError(f"model: {err}") from err

    return build


def run_training(
    cfg: TrainConfig,
    out_dir: str | Path,
    *,
    on_epoch_end: EpochCallback | None = None,
    progress: bool = True,
    datasets: tuple[Dataset, Dataset | None] | None = None,
    placement: Placement | None = None,
) -> TrainResult:
    """Open the datasets (unless given), build the model and :func:`train` it into ``out_dir``
    on ``placement`` (None: resolved from ``cfg``)."""
    train_set, val_set = datasets if datasets is not None else open_datasets(cfg)
    factory = model_factory(cfg, image_size_of(train_set))
    return train(
        cfg,
        factory,
        train_set,
        val_set,
        out_dir,
        on_epoch_end=on_epoch_end,
        progress=progress,
        placement=placement,
    )
