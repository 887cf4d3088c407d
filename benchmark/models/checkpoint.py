"""Reading a trained model back from a checkpoint file.

The file is written by ``benchmark.training`` (one per epoch); it holds the model's weights and its
``ModelConfig`` (``model_config``, :meth:`ModelConfig.to_dict`), so a ``PoseModel`` can be rebuilt
without the train config. It lives here, not in training, so that evaluation can load a model
without importing the trainer.

Formats: 2 (issue 13: one ``ModelConfig`` with ``attitude_options`` etc.) is written. Format 1
(``attitude_kwargs`` ..., before issue 13) still loads for evaluation: its model config is read
with the old field names and the weights are unchanged. Training does not resume a format-1
checkpoint: the train config changed shape, so its hash differs and the loop refuses it, naming
the file.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

CHECKPOINT_FORMAT = 2  # bump when the checkpoint's keys change
READABLE_FORMATS = (1, 2)  # 1: model config with *_kwargs field names (read by ModelConfig)


def load_checkpoint(path: str | Path, map_location: str | torch.device = "cpu") -> dict[str, Any]:
    """The checkpoint dict at ``path``, its tensors on ``map_location`` (the CPU by default:
    a checkpoint written on a GPU loads on a machine without one); a truncated or foreign file
    raises ValueError naming it."""
    path = Path(path)
    try:
        ckpt = torch.load(path, map_location=map_location, weights_only=False)
    except Exception as err:  # truncated / foreign file: say which file
        raise ValueError(f"cannot read checkpoint {path}: {err}") from err
    if not isinstance(ckpt, dict) or ckpt.get("format") not in READABLE_FORMATS:
        found = ckpt.get("format") if isinstance(ckpt, dict) else None
        raise ValueError(
            f"{path} is not a uavbench checkpoint this version reads (format {found!r}; readable: "
            f"{', '.join(map(str, READABLE_FORMATS))}); retrain it with uavbench train"
        )
    return ckpt


def load_trained_model(
    checkpoint: str | Path, device: str | torch.device | None = None
) -> torch.nn.Module:
    """Rebuild the ``PoseModel`` saved in a checkpoint (eval mode), on ``device`` (default the
    CPU). The weights are read onto the CPU whatever device wrote them, then moved."""
    from benchmark.models.pair import ModelConfig, build_model

    ckpt = load_checkpoint(checkpoint)
    if ckpt.get("model_config") is None:
        raise ValueError(f"{checkpoint} holds no model config; cannot rebuild the model")
    try:
        config = ModelConfig.from_dict(ckpt["model_config"], where=str(checkpoint))
    except (TypeError, ValueError) as err:
        raise ValueError(
            f"{checkpoint}: its model config cannot be rebuilt by this version ({err}); "
            "retrain it with uavbench train"
        ) from err
    model = build_model(config)
    model.load_state_dict(ckpt["model"])
    if device is not None:
        model.to(device)
    return model.eval()
