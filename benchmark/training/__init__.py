"""Training: the train config, the deterministic resumable loop, and model/dataset building.

``run_training(cfg, out_dir, on_epoch_end=...)`` is what a runner calls; this package never imports
``benchmark.tracking`` (connect a tracker through ``on_epoch_end``) except in ``command.py``, the
``uavbench train`` CLI. Checkpoints are read with ``benchmark.models.checkpoint`` (re-exported
here).
"""

from benchmark.models.checkpoint import load_checkpoint, load_trained_model
from benchmark.training.build import (
    image_size_of,
    model_factory,
    open_datasets,
    predictions_csv_path,
    run_training,
    train_and_evaluate,
)
from benchmark.training.config import (
    DataConfig,
    LossConfig,
    ModelSection,
    OptimConfig,
    TrainConfig,
    load_train_config,
)
from benchmark.training.loop import (
    CHECKPOINT,
    CheckpointMismatchError,
    NonFiniteLossError,
    TrainResult,
    derive_seed,
    make_optimizer,
    train,
    translation_labels,
)

__all__ = [
    "CHECKPOINT",
    "CheckpointMismatchError",
    "DataConfig",
    "LossConfig",
    "ModelSection",
    "NonFiniteLossError",
    "OptimConfig",
    "TrainConfig",
    "TrainResult",
    "derive_seed",
    "image_size_of",
    "load_checkpoint",
    "load_train_config",
    "load_trained_model",
    "make_optimizer",
    "model_factory",
    "open_datasets",
    "predictions_csv_path",
    "run_training",
    "train",
    "train_and_evaluate",
    "translation_labels",
]
