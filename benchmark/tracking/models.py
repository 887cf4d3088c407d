"""Trained models in MLflow's pytorch flavor: a servable wrapper and the save/log calls.

MLflow's pytorch flavor serves a module that takes ONE float32 tensor and returns one tensor
(``mlflow.pytorch._PyTorchWrapper.predict``). A pose model takes two images, so
:class:`PosePredictor` packs them into one input and its outputs into one tensor:

- input ``(B, 6, H, W)`` float32 in [0, 1]: channels 0-2 the UAV image, 3-5 the satellite image
  (both RGB, the same size, as ``PairDataset`` gives them);
- output ``(B, 12)`` float32: ``R_uav^sat`` row-major (9 numbers), then ``T = [dE, dN, dU]`` in
  metres, the model's own ``decode``.

The wrapper changes no number: it calls the model's ``forward`` (without the shared-satellite
index) and ``decode``, as the evaluation does. Loading back needs this package importable (the
module is pickled, as ``mlflow.pytorch.save_model`` does by default). mlflow and torch are imported
only when a model is saved or logged.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import torch
from torch import nn

UAV_CHANNELS = 3  # input channels 0..2: the UAV image; 3..5: the satellite image


class PosePredictor(nn.Module):
    """``(B, 6, H, W) -> (B, 12)``: a pose model (``forward(uav, sat)`` and ``decode``) behind
    one input and one output tensor (see the module docstring)."""

    def __init__(self, model: nn.Module) -> None:
        super().__init__()
        self.model = model

    def forward(self, pair: torch.Tensor) -> torch.Tensor:
        if pair.ndim != 4 or pair.shape[1] != 2 * UAV_CHANNELS:
            raise ValueError(
                f"PosePredictor input must be (B, 6, H, W) (UAV RGB then satellite RGB), got "
                f"{tuple(pair.shape)}"
            )
        uav, sat = pair[:, :UAV_CHANNELS], pair[:, UAV_CHANNELS:]
        R, T = self.model.decode(self.model(uav, sat, None))
        return torch.cat([R.reshape(R.shape[0], 9), T], dim=1).to(torch.float32)


def pack_pair(uav: torch.Tensor, sat: torch.Tensor) -> torch.Tensor:
    """``(B, 3, H, W)`` UAV and satellite images -> the ``(B, 6, H, W)`` predictor input."""
    if uav.shape != sat.shape:
        raise ValueError(
            f"UAV images {tuple(uav.shape)} and satellite images {tuple(sat.shape)} must have "
            "the same shape to be packed into one model input"
        )
    return torch.cat([uav, sat], dim=1).to(torch.float32)


@contextlib.contextmanager
def _quiet_pickle_warning() -> Iterator[None]:
    """MLflow logs a warning on every pickled model (arbitrary code on load); pickle is chosen
    on purpose here (see :func:`_flavor_kwargs`), so once per unit is noise."""
    logger = logging.getLogger("mlflow.pytorch")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        yield
    finally:
        logger.setLevel(level)


def _flavor_kwargs(model: nn.Module, input_example: Any) -> dict[str, Any]:
    """Signature and example; pinned requirements so MLflow does not infer them (inference
    loads the model in a subprocess: seconds per unit for nothing)."""
    import numpy as np
    from mlflow.models import infer_signature

    predictor = model if isinstance(model, PosePredictor) else PosePredictor(model)
    example = np.asarray(input_example, dtype=np.float32)
    was_training = predictor.training
    predictor.eval()
    try:
        with torch.no_grad():
            output = predictor(torch.from_numpy(example)).numpy()
    finally:
        predictor.train(was_training)
    return {
        "pytorch_model": predictor,
        "signature": infer_signature(example, output),
        "input_example": example,
        "pip_requirements": [f"torch=={torch.__version__.split('+')[0]}", "uavbench"],
        "serialization_format": "pickle",  # torch.export fails on some heads; pickle does not
    }


def save_pytorch_model(model: nn.Module, input_example: Any, path: str | Path) -> Path:
    """Write the flavor's directory at ``path`` (loadable by ``mlflow.pytorch.load_model(path)``).
    ``input_example``: ``(b, 6, H, W)`` float32 array, e.g. :func:`pack_pair` of a few pairs."""
    import mlflow.pytorch

    path = Path(path)
    with _quiet_pickle_warning():
        mlflow.pytorch.save_model(path=str(path), **_flavor_kwargs(model, input_example))
    return path


def log_pytorch_model(
    model: nn.Module, input_example: Any, run_id: str, tracking_uri: str, name: str = "model"
) -> str:
    """Log to run ``run_id`` of ``tracking_uri`` (MLflow 3: a LoggedModel linked to the run,
    shown in its Models column); returns the model URI (``models:/<model_id>``)."""
    import mlflow
    import mlflow.pytorch

    if mlflow.get_tracking_uri() != tracking_uri:
        mlflow.set_tracking_uri(tracking_uri)
    # The LoggedModel belongs in the run's experiment; the fluent call alone would put it in the
    # process's active experiment (Default), so it is created here and passed by id.
    client = mlflow.MlflowClient(tracking_uri)
    run = client.get_run(run_id)
    logged = client.create_logged_model(
        run.info.experiment_id, name=name, source_run_id=run_id, model_type="pose"
    )
    with _quiet_pickle_warning():
        info = mlflow.pytorch.log_model(
            name=name,
            run_id=run_id,
            model_id=logged.model_id,
            **_flavor_kwargs(model, input_example),
        )
    return str(info.model_uri)
