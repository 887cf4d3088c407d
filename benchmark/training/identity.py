"""One identity and one tag set for a trained model, shared by ``uavbench train`` and the runner.

A run's key hashes what decides its numbers and nothing about the machine:

- the *portable* train config (:func:`portable_config`: the data directory and the torch thread
  count blanked; the model's head options are already canonical, so an option set to the head's
  default hashes like an unset one, ``benchmark.models.model_config``), hashed by
  :func:`numbers_hash`: without the device, with the precision only when it is not fp32 (keys of
  fp32 runs are the keys stored before devices existed),
- the dataset's content (the sha256 of its ``manifest.json``, not its path),
- the ``version`` of the two heads (a head whose maths changed is trained again).

``uavbench train`` and a ``uavbench reproduce`` unit of the same config and data therefore have
the same :func:`run_key` and the same :func:`run_tags`; a tracking store can be searched for
``tags.model_key`` across the train experiment and the table experiments.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from typing import TYPE_CHECKING

from benchmark.training.config import TrainConfig

if TYPE_CHECKING:
    from benchmark.models.device import Placement

MODEL_KEY_TAG = "model_key"  # the tag holding run_key(cfg, manifest) on every tracked run


def effective_precision(cfg: TrainConfig) -> str:
    """``cfg.precision`` resolved on ``cfg.device`` of this machine: fp32, bf16 or fp16. An
    explicit precision is itself, whatever this machine has (a reproduction's units arrive
    resolved: ``benchmark.runner.plan.units.resolved_precision``)."""
    from benchmark.models.device import check_precision_name, resolve_device, resolve_precision

    if cfg.precision != "auto":
        check_precision_name(cfg.precision)
        return cfg.precision
    try:
        device = resolve_device(cfg.device)
    except ValueError:  # a device this machine lacks: its precision as asked ("auto" -> fp32)
        device = None
    if device is None:
        return "fp32" if cfg.precision == "auto" else cfg.precision
    return resolve_precision(cfg.precision, device)


def numbers_hash(cfg: TrainConfig, precision: str | None = None) -> str:
    """:func:`benchmark.config.config_hash` of ``cfg`` as it was before devices (issue 11): the
    ``device`` left out (any device computes the same model), the ``precision`` left out when it
    is fp32 and written resolved (``bf16``/``fp16``, never ``auto``) otherwise. Hashes and run keys
    of fp32 runs are therefore the ones stored before ``device``/``precision`` existed, and a
    checkpoint resumes on another device. ``precision``: ``cfg.precision`` already resolved
    (``Placement.precision``); None resolves it here (:func:`effective_precision`)."""
    from benchmark.config import to_dict

    data = to_dict(cfg)
    del data["device"], data["precision"]
    # A frozen pretrained encoder is named by its key, never its path; without one the section
    # is left out, so keys of runs from before it existed are unchanged. ``clip``: the heads-only
    # protocol clips each head by its own gradient norm (``loop.clip_groups``, stop 30); units
    # trained with one norm over all heads before it have other keys and are trained again.
    pretrained = data.pop("pretrained")
    if pretrained["checkpoint"]:
        data["pretrained"] = {"key": pretrained["key"], "clip": "per_head"}
    precision = precision or effective_precision(cfg)
    if precision != "fp32":
        data["precision"] = precision
    text = json.dumps(data, sort_keys=True, separators=(",", ":"), allow_nan=True)
    payload = f"{type(cfg).__module__}.{type(cfg).__qualname__}:{text}"  # as config_hash
    return hashlib.sha256(payload.encode("utf-8")).hexdigest()[:16]


def portable_config(cfg: TrainConfig) -> TrainConfig:
    """``cfg`` without what only locates, schedules or checks the run: ``data.root``,
    ``threads`` and ``data.verify`` (how the files are checked never changes the numbers; it is
    pinned to ``"size"``, its value before checksums became the default, so keys stay valid)."""
    data = dataclasses.replace(cfg.data, root="", verify="size")
    return dataclasses.replace(cfg, data=data, threads=None)


def run_key(cfg: TrainConfig, dataset_manifest: str, precision: str | None = None) -> str:
    """16 hex digits identifying the trained model of ``cfg`` on the dataset whose
    ``manifest.json`` has sha256 ``dataset_manifest``; stable across machines and data paths.
    ``precision``: resolved, as in :func:`numbers_hash`."""
    from benchmark.models.registry import head_versions

    versions = head_versions(cfg.model.attitude, cfg.model.translation)
    text = json.dumps([numbers_hash(portable_config(cfg), precision), dataset_manifest, versions])
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def model_tags(
    cfg: TrainConfig, dataset_manifest: str, precision: str | None = None
) -> dict[str, str]:
    """The tags naming the trained model of ``cfg`` (strings; the same for a ``train`` run and
    a reproduce unit): model key, heads and their options and versions, encoder, seed, dataset.
    Nothing about the machine: those tags (:func:`device_tags`) are written where the model
    computes. ``precision``: resolved, as in :func:`numbers_hash` (None: resolved here)."""
    from benchmark.models.registry import head_versions

    m = cfg.model
    return {
        MODEL_KEY_TAG: run_key(cfg, dataset_manifest, precision),
        "config_hash": numbers_hash(portable_config(cfg), precision),
        "head": m.attitude,
        "translation_head": m.translation,
        "head_options": json.dumps(
            {"attitude": m.attitude_options, "translation": m.translation_options},
            sort_keys=True,
        ),
        "head_versions": json.dumps(head_versions(m.attitude, m.translation)),
        "encoder": f"{m.encoder} {m.variant} w{m.width:g}",
        "satellite_input": m.satellite_input,
        "train_split": cfg.data.train_split,
        "seed": str(cfg.seed),
        "dataset_manifest_sha256": dataset_manifest,
    }


def run_tags(
    cfg: TrainConfig, dataset_manifest: str, placement: Placement | None = None
) -> dict[str, str]:
    """:func:`model_tags` and where it ran (:func:`device_tags`), for a run that computes in
    this process. ``placement``: ``cfg``'s device and precision resolved once by the caller
    (None: resolved here)."""
    if placement is None:
        placement = placement_of(cfg)
    return {
        **model_tags(cfg, dataset_manifest, placement.precision),
        **device_tags(cfg, placement),
    }


def placement_of(cfg: TrainConfig) -> Placement:
    """``cfg.device`` and ``cfg.precision`` resolved on this machine (not checked: a tag or a key
    may name a precision this machine refuses to run)."""
    from benchmark.models.device import resolve_placement

    return resolve_placement(cfg.device, cfg.precision, check=False)


def device_tags(cfg: TrainConfig, placement: Placement | None = None) -> dict[str, str]:
    """Where the run computes, resolved on this machine: ``device`` (``cpu``, ``cuda:0``, ...),
    ``precision`` (``fp32``, ``bf16``, ``fp16``) and ``accelerator`` (the GPU's name or the CPU
    model). Tags only: none of them is part of :func:`run_key` (fp32 precision included).
    ``placement``: resolved by the caller (None: :func:`placement_of`)."""
    from benchmark.models.device import accelerator_name

    placement = placement or placement_of(cfg)
    return {
        "device": str(placement.device),
        "precision": placement.precision,
        "accelerator": accelerator_name(placement.device),
    }
