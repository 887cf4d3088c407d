"""From a ``TrainConfig`` to datasets and a model; from a checkpoint back to a model."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import torch
from torch.utils.data import Dataset, Subset

from benchmark.config import ConfigError
from benchmark.training.config import TrainConfig
from benchmark.training.loop import EpochCallback, TrainResult, train


def _limit(dataset: Dataset, limit: int | None) -> Dataset:
    if limit is None or limit >= len(dataset):
        return dataset
    return Subset(dataset, range(limit))


def open_datasets(cfg: TrainConfig) -> tuple[Dataset, Dataset | None]:
    """``(train, val)`` ``PairDataset``s of ``cfg.data`` (val None when ``val_split`` is None)."""
    from benchmark.data import PairDataset

    if not cfg.data.root:
        raise ConfigError("data.root: no dataset directory given (set data.root=DIR)")
    root = Path(cfg.data.root)
    if not root.is_dir():
        raise ConfigError(f"data.root={cfg.data.root!r}: no such directory")
    train_set = _limit(
        PairDataset(root, cfg.data.train_split, verify=cfg.data.verify), cfg.data.limit_train
    )
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
    """A zero-argument builder of the ``PoseModel`` of ``cfg`` (called after seeding)."""
    from benchmark.models import create_model

    m = cfg.model
    if m.input_size is not None and m.input_size != input_size:
        raise ConfigError(
            f"model.input_size={m.input_size} but the dataset images are {input_size} px; "
            "leave model.input_size unset to follow the dataset"
        )

    def build() -> torch.nn.Module:
        try:
            return create_model(
                encoder=m.encoder,
                variant=m.variant,
                width=m.width,
                input_size=input_size,
                attitude=m.attitude,
                translation=m.translation,
                attitude_kwargs=cfg.loss.attitude_kwargs(),
                aux_weight=cfg.loss.aux_weight,
                channels_last=m.channels_last,
                satellite_input=m.satellite_input,
            )
        except TypeError as err:  # an option the chosen head does not take (e.g. loss.kappa)
            raise ConfigError(
                f"model.attitude={m.attitude!r} does not accept the loss options "
                f"{cfg.loss.attitude_kwargs()}: {err}"
            ) from err

    return build


def run_training(
    cfg: TrainConfig,
    out_dir: str | Path,
    *,
    on_epoch_end: EpochCallback | None = None,
    progress: bool = True,
    datasets: tuple[Dataset, Dataset | None] | None = None,
) -> TrainResult:
    """Open the datasets (unless given), build the model and :func:`train` it into ``out_dir``."""
    train_set, val_set = datasets if datasets is not None else open_datasets(cfg)
    factory = model_factory(cfg, image_size_of(train_set))
    return train(
        cfg, factory, train_set, val_set, out_dir, on_epoch_end=on_epoch_end, progress=progress
    )


def predictions_csv_path(out_dir: str | Path, split: str) -> Path:
    """``<out_dir>/predictions/<split with / replaced by _>.csv``."""
    return Path(out_dir) / "predictions" / (split.replace("/", "_") + ".csv")


def train_and_evaluate(
    cfg: TrainConfig,
    out_dir: str | Path,
    eval_splits: list[str] | tuple[str, ...],
    *,
    on_epoch_end: EpochCallback | None = None,
    progress: bool = True,
    datasets: tuple[Dataset, Dataset | None] | None = None,
) -> tuple[TrainResult, dict[str, dict[str, float]]]:
    """Train (or resume, or reuse a finished checkpoint) into ``out_dir``, then evaluate every
    split of ``cfg.data.root`` in ``eval_splits``. Writes ``history.json`` and
    :func:`predictions_csv_path` per split; returns the result and ``{split: summary}``."""
    import json

    from benchmark.data import PairDataset
    from benchmark.evaluation.evaluate import evaluate

    result = run_training(
        cfg, out_dir, on_epoch_end=on_epoch_end, progress=progress, datasets=datasets
    )
    out_dir = Path(out_dir)
    (out_dir / "history.json").write_text(json.dumps(result.history, indent=1) + "\n")
    summaries = {}
    for split in eval_splits:
        summary, _ = evaluate(
            result.model,
            PairDataset(cfg.data.root, split, verify=cfg.data.verify),
            out_csv=predictions_csv_path(out_dir, split),
            batch_size=max(cfg.optim.batch_size, 32),
            shared_satellite=cfg.model.shared_satellite,
            progress=progress,
            desc=f"eval {split}",
        )
        summaries[split] = summary
    return result, summaries
