"""From table specs to training units: what to train once, and which splits to evaluate it on.

Many table entries share a model (Pd/Re-Net on ``standard/train`` appears in Tables 1-4, Fig. 6,
Fig. 7 at kappa 10 and Fig. 9 as variant ``/``). A :class:`Unit` is one (train config, seed): it is
trained once and evaluated on the union of the splits its jobs need. Its key hashes the train
config without machine-specific paths, the dataset's manifest hash and the versions of its two
heads, so the same reproduction on another machine finds the same keys in a shared tracking store,
and a head whose maths changed (version bump) is trained again.
"""

from __future__ import annotations

import dataclasses
import hashlib
import inspect
import json
from dataclasses import dataclass, field
from pathlib import Path

from benchmark.config import config_hash
from benchmark.runner.profiles import ReproProfile
from benchmark.runner.specs import Job, TableSpec, VariantSpec
from benchmark.training.config import (
    DataConfig,
    LossConfig,
    ModelSection,
    OptimConfig,
    TrainConfig,
)


@dataclass
class Unit:
    """One model to train (``cfg``) and the jobs (table entries) that read its results."""

    key: str
    cfg: TrainConfig
    jobs: list[Job] = field(default_factory=list)

    @property
    def val_split(self) -> str | None:
        """The validation split of the training family (``standard/val`` for ``standard/train``),
        or None (height splits have none). Every unit is evaluated on it as well: learning rates,
        loss terms and profile settings are chosen on these numbers, never on the test splits."""
        return self.cfg.data.val_split

    def job_splits(self, job: Job) -> list[str]:
        """The splits whose numbers a job's tracked run holds: its test splits, then the unit's
        validation split."""
        splits = list(job.eval_splits)
        if self.val_split is not None and self.val_split not in splits:
            splits.append(self.val_split)
        return splits

    @property
    def eval_splits(self) -> list[str]:
        seen: dict[str, None] = {}
        for job in self.jobs:
            for split in self.job_splits(job):
                seen[split] = None
        return list(seen)

    @property
    def title(self) -> str:
        job = self.jobs[0]
        extra = f" [{job.x}]" if job.x is not None else ""
        return f"{job.label}{extra} on {self.cfg.data.train_split}, seed {self.cfg.seed}"


def head_default(attitude: str, option: str) -> object:
    """The default of ``option`` (e.g. kappa) in the attitude head's constructor, or None."""
    from benchmark.models.registry import get_head_class

    parameter = inspect.signature(get_head_class(attitude, "attitude")).parameters.get(option)
    if parameter is None or parameter.default is inspect.Parameter.empty:
        return None
    return parameter.default


def loss_config(variant: VariantSpec) -> LossConfig:
    """Spell a variant's kappa so that the head default and no value hash alike (Fig. 7's kappa
    10 is the same model as Table 1's Pd/Re-Net)."""
    kappa = variant.kappa
    if kappa is not None and head_default(variant.attitude, "kappa") == kappa:
        kappa = None
    return LossConfig(kappa=kappa)


def val_split_for(train_split: str, available: list[str]) -> str | None:
    """``X/val`` for ``X/train`` when the dataset has it (standard, frames and towns do; the
    height splits do not)."""
    if train_split.endswith("/train"):
        candidate = train_split[: -len("train")] + "val"
        if candidate in available:
            return candidate
    return None


def train_config(
    job: Job, profile: ReproProfile, seed: int, data_root: Path, splits: list[str]
) -> TrainConfig:
    v = job.variant
    return TrainConfig(
        data=DataConfig(
            root=str(data_root),
            train_split=job.train_split,
            val_split=val_split_for(job.train_split, splits),
            verify="size",
        ),
        model=ModelSection(
            variant=v.encoder_variant,
            width=profile.width,
            attitude=v.attitude,
            translation=v.translation,
            satellite_input=v.satellite_input,
        ),
        optim=OptimConfig(
            name=profile.optimizer,
            lr=profile.lr,
            batch_size=profile.batch_size,
            epochs=profile.epochs,
            lr_schedule=profile.lr_schedule,
            grad_clip=profile.grad_clip,
        ),
        loss=loss_config(v),
        seed=seed,
        threads=1,
    )


def unit_key(cfg: TrainConfig, dataset_hash: str) -> str:
    """Stable across machines: the config without its data path, the dataset identity and the
    heads' versions."""
    from benchmark.models.registry import head_versions

    portable = dataclasses.replace(cfg, data=dataclasses.replace(cfg.data, root=""), threads=None)
    versions = head_versions(cfg.model.attitude, cfg.model.translation)
    text = json.dumps([config_hash(portable), dataset_hash, versions])
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def job_key(job: Job, unit: str) -> str:
    """Identity of one table entry's tracked run: the unit plus where its numbers go."""
    text = json.dumps([job.table, job.label, job.x, list(job.eval_splits), unit])
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def plan_units(
    specs: list[TableSpec],
    profile: ReproProfile,
    seeds: list[int],
    data_root: Path,
    splits: list[str],
    dataset_hash: str,
) -> list[Unit]:
    """Deduplicated units in first-appearance order (so ``--only table1`` runs table 1 first)."""
    missing = sorted(
        {s for spec in specs for job in spec.jobs() for s in (job.train_split, *job.eval_splits)}
        - set(splits)
    )
    if missing:
        raise ValueError(f"{data_root}: the dataset has no split(s) {missing}; it has {splits}")
    units: dict[str, Unit] = {}
    for seed in seeds:
        for spec in specs:
            for job in spec.jobs():
                cfg = train_config(job, profile, seed, data_root, splits)
                key = unit_key(cfg, dataset_hash)
                units.setdefault(key, Unit(key, cfg)).jobs.append(job)
    return list(units.values())
