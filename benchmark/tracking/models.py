"""Trained models in MLflow's pytorch flavor: a servable wrapper and the save/log calls.

MLflow's pytorch flavor serves a module that takes ONE float32 tensor and returns one tensor
(``mlflow.pytorch._PyTorchWrapper.predict``). A pose model takes two images, so
:class:`PosePredictor` packs them into one input and its outputs into one tensor:

- input ``(B, 6, H, W)`` float32 in [0, 1]: channels 0-2 the UAV image, 3-5 the satellite image
  (both RGB, the same size, as ``PairDataset`` gives them); or ``(B, 13, H, W)``: the same and
  then the pair's ``context`` (:data:`CONTEXT_PLANES`: field of view, satellite footprint and
  height, the gravity-aided protocol's sensor priors), each number a constant plane. A pair
  encoder needs the context for the true geometry (without it the matching encoder assumes the
  quick profile's defaults), and the gravity-aided protocol cannot run without its priors;
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
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import torch
from torch import nn

UAV_CHANNELS = 3  # input channels 0..2: the UAV image; 3..5: the satellite image
# Channels 6.. of a packed input with context: (context key, index in that value or None).
CONTEXT_PLANES: tuple[tuple[str, int | None], ...] = (
    ("fov", None),
    ("sat_footprint_m", 0),
    ("sat_footprint_m", 1),
    ("sat_height_m", None),
    ("prior_attitude", 0),
    ("prior_attitude", 1),
    ("prior_altitude_m", None),
)
WITH_CONTEXT = 2 * UAV_CHANNELS + len(CONTEXT_PLANES)


class PosePredictor(nn.Module):
    """``(B, 6, H, W)`` or ``(B, 13, H, W)`` -> ``(B, 12)``: a pose model (``forward(uav, sat,
    sat_ids, context)`` and ``decode``) behind one input and one output tensor (see the module
    docstring)."""

    def __init__(self, model: nn.Module) -> None:
        super().__init__()
        self.model = model

    def forward(self, pair: torch.Tensor) -> torch.Tensor:
        if pair.ndim != 4 or pair.shape[1] not in (2 * UAV_CHANNELS, WITH_CONTEXT):
            raise ValueError(
                f"PosePredictor input must be (B, 6, H, W) (UAV RGB then satellite RGB) or "
                f"(B, {WITH_CONTEXT}, H, W) (then the context planes), got {tuple(pair.shape)}"
            )
        uav, sat = pair[:, :UAV_CHANNELS], pair[:, UAV_CHANNELS : 2 * UAV_CHANNELS]
        context = unpack_context(pair) if pair.shape[1] == WITH_CONTEXT else None
        R, T = self.model.decode(self.model(uav, sat, None, context))
        return torch.cat([R.reshape(R.shape[0], 9), T], dim=1).to(torch.float32)


def pack_pair(
    uav: torch.Tensor, sat: torch.Tensor, context: Mapping[str, torch.Tensor] | None = None
) -> torch.Tensor:
    """``(B, 3, H, W)`` UAV and satellite images -> the ``(B, 6, H, W)`` predictor input, or with
    ``context`` (``PairDataset``'s items' ``context``, collated: each value ``(B,)`` or
    ``(B, 2)``) the ``(B, 13, H, W)`` one."""
    if uav.shape != sat.shape:
        raise ValueError(
            f"UAV images {tuple(uav.shape)} and satellite images {tuple(sat.shape)} must have "
            "the same shape to be packed into one model input"
        )
    parts = [uav, sat]
    if context is not None:
        missing = sorted({key for key, _ in CONTEXT_PLANES} - set(context))
        if missing:
            raise ValueError(
                f"pack_pair: context has no {', '.join(missing)} (got {sorted(context)}); pass "
                "the items' 'context' of PairDataset"
            )
        b, _, h, w = uav.shape
        for key, k in CONTEXT_PLANES:
            value = torch.as_tensor(context[key], dtype=torch.float32)
            value = value if k is None else value[:, k]
            parts.append(value.reshape(b, 1, 1, 1).expand(b, 1, h, w).to(uav.device))
    return torch.cat([p.to(torch.float32) for p in parts], dim=1)


def pack_items(items: Sequence[Mapping[str, Any]]) -> torch.Tensor:
    """``PairDataset`` items (each with ``uav``, ``sat`` ``(3, H, W)`` and ``context``) -> the
    ``(B, 13, H, W)`` predictor input: a logged model's input example."""
    uav = torch.stack([item["uav"] for item in items])
    sat = torch.stack([item["sat"] for item in items])
    keys = {key for key, _ in CONTEXT_PLANES}
    context = {k: torch.stack([torch.as_tensor(i["context"][k]) for i in items]) for k in keys}
    return pack_pair(uav, sat, context)


def unpack_context(pair: torch.Tensor) -> dict[str, torch.Tensor]:
    """The ``context`` dict (values ``(B,)`` / ``(B, 2)``) of a ``(B, 13, H, W)`` input."""
    planes = pair[:, 2 * UAV_CHANNELS :, 0, 0]  # (B, 7): one number per plane
    out: dict[str, list[torch.Tensor]] = {}
    for j, (key, _) in enumerate(CONTEXT_PLANES):
        out.setdefault(key, []).append(planes[:, j])
    return {k: v[0] if len(v) == 1 else torch.stack(v, dim=1) for k, v in out.items()}


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
