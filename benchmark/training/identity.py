"""One identity and one tag set for a trained model, shared by ``uavbench train`` and the runner.

A run's key hashes what decides its numbers and nothing about the machine:

- the *portable* train config (:func:`portable_config`: the data directory and the torch thread
  count blanked; the model's head options are already canonical, so an option set to the head's
  default hashes like an unset one, ``benchmark.models.model_config``),
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

from benchmark.config import config_hash
from benchmark.training.config import TrainConfig

MODEL_KEY_TAG = "model_key"  # the tag holding run_key(cfg, manifest) on every tracked run


def portable_config(cfg: TrainConfig) -> TrainConfig:
    """``cfg`` without what only locates, schedules or checks the run: ``data.root``,
    ``threads`` and ``data.verify`` (how the files are checked never changes the numbers; it is
    pinned to ``"size"``, its value before checksums became the default, so keys stay valid)."""
    data = dataclasses.replace(cfg.data, root="", verify="size")
    return dataclasses.replace(cfg, data=data, threads=None)


def run_key(cfg: TrainConfig, dataset_manifest: str) -> str:
    """16 hex digits identifying the trained model of ``cfg`` on the dataset whose
    ``manifest.json`` has sha256 ``dataset_manifest``; stable across machines and data paths."""
    from benchmark.models.registry import head_versions

    versions = head_versions(cfg.model.attitude, cfg.model.translation)
    text = json.dumps([config_hash(portable_config(cfg)), dataset_manifest, versions])
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def run_tags(cfg: TrainConfig, dataset_manifest: str) -> dict[str, str]:
    """The tags describing the trained model of ``cfg`` (strings; the same for a ``train`` run
    and a reproduce unit): model key, heads and their options and versions, encoder, seed,
    dataset."""
    from benchmark.models.registry import head_versions

    m = cfg.model
    return {
        MODEL_KEY_TAG: run_key(cfg, dataset_manifest),
        "config_hash": config_hash(portable_config(cfg)),
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
