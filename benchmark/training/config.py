"""The train configuration: frozen dataclasses, one section per concern.

Defaults are the paper's settings (Sec. 3.3): SGD with momentum 0.9, learning rate 1e-3, batch 20;
vMF concentration kappa = 10 and distribution-loss weight alpha = 8e7 (the heads' own defaults);
auxiliary weights w1 = w2 = 0.3; the AGTFM encoder (``a-f``) at width 1.0. Override any field with
``--set section.field=value`` (:func:`benchmark.config.apply_overrides`), any head or encoder
option with ``--set model.attitude_options.kappa=5`` (``translation_options``,
``encoder_options``), or load a YAML file holding some of the fields (:func:`load_train_config`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar, Literal

from benchmark.config import ConfigError, apply_overrides, load_yaml
from benchmark.models.device import check_device_name, check_precision_name
from benchmark.models.model_config import ModelConfig


def _positive(value: float, name: str, *, allow_zero: bool = False) -> None:
    ok = math.isfinite(value) and (value >= 0 if allow_zero else value > 0)
    if not ok:
        op = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{name} must be a finite number {op}, got {value!r}")


@dataclass(frozen=True)
class DataConfig:
    """Which pairs to train on. ``root`` is a directory written by ``uavbench simulate``."""

    root: str = ""
    train_split: str = "standard/train"  # several joined by "+": one training set of all
    val_split: str | None = "standard/val"  # None: no validation pass
    limit_train: int | None = None  # first N training pairs only (smoke runs)
    limit_val: int | None = None
    num_workers: int = 0  # DataLoader worker processes (0: load in the training process)
    # dataset file check when opening: sha256 hashes each file once and caches the result by file
    # identity (benchmark.data.integrity), so later opens cost a stat; "size" is the cheap opt-out
    verify: Literal["sha256", "size", "full"] = "sha256"

    def __post_init__(self) -> None:
        for name in ("limit_train", "limit_val"):
            value = getattr(self, name)
            if value is not None and value < 1:
                raise ValueError(f"{name} must be >= 1 or None, got {value}")
        if self.num_workers < 0:
            raise ValueError(f"num_workers must be >= 0, got {self.num_workers}")


@dataclass(frozen=True)
class OptimConfig:
    """SGD with momentum by default (the paper's SGDM, Sec. 3.3). ``name="adam"``/``"adamw"``
    (``momentum`` unused, PyTorch's default betas) converge much faster in short CPU runs."""

    name: Literal["sgd", "adam", "adamw"] = "sgd"
    lr: float = 1e-3
    momentum: float = 0.9
    weight_decay: float = 0.0
    batch_size: int = 20
    epochs: int = 30
    grad_clip: float | None = None  # max global gradient norm; None: no clipping
    lr_schedule: Literal["constant", "cosine"] = "constant"

    def __post_init__(self) -> None:
        _positive(self.lr, "lr")
        _positive(self.momentum, "momentum", allow_zero=True)
        _positive(self.weight_decay, "weight_decay", allow_zero=True)
        if self.batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {self.batch_size}")
        if self.epochs < 1:
            raise ValueError(f"epochs must be >= 1, got {self.epochs}")
        if self.grad_clip is not None:
            _positive(self.grad_clip, "grad_clip")


@dataclass(frozen=True)
class PretrainedConfig:
    """Start from another run's encoder and keep it frozen: only the heads train.

    ``checkpoint`` is a ``checkpoint.pt`` (``uavbench train`` / a reproduce unit) whose model has
    the same encoder (name, options, input size); its ``encoder.*`` weights are loaded and never
    updated. The heads then train and evaluate on the encoder's features, computed once per split
    and satellite mode and cached beside the checkpoint (``benchmark.training.encoded``).
    ``key`` names those weights in the run's identity instead of the path (the runner sets the
    run key of the unit that trained them; empty: the checkpoint file's sha256, read when the run
    starts, :func:`benchmark.training.encoded.resolve_pretrained`)."""

    checkpoint: str = ""  # "": train the encoder (the default)
    key: str = ""

    @property
    def enabled(self) -> bool:
        return bool(self.checkpoint)


@dataclass(frozen=True)
class TrainConfig:
    """One training run: which data, which model (``benchmark.models.ModelConfig``, the same
    description ``create_model``, table specs and checkpoints use), how to optimise, which seed."""

    # Keys of the train config before issue 13, refused with where they live now.
    MOVED: ClassVar[dict[str, str]] = {
        "loss.kappa": "model.attitude_options.kappa",
        "loss.alpha": "model.attitude_options.alpha",
        "loss.aux_weight": "model.aux_weight",
    }

    data: DataConfig = field(default_factory=DataConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    seed: int = 0
    threads: int | None = None  # torch.set_num_threads; None leaves torch's default
    val_every: int = 1  # validate every N epochs (and always after the last); 0: never
    # Where and in what precision to train, validate and evaluate (benchmark.models.device):
    # "auto" = CUDA, else MPS, else CPU; or "cpu", "cuda", "cuda:N", "mps". Precision "fp32",
    # "bf16", "fp16" (autocast; fp16 with a gradient scaler) or "auto" (bf16 on CUDA with bf16
    # support, else fp32; always fp32 on a CPU). The device is not part of a run's identity,
    # fp32 is not either. Only the names are checked here, so a config stays valid on any
    # machine (a bf16 config planned on a laptop for a GPU); whether this machine runs it is
    # checked where it runs (models/device.py: check_precision_supported, bf16 on a CPU needs
    # avx512_bf16/amx_bf16 or UAVBENCH_ALLOW_SLOW_BF16=1).
    device: str = "auto"
    precision: str = "auto"
    pretrained: PretrainedConfig = field(default_factory=PretrainedConfig)

    def __post_init__(self) -> None:
        if self.seed < 0:
            raise ValueError(f"seed must be >= 0, got {self.seed}")
        if self.threads is not None and self.threads < 1:
            raise ValueError(f"threads must be >= 1 or None, got {self.threads}")
        if self.val_every < 0:
            raise ValueError(f"val_every must be >= 0, got {self.val_every}")
        check_device_name(self.device)
        check_precision_name(self.precision)


def load_train_config(path: str | Path | None = None, overrides: list[str] = ()) -> TrainConfig:
    """Defaults, then the YAML file (if any), then ``overrides`` (``["optim.lr=0.01", ...]``)."""
    cfg = TrainConfig() if path is None else load_yaml(path, TrainConfig)
    assert isinstance(cfg, TrainConfig)
    return apply_overrides(cfg, list(overrides))


__all__ = [
    "ConfigError",
    "DataConfig",
    "ModelConfig",
    "OptimConfig",
    "PretrainedConfig",
    "TrainConfig",
    "load_train_config",
]
