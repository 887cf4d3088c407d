"""From table specs to training units: what to train once, and which splits to evaluate it on.

Many table entries share a model (Pd/Re-Net on ``standard/train`` appears in Tables 1-4, Fig. 6,
Fig. 7 at kappa 10 and Fig. 9 as variant ``/``). A :class:`Unit` is one (train config, seed): it is
trained once and evaluated on the union of the splits its jobs need. Its key is
``benchmark.training.identity.run_key``: the train config without machine-specific paths (head
options canonical: a head's default equals no value), the dataset's manifest hash and the versions
of its two heads, so the same reproduction on another machine finds the same keys in a shared
tracking store, a head whose maths changed (version bump) is trained again, and ``uavbench train``
with the same config and data gets the same key.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

from benchmark.runner.profiles import ReproProfile
from benchmark.runner.specs import Job, TableSpec
from benchmark.training.config import DataConfig, TrainConfig
from benchmark.training.identity import run_key


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
    """The unit config of ``job``: the row's model at the profile's width, the profile's
    optimiser, device and precision, one torch thread, validation on the training family's val
    split."""
    return TrainConfig(
        data=DataConfig(
            root=str(data_root),
            train_split=job.train_split,
            val_split=val_split_for(job.train_split, splits),
            # verify: DataConfig's default, as for `uavbench train` (the same config, the same
            # run key); the default checks sha256 once per file and caches it (issue 14).
        ),
        model=job.variant.model_config(width=profile.width),
        optim=profile.optim,
        seed=seed,
        threads=1,
        device=profile.device,
        precision=profile.precision,
    )


def unit_key(cfg: TrainConfig, dataset_hash: str) -> str:
    """Stable across machines: ``benchmark.training.identity.run_key``, the key ``uavbench
    train`` gives the same config and data."""
    return run_key(cfg, dataset_hash)


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
