"""Heads on a frozen pretrained encoder (``TrainConfig.pretrained``): load it, encode each split
once, train and evaluate the heads on the cached features.

Why: a pair encoder such as the matching encoder costs seconds per batch on a CPU core while
the heads on its ``F`` features cost microseconds. With the encoder frozen, its features of a
split do not depend on the head, the seed of the head's training or the epoch, so each
(encoder weights, split, satellite mode, satellite input) is encoded once and every head that
sits on the encoder reads the same file. The quick reproduction trains one encoder per seed and
fourteen heads on it this way (``benchmark.runner.plan.repro_profiles.SharedEncoder``).

Numerics: the features are computed in eval mode (the matching encoder then builds its
bird's-eye view from the protocol's test-time inputs, so the heads train on what they are
tested on), in float32, in batches of :data:`ENCODE_BATCH` (the per-pair features do not depend
on the batch: per-sample GroupNorm, per-pair correlation). A head trained on cached features
and the same model run end to end on images give the same predictions to float32 rounding.

Cache: ``<checkpoint dir>/encodings/<options>/<split>[__swap][__blank][__firstN].pt`` (``options``:
8 hex digits of the encoder's options, e.g. the matching protocol) holding the features
``(N, F)``, the labels and the identity of what produced them (the checkpoint file's sha256, the
dataset manifest's sha256, the encoder options); a file whose identity differs is recomputed and
replaced (atomic write), so a retrained encoder or another dataset never reads stale features.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch
from torch.utils.data import DataLoader, Dataset, Subset

from benchmark.config import ConfigError
from benchmark.data.dataset import R_COLUMNS
from benchmark.models.checkpoint import load_checkpoint
from benchmark.progress import Progress
from benchmark.training.config import TrainConfig

__all__ = [
    "ENCODE_BATCH",
    "EncodedPairs",
    "encode_dataset",
    "file_sha256",
    "load_pretrained_encoder",
    "resolve_pretrained",
    "weight_options",
]

ENCODE_BATCH = 32  # pairs per encoder batch when filling the cache
_ENCODER_FIELDS = ("encoder", "encoder_options", "variant", "width", "input_size")


def file_sha256(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _checkpoint_path(cfg: TrainConfig) -> Path:
    path = Path(cfg.pretrained.checkpoint)
    if not path.is_file():
        raise ConfigError(
            f"pretrained.checkpoint={cfg.pretrained.checkpoint!r}: no such file (a checkpoint.pt "
            "written by `uavbench train` or a reproduce unit whose encoder the heads sit on)"
        )
    return path


def resolve_pretrained(cfg: TrainConfig) -> TrainConfig:
    """``cfg`` with ``pretrained.key`` filled (the checkpoint's sha256, 16 hex digits) when a
    checkpoint is given without a key; unchanged otherwise. Raises ConfigError for a missing
    file."""
    if not cfg.pretrained.enabled or cfg.pretrained.key:
        return cfg
    key = file_sha256(_checkpoint_path(cfg))[:16]
    return dataclasses.replace(cfg, pretrained=dataclasses.replace(cfg.pretrained, key=key))


def weight_options(options: Mapping[str, Any]) -> dict[str, Any]:
    """The encoder options that shape its trained weights: all but the matching encoder's
    ``protocol``, which only chooses its test-time inputs (both protocols train the matcher on
    the sensor priors and the gravity branch on the truth), so one trained encoder serves both."""
    return {k: v for k, v in options.items() if k != "protocol"}


def load_pretrained_encoder(model: torch.nn.Module, cfg: TrainConfig) -> None:
    """Load the ``encoder.*`` weights of ``cfg.pretrained.checkpoint`` into ``model.encoder``
    and freeze them (``requires_grad`` off: the optimiser never sees them). The checkpoint's
    model must have the same encoder (name, options but the matching encoder's ``protocol``,
    variant, width, input size): a mismatch is a ConfigError naming the field and both values.
    (The checkpoint's identity is in the unit's key: ``TrainConfig.pretrained``.)"""
    path = _checkpoint_path(cfg)
    if not getattr(model, "pair_encoder", False):
        raise ConfigError(
            f"pretrained.checkpoint={str(path)!r}: frozen encoders are for pair encoders (the "
            f"matching encoder); model.encoder={model.config.encoder!r} trains end to end"
        )
    ckpt = load_checkpoint(path)
    theirs = dict(ckpt.get("model_config") or {})
    ours = model.config.to_dict()
    # A gravity-aided head may sit on a vision-only encoder and vice versa (weight_options).
    for config in (theirs, ours):
        config["encoder_options"] = weight_options(config.get("encoder_options") or {})
    for name in _ENCODER_FIELDS:
        if theirs.get(name) != ours.get(name):
            raise ConfigError(
                f"pretrained.checkpoint={str(path)!r}: its model has {name}="
                f"{theirs.get(name)!r}, this run's model.{name}={ours.get(name)!r}; the frozen "
                "encoder must be the one the checkpoint trained"
            )
    prefix = "encoder."
    state = {k[len(prefix) :]: v for k, v in ckpt["model"].items() if k.startswith(prefix)}
    model.encoder.load_state_dict(state)
    model.encoder.requires_grad_(False)


class EncodedPairs(Dataset):
    """A split as a frozen encoder sees it: items ``features (F,)``, ``R (3, 3)``, ``T (3,)``,
    ``index`` (the item's row in the split). ``poses`` and ``served_sat_index`` are the base
    dataset's rows (the per-frame columns of ``benchmark.evaluation.evaluate.pair_columns`` and
    the translation statistics of ``benchmark.training.loop.translation_labels``)."""

    def __init__(
        self,
        features: torch.Tensor,
        R: torch.Tensor,
        T: torch.Tensor,
        index: torch.Tensor,
        poses: pd.DataFrame | None = None,
        served_sat_index: np.ndarray | None = None,
    ) -> None:
        n = features.shape[0]
        if not (R.shape == (n, 3, 3) and T.shape == (n, 3) and index.shape == (n,)):
            raise ValueError(
                f"EncodedPairs: features {tuple(features.shape)}, R {tuple(R.shape)}, "
                f"T {tuple(T.shape)}, index {tuple(index.shape)} do not describe {n} items"
            )
        self.features, self.R, self.T, self.index = features, R, T, index
        self.poses = poses
        self.served_sat_index = served_sat_index

    def __len__(self) -> int:
        return int(self.features.shape[0])

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        return {"features": self.features[i], "R": self.R[i], "T": self.T[i],
                "index": self.index[i]}  # fmt: skip


def _base(dataset: Dataset) -> tuple[Any, list[int] | None]:
    if isinstance(dataset, Subset):
        return dataset.dataset, list(dataset.indices)
    return dataset, None


def _cache_name(dataset: Dataset, satellite_input: str) -> str:
    base, rows = _base(dataset)
    split = getattr(base, "split", None)
    if split is None:
        raise ValueError("encode_dataset: needs a PairDataset (or a Subset of one) to name its "
                         f"cache, got {type(base).__name__}")  # fmt: skip
    name = split.replace("/", "__")
    if getattr(base, "satellite", "true") != "true":
        name += f"__{base.satellite}"
    if satellite_input != "image":
        name += f"__{satellite_input}"
    if rows is not None:
        if rows != list(range(len(rows))):
            raise ValueError("encode_dataset: a Subset must be the first N items of a split")
        name += f"__first{len(rows)}"
    return name


def _read_cache(path: Path, identity: dict[str, str], n: int) -> dict[str, Any] | None:
    if not path.is_file():
        return None
    try:
        cached = torch.load(path, weights_only=True)
    except (OSError, RuntimeError, EOFError):  # a torn or foreign file: compute again
        return None
    if cached.get("identity") != identity or cached["features"].shape[0] != n:
        return None
    return cached


def _write_cache(
    model: torch.nn.Module,
    dataset: Dataset,
    poses: pd.DataFrame,
    path: Path,
    identity: dict[str, str],
    name: str,
    progress: bool,
    precision: str = "fp32",
) -> dict[str, Any]:
    from benchmark.data import atomic_write_bytes

    features = _encode(model, dataset, f"encode {name}", progress, precision)
    # Labels from the split's table (the items' own float32 values), not from the images.
    R = torch.from_numpy(poses[R_COLUMNS].to_numpy(np.float32).reshape(-1, 3, 3).copy())
    T = torch.from_numpy(poses[["dE", "dN", "dU"]].to_numpy(np.float32).copy())
    index = torch.arange(len(dataset), dtype=torch.int64)
    cached = {"identity": dict(identity), "features": features, "R": R, "T": T, "index": index}
    buf = io.BytesIO()
    torch.save(cached, buf)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, buf.getbuffer())
    return cached


@torch.no_grad()
def _encode(
    model: torch.nn.Module, dataset: Dataset, desc: str, progress: bool, precision: str = "fp32"
) -> torch.Tensor:
    """``(N, F)`` float32 features of ``dataset`` in eval mode, computed under ``precision``'s
    autocast (a bf16 unit's frozen encoder computes in bf16, as its training did)."""
    from benchmark.models.device import autocast

    weight = next(iter(model.parameters()))
    loader = DataLoader(dataset, batch_size=ENCODE_BATCH, shuffle=False)
    was_training = model.training
    model.eval()
    parts = []
    try:
        with Progress(len(loader), desc, unit="batch", enabled=progress) as bar:
            for batch in loader:
                ctx = batch.get("context")
                if ctx is not None:
                    ctx = {k: v.to(weight.device) for k, v in ctx.items()}
                with autocast(weight.device, precision):
                    enc = model.encode_pairs(
                        batch["uav"].to(weight.device),
                        batch["sat"].to(weight.device),
                        batch["sat_id"].to(weight.device) if model.shared_satellite else None,
                        ctx,
                    )
                parts.append(enc.features.float().cpu())
                bar.update(1)
    finally:
        model.train(was_training)
    return torch.cat(parts)


def encode_dataset(
    model: torch.nn.Module,
    dataset: Dataset,
    cache_dir: str | Path,
    identity: dict[str, str],
    *,
    progress: bool = False,
    precision: str = "fp32",
) -> EncodedPairs:
    """``dataset`` (a ``PairDataset`` or its first N items) through ``model``'s frozen encoder,
    read from ``cache_dir`` when a file with the same ``identity`` (checkpoint and dataset
    digests) exists, else computed and written there atomically."""
    from benchmark.locks import work_lock

    base, rows = _base(dataset)
    name = _cache_name(dataset, model.satellite_input)
    path = Path(cache_dir) / f"{name}.pt"
    poses = base.poses if rows is None else base.poses.iloc[rows].reset_index(drop=True)
    cached = _read_cache(path, identity, len(dataset))
    if cached is None:
        # Units of one seed start together and need the same splits: the first encodes, the
        # others wait for its file instead of encoding it again.
        with work_lock(path.with_suffix(".lock"), what=f"encode {name}", wait=True):
            cached = _read_cache(path, identity, len(dataset))
            if cached is None:
                cached = _write_cache(
                    model, dataset, poses, path, identity, name, progress, precision
                )
    served = getattr(base, "served_sat_index", None)
    if served is not None and rows is not None:
        served = served[rows]
    return EncodedPairs(cached["features"], cached["R"], cached["T"], cached["index"], poses,
                        served)  # fmt: skip


def encode_for_heads(
    model: torch.nn.Module,
    cfg: TrainConfig,
    dataset: Dataset,
    *,
    progress: bool = False,
    precision: str = "fp32",
) -> EncodedPairs:
    """``dataset`` as the heads of ``model`` see it when ``cfg.pretrained`` freezes its encoder
    (already loaded by :func:`load_pretrained_encoder`): cached under
    ``<checkpoint dir>/encodings``, keyed by the checkpoint's and the dataset manifest's
    sha256 and, other than fp32, the ``precision`` (resolved) the encoder computes in."""
    checkpoint = _checkpoint_path(cfg)
    base, _ = _base(dataset)
    # The encoder's options (the matching protocol) change the features of the same weights.
    options = json.dumps(model.config.encoder_options, sort_keys=True)
    identity = {
        "checkpoint_sha256": file_sha256(checkpoint),
        "manifest_sha256": file_sha256(Path(base.root) / "manifest.json"),
        "encoder_options": options,
    }
    tag = hashlib.sha256(options.encode()).hexdigest()[:8]
    if precision != "fp32":  # fp32 caches keep their identity and place from before precisions;
        identity["precision"] = precision  # another precision's cache sits beside them
        tag += f"-{precision}"
    return encode_dataset(model, dataset, checkpoint.parent / "encodings" / tag, identity,
                          progress=progress, precision=precision)  # fmt: skip
