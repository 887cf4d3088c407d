"""The deterministic, resumable training loop.

Determinism: the model is initialised after ``torch.manual_seed(seed)``; epoch ``e`` shuffles with
its own generator seeded from ``(seed, e)`` and reseeds the global torch RNG from ``(seed, e)``
(dropout), so epoch ``e`` does the same work whether the process started at epoch 0 or resumed at
``e``. With the same config, seed and thread count the final weights are bit-identical.

Checkpoints: after every epoch ``<out>/checkpoint.pt`` is replaced atomically (temp file, fsync,
rename) with the model and optimiser states, RNG states, the epoch count, the per-epoch history and
the config (the final checkpoint omits the optimiser state, which nothing needs any more).
``train`` on an ``out`` holding a checkpoint of the same config resumes from it; the
history is replayed to ``on_epoch_end`` first, so a tracker attached to a resumed run still gets
every epoch.

Devices (``cfg.device``, ``cfg.precision``; ``benchmark.models.device``): the model is built and
initialised on the CPU, then moved; batches follow it; the forward pass runs under autocast for
bf16/fp16, the losses in float32; fp16 scales the loss (``GradScaler``, its state checkpointed).
On the CPU in fp32 nothing is moved or cast: the numbers are the ones from before devices.
Divergence (``benchmark.training.divergence``): a non-finite loss at any step, non-finite weights
or validation numbers after an epoch raise ``DivergenceError`` before that epoch's checkpoint.

Heads are used only through the contract (``PoseModel.loss`` / ``decode`` and, for the
translation statistics, ``TranslationHead.fit_statistics``). This module never imports tracking:
the caller passes ``on_epoch_end(epoch, metrics)``.
"""

from __future__ import annotations

import io
import math
import os
import random
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import ConcatDataset, DataLoader, Dataset, Subset

from benchmark.config import to_dict
from benchmark.evaluation.evaluate import forward_batch
from benchmark.models.checkpoint import CHECKPOINT_FORMAT, load_checkpoint
from benchmark.models.device import (
    Placement,
    autocast,
    grad_scaler,
    outputs_to_float,
    resolve_placement,
    to_device,
)
from benchmark.progress import Progress
from benchmark.training.config import TrainConfig
from benchmark.training.divergence import (
    DivergenceError,
    NonFiniteLossError,
    check_finite,
    non_finite_term,
    non_finite_weights,
)
from benchmark.training.encoded import encode_for_heads, load_pretrained_encoder
from benchmark.training.identity import numbers_hash

CHECKPOINT = "checkpoint.pt"
EpochCallback = Callable[[int, dict[str, float]], None]
__all__ = [  # the divergence checks are re-exported: benchmark.training.loop.DivergenceError
    "CHECKPOINT",
    "CheckpointMismatchError",
    "DivergenceError",
    "NonFiniteLossError",
    "TrainResult",
    "check_finite",
    "derive_seed",
    "epoch_permutation",
    "loader_workers",
    "make_optimizer",
    "non_finite_term",
    "non_finite_weights",
    "train",
    "translation_labels",
]


class CheckpointMismatchError(ValueError):
    """A checkpoint in the output directory belongs to a different config."""


@dataclass
class TrainResult:
    model: torch.nn.Module
    history: list[dict[str, float]]  # one dict per epoch (epoch numbers from 1)
    checkpoint: Path
    resumed_from_epoch: int  # 0 for a fresh run
    config_hash: str
    extra: dict[str, Any] = field(default_factory=dict)


def derive_seed(*parts: int) -> int:
    """A 63-bit seed from integers (a splitmix64-style mix; independent of PYTHONHASHSEED)."""
    x = 0x9E3779B97F4A7C15
    for p in parts:
        x = (x ^ (int(p) & 0xFFFFFFFFFFFFFFFF)) * 0xBF58476D1CE4E5B9 & 0xFFFFFFFFFFFFFFFF
        x ^= x >> 31
    return x & 0x7FFFFFFFFFFFFFFF


def epoch_permutation(n: int, seed: int, epoch: int) -> list[int]:
    g = torch.Generator().manual_seed(derive_seed(seed, epoch, 1))
    return torch.randperm(n, generator=g).tolist()


def translation_labels(dataset: Dataset) -> torch.Tensor:
    """``(N, 3)`` metres: all ``T`` labels of ``dataset`` without decoding images when possible
    (``PairDataset`` keeps its labels in ``poses``; a ``Subset`` of one is indexed)."""
    if isinstance(dataset, ConcatDataset):  # several training splits: their labels in order
        return torch.cat([translation_labels(part) for part in dataset.datasets])
    base, idx = dataset, None
    if isinstance(dataset, Subset):
        base, idx = dataset.dataset, list(dataset.indices)
    poses = getattr(base, "poses", None)
    if poses is not None and {"dE", "dN", "dU"} <= set(poses.columns):
        T = torch.from_numpy(poses[["dE", "dN", "dU"]].to_numpy(np.float64, copy=True))
        return T if idx is None else T[idx]
    return torch.stack(
        [torch.as_tensor(dataset[i]["T"], dtype=torch.float64) for i in range(len(dataset))]
    )


def _atomic_save(obj: Any, path: Path) -> None:
    """Replace ``path`` by ``obj`` atomically: serialised in memory first, then written to a
    temporary file beside it, fsynced and renamed. A full disk or a refused permission raises an
    ``OSError`` naming ``path`` (torch.save straight into a file would fail inside its zip writer
    with ``enforce fail at inline_container.cc`` and no path) and leaves the previous checkpoint
    as it was. The in-memory copy costs the checkpoint's size once more in RAM for a moment."""
    from benchmark.data import atomic_write_bytes

    buf = io.BytesIO()
    torch.save(obj, buf)
    atomic_write_bytes(path, buf.getbuffer())


def _rng_state() -> dict[str, Any]:
    return {
        "torch": torch.get_rng_state(),
        "numpy": np.random.get_state(),
        "python": random.getstate(),
    }


def _set_rng_state(state: dict[str, Any]) -> None:
    torch.set_rng_state(state["torch"])
    np.random.set_state(state["numpy"])
    random.setstate(state["python"])


# foreach per optimiser when every parameter is on the CPU. torch's CPU default loops over the
# tensors in Python; _foreach_* calls the same per-tensor ATen kernels with the same scalars from
# C++ (bit-identical weights). Measured on the quick model (issue 20, optimiser CPU time, 30
# alternating steps): Adam 82.5 -> 69.4 ms (about 10 ops per tensor), SGD 13.0 -> 15.6 ms (its
# three in-place passes then stream all 8 M weights three times instead of one cache-warm pass per
# tensor), so SGD keeps the loop. fused=True saves memory passes but rounds differently: not used.
CPU_FOREACH = {"sgd": False, "adam": True, "adamw": True}


def make_optimizer(
    cfg: TrainConfig, model: torch.nn.Module, *, foreach: bool | None = None
) -> torch.optim.Optimizer:
    """``cfg.optim``'s optimiser; ``foreach`` None: :data:`CPU_FOREACH` on the CPU, else torch's
    default (CUDA: foreach)."""
    params = [p for p in model.parameters() if p.requires_grad]
    o = cfg.optim
    if foreach is None and params and all(p.device.type == "cpu" for p in params):
        foreach = CPU_FOREACH.get(o.name)
    if o.name == "sgd":
        return torch.optim.SGD(params, lr=o.lr, momentum=o.momentum, weight_decay=o.weight_decay,
                               foreach=foreach)  # fmt: skip
    if o.name == "adam":
        return torch.optim.Adam(params, lr=o.lr, weight_decay=o.weight_decay, foreach=foreach)
    if o.name == "adamw":
        return torch.optim.AdamW(params, lr=o.lr, weight_decay=o.weight_decay, foreach=foreach)
    raise ValueError(f"optim.name={o.name!r}: expected 'sgd', 'adam' or 'adamw'")


def clip_groups(model: torch.nn.Module, per_head: bool) -> list[list[torch.Tensor]]:
    """The parameter groups whose gradient norms are clipped, each by its own norm.

    End to end (``per_head`` False) one group holds every trainable parameter: the heads share
    the encoder, and one norm is the paper's training. On a frozen encoder (``per_head`` True)
    the heads share nothing, so each top-level child of ``model`` (each element of a
    ``ModuleList``) is a group of its own: with one norm, a head with large gradients (an NLL)
    would shrink every other head's steps, and a row's attitude would depend on its translation
    loss (measured in DEVELOPERS.md, issue 21). Frozen parameters are in no group."""
    trainable = [p for p in model.parameters() if p.requires_grad]
    if not per_head:
        return [trainable] if trainable else []
    groups = []
    for child in model.children():
        for module in child if isinstance(child, torch.nn.ModuleList) else [child]:
            params = [p for p in module.parameters() if p.requires_grad]
            if params:
                groups.append(params)
    if sum(len(g) for g in groups) != len(trainable):  # a parameter held by the model itself
        raise ValueError("clip_groups: the model has trainable parameters outside its children")
    return groups


def _lr_at(cfg: TrainConfig, epoch: int) -> float:
    """Learning rate of (0-based) ``epoch``; cosine decays to 0 over ``optim.epochs``."""
    if cfg.optim.lr_schedule == "cosine":
        return cfg.optim.lr * 0.5 * (1 + math.cos(math.pi * epoch / cfg.optim.epochs))
    return cfg.optim.lr


def train(
    cfg: TrainConfig,
    model_factory: Callable[[], torch.nn.Module],
    train_set: Dataset,
    val_set: Dataset | None,
    out_dir: str | Path,
    *,
    on_epoch_end: EpochCallback | None = None,
    progress: bool = True,
    placement: Placement | None = None,
) -> TrainResult:
    """Train ``model_factory()`` (a ``PoseModel``) on ``train_set`` per ``cfg`` on ``placement``
    (``cfg.device``/``cfg.precision`` resolved and checked by the caller; None: here); resume if
    ``out_dir`` holds a checkpoint of the same config. Raises :class:`DivergenceError` if a
    training loss (any step), a weight or a validation number becomes non-finite (checked before
    the epoch's checkpoint is written: the last good checkpoint stays on disk)."""
    from benchmark.evaluation.evaluate import predict

    if cfg.threads is not None:
        torch.set_num_threads(cfg.threads)
    out_dir = Path(out_dir)
    ckpt_path = out_dir / CHECKPOINT
    # The device is not part of the hash (a checkpoint resumes anywhere), fp32 not either: the
    # hashes of checkpoints written before devices existed still match (identity.numbers_hash).
    if placement is None:  # bf16 needs native bf16 on a CPU (or the env)
        placement = resolve_placement(cfg.device, cfg.precision)
    device, precision = placement.device, placement.precision
    chash = numbers_hash(cfg, precision)
    torch.manual_seed(derive_seed(cfg.seed, 0))
    model = model_factory()  # built and initialised on the CPU: the same weights on any device
    if cfg.pretrained.enabled:  # a frozen encoder: only the heads train, on its features
        load_pretrained_encoder(model, cfg)
    model.translation_head.fit_statistics(translation_labels(train_set))
    model.to(device)  # the same module, in place (a no-op on the CPU)
    if cfg.pretrained.enabled:
        train_set = encode_for_heads(model, cfg, train_set, progress=progress, precision=precision)
        if val_set is not None:
            val_set = encode_for_heads(model, cfg, val_set, progress=progress, precision=precision)
    optimizer = make_optimizer(cfg, model)
    scaler = grad_scaler(device, precision)  # fp16 only; disabled otherwise
    history: list[dict[str, float]] = []
    start_epoch = 0
    if ckpt_path.exists():
        ckpt = load_checkpoint(ckpt_path)
        if ckpt["format"] != CHECKPOINT_FORMAT:
            raise CheckpointMismatchError(
                f"{ckpt_path} is a checkpoint of format {ckpt['format']} (before the one model "
                f"config of format {CHECKPOINT_FORMAT}); training cannot resume it: use another "
                "output directory or delete the checkpoint (uavbench evaluate still reads it)"
            )
        if ckpt["config_hash"] != chash:
            raise CheckpointMismatchError(
                f"{ckpt_path} was written by a different config (hash {ckpt['config_hash']}, "
                f"this run {chash}); use another output directory or delete the checkpoint"
            )
        model.load_state_dict(ckpt["model"])
        if ckpt["optimizer"] is not None:  # None in the final checkpoint of a finished run
            optimizer.load_state_dict(ckpt["optimizer"])  # moved to the parameters' device
        if ckpt.get("scaler"):
            scaler.load_state_dict(ckpt["scaler"])
        _set_rng_state(ckpt["rng"])
        history = list(ckpt["history"])
        start_epoch = int(ckpt["epoch"])
    if on_epoch_end is not None:
        for record in history:  # replay: a resumed run reports every epoch
            on_epoch_end(int(record["epoch"]), dict(record))

    n = len(train_set)
    steps_per_epoch = math.ceil(n / cfg.optim.batch_size)
    epochs = cfg.optim.epochs
    with Progress(
        epochs * steps_per_epoch,
        f"train seed {cfg.seed}",
        unit="batch",
        initial=start_epoch * steps_per_epoch,
        enabled=progress,
    ) as bar:
        for epoch in range(start_epoch, epochs):
            record = _train_one_epoch(
                cfg, model, optimizer, train_set, epoch, bar, (device, precision, scaler)
            )
            last = epoch + 1 == epochs
            lr = float(record["lr"])
            # The last step's update is checked by no later loss: look at the weights (one pass)
            # and the validation numbers before this epoch's checkpoint may replace the last one.
            bad = non_finite_weights(model)
            if bad:
                where = f"the end of epoch {epoch + 1} ({len(bad)} tensors)"
                raise DivergenceError("weights", where, bad[0], {bad[0]: math.nan}, lr)
            if val_set is not None and cfg.val_every and ((epoch + 1) % cfg.val_every == 0 or last):
                pred = predict(
                    model,
                    val_set,
                    batch_size=max(cfg.optim.batch_size, 32),
                    shared_satellite=cfg.model.shared_satellite,
                    precision=precision,
                    num_workers=loader_workers(cfg, device),
                )
                val = _val_metrics(pred)
                check_finite("validation loss or metric", f"validation after epoch {epoch + 1}",
                             val, lr)  # fmt: skip
                record.update(val)
            history.append(record)
            _atomic_save(
                {
                    "format": CHECKPOINT_FORMAT,
                    "config": to_dict(cfg),
                    "config_hash": chash,
                    "model_config": _model_config_dict(model),
                    "epoch": epoch + 1,
                    "model": model.state_dict(),
                    # The last epoch's optimizer state is never needed again; dropping it
                    # makes a finished run's checkpoint 2-3x smaller (momentum / Adam moments).
                    "optimizer": None if last else optimizer.state_dict(),
                    "rng": _rng_state(),
                    "history": history,
                    "scaler": scaler.state_dict() if scaler.is_enabled() and not last else None,
                },
                ckpt_path,
            )
            if on_epoch_end is not None:
                on_epoch_end(epoch + 1, dict(record))
    return TrainResult(model, history, ckpt_path, start_epoch, chash)


def _model_config_dict(model: torch.nn.Module) -> dict[str, Any] | None:
    config = getattr(model, "config", None)
    return config.to_dict() if config is not None and hasattr(config, "to_dict") else None


def loader_workers(cfg: TrainConfig, device: torch.device) -> int:
    """DataLoader worker processes: ``data.num_workers``; on an accelerator 0 means
    ``min(4, CPUs - 1)``, so decoding the next batches overlaps the device's step (the items and
    their order do not depend on the workers: same numbers)."""
    if cfg.data.num_workers or device.type == "cpu":
        return cfg.data.num_workers
    return max(0, min(4, (os.cpu_count() or 1) - 1))


def _train_one_epoch(
    cfg: TrainConfig,
    model: torch.nn.Module,
    optimizer: torch.optim.Optimizer,
    train_set: Dataset,
    epoch: int,
    bar: Progress,
    where: tuple[torch.device, str, torch.amp.GradScaler],
) -> dict[str, float]:
    """One epoch. ``where`` = (device, resolved precision, grad scaler). The forward pass runs
    under autocast (bf16/fp16), the losses in float32 on its outputs cast back to float32."""
    device, precision, scaler = where
    torch.manual_seed(derive_seed(cfg.seed, epoch, 2))  # dropout etc.: a function of (seed, epoch)
    lr = _lr_at(cfg, epoch)
    for group in optimizer.param_groups:
        group["lr"] = lr
    loader = DataLoader(
        train_set,
        batch_size=cfg.optim.batch_size,
        sampler=epoch_permutation(len(train_set), cfg.seed, epoch),
        num_workers=loader_workers(cfg, device),
        pin_memory=device.type == "cuda",
        generator=torch.Generator().manual_seed(derive_seed(cfg.seed, epoch, 3)),
    )
    model.train()
    groups = clip_groups(model, per_head=cfg.pretrained.enabled)
    sums: dict[str, float] = {}
    count, start = 0, time.perf_counter()
    for step, batch in enumerate(loader):
        batch = to_device(batch, device)  # the same dict on the CPU
        with autocast(device, precision):
            out = forward_batch(model, batch, cfg.model.shared_satellite)
        if precision != "fp32":
            out = outputs_to_float(out)
        losses = model.loss(out, batch["R"], batch["T"])
        total = losses["total"]
        # One isfinite on the scalar already computed, before backward: a single-element
        # kernel (microseconds); the float() of every term below syncs an accelerator anyway.
        if not bool(torch.isfinite(total)):
            values = {k: float(v.detach()) for k, v in losses.items()}
            check_finite("training loss", f"epoch {epoch + 1}, step {step + 1}", values, lr)
        optimizer.zero_grad(set_to_none=True)
        # fp16: a scaled loss, gradients unscaled before clipping, a step with inf gradients
        # skipped. A disabled scaler (fp32, bf16) passes through: scale() returns the loss,
        # unscale_() and update() do nothing, step() is optimizer.step().
        scaler.scale(total).backward()
        if cfg.optim.grad_clip is not None:
            scaler.unscale_(optimizer)
            for group in groups:
                torch.nn.utils.clip_grad_norm_(group, cfg.optim.grad_clip)
        scaler.step(optimizer)
        scaler.update()
        b = batch["R"].shape[0]
        for key, value in losses.items():
            sums[key] = sums.get(key, 0.0) + float(value.detach()) * b
        count += b
        bar.update(1, postfix=f"epoch {epoch + 1} loss {float(total.detach()):.4g}")
    elapsed = time.perf_counter() - start
    record = {f"train_loss_{k}": v / count for k, v in sums.items()}
    record.update(
        {
            "epoch": float(epoch + 1),
            "lr": lr,
            "epoch_time_s": elapsed,
            "pairs_per_s": count / elapsed,
        }
    )
    return record


def _val_metrics(pred: Any) -> dict[str, float]:
    from benchmark.geometry import geodesic_distance

    err_deg = torch.rad2deg(geodesic_distance(pred.R_hat, pred.R_gt))
    trans = (pred.T_hat - pred.T_gt).abs().mean(0)
    out = {f"val_loss_{k}": v for k, v in pred.loss.items()}
    out.update(
        {
            "val_dphi_deg": float(err_deg.mean()),
            "val_median_dphi_deg": float(err_deg.median()),
            "val_dE_m": float(trans[0]),
            "val_dN_m": float(trans[1]),
            "val_dU_m": float(trans[2]),
        }
    )
    return out
