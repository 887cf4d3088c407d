"""Reading a trained model back from a checkpoint file.

The file is written by ``benchmark.training`` (one per epoch); it holds the model's weights and its
``ModelConfig`` (``model_config``), so a ``PoseModel`` can be rebuilt without the train config. It
lives here, not in training, so that evaluation can load a model without importing the trainer.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

CHECKPOINT_FORMAT = 1  # bump when the checkpoint's keys change


def load_checkpoint(path: str | Path) -> dict[str, Any]:
    """The checkpoint dict at ``path``; a truncated or foreign file raises ValueError naming it."""
    path = Path(path)
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as err:  # truncated / foreign file: say which file
        raise ValueError(f"cannot read checkpoint {path}: {err}") from err
    if not isinstance(ckpt, dict) or ckpt.get("format") != CHECKPOINT_FORMAT:
        raise ValueError(f"{path} is not a uavbench checkpoint (format {CHECKPOINT_FORMAT})")
    return ckpt


def load_trained_model(checkpoint: str | Path) -> torch.nn.Module:
    """Rebuild the ``PoseModel`` saved in a checkpoint (eval mode)."""
    from benchmark.models.pair import ModelConfig, build_model

    ckpt = load_checkpoint(checkpoint)
    if ckpt.get("model_config") is None:
        raise ValueError(f"{checkpoint} holds no model config; cannot rebuild the model")
    model = build_model(ModelConfig(**ckpt["model_config"]))
    model.load_state_dict(ckpt["model"])
    return model.eval()
