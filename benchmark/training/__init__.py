"""Training: the train config, the deterministic resumable loop, model/dataset building, the one
train-then-evaluate path and the run identity.

``train_and_evaluate(cfg, out_dir, eval_splits)`` is what ``uavbench train`` and every
``uavbench reproduce`` unit call; ``run_key`` / ``run_tags`` identify its trained model the same
way for both. This package never imports ``benchmark.tracking`` (connect a tracker through
``on_epoch_end``) except in ``tracked_run.py``, what ``uavbench train`` runs. Checkpoints are
read with ``benchmark.models.checkpoint`` (re-exported here).
"""

from benchmark.models.checkpoint import load_checkpoint, load_trained_model
from benchmark.training.build import image_size_of, model_factory, open_datasets, run_training
from benchmark.training.config import (
    DataConfig,
    ModelConfig,
    OptimConfig,
    TrainConfig,
    load_train_config,
)
from benchmark.training.identity import (
    MODEL_KEY_TAG,
    device_tags,
    model_tags,
    numbers_hash,
    portable_config,
    run_key,
    run_tags,
)
from benchmark.training.loop import (
    CHECKPOINT,
    CheckpointMismatchError,
    DivergenceError,
    NonFiniteLossError,
    TrainResult,
    derive_seed,
    make_optimizer,
    train,
    translation_labels,
)
from benchmark.training.pipeline import (
    TrainEvalResult,
    eval_key,
    eval_keys,
    split_filename,
    train_and_evaluate,
)

__all__ = [
    "CHECKPOINT",
    "MODEL_KEY_TAG",
    "CheckpointMismatchError",
    "DataConfig",
    "DivergenceError",
    "ModelConfig",
    "NonFiniteLossError",
    "OptimConfig",
    "TrainConfig",
    "TrainEvalResult",
    "TrainResult",
    "derive_seed",
    "device_tags",
    "eval_key",
    "eval_keys",
    "image_size_of",
    "load_checkpoint",
    "load_train_config",
    "load_trained_model",
    "make_optimizer",
    "model_factory",
    "model_tags",
    "numbers_hash",
    "open_datasets",
    "portable_config",
    "run_key",
    "run_tags",
    "run_training",
    "split_filename",
    "train",
    "train_and_evaluate",
    "translation_labels",
]
