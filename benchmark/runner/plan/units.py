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

import dataclasses
import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

from benchmark.models.device import resolve_placement
from benchmark.models.model_config import ModelConfig
from benchmark.runner.plan.repro_profiles import ReproProfile
from benchmark.runner.plan.specs import Job, TableSpec
from benchmark.sim import CONFIRMS
from benchmark.training.config import DataConfig, PretrainedConfig, TrainConfig
from benchmark.training.encoded import weight_options
from benchmark.training.identity import run_key
from benchmark.training.loop import CHECKPOINT


@dataclass
class Unit:
    """One model to train (``cfg``) and the jobs (table entries) that read its results.

    ``needs``: keys of units that must finish first (the shared encoder whose checkpoint this
    unit's frozen encoder loads, ``cfg.pretrained``). A shared-encoder unit may have no jobs of
    its own (no table shows its end-to-end heads); it is trained for the units that need it."""

    key: str
    cfg: TrainConfig
    jobs: list[Job] = field(default_factory=list)
    needs: tuple[str, ...] = ()
    shared_encoder: bool = False  # trained for other units' frozen encoders
    # The confirmation draw's splits that repeat a test split of its jobs (``confirm/standard``
    # for ``standard/test``, ``benchmark.sim.CONFIRMS``): evaluated with the same trained model,
    # read by the claims only (no table shows them), so no job lists them.
    confirm_splits: tuple[str, ...] = ()

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
        if not self.jobs:  # a shared encoder: its validation numbers only
            return [self.val_split] if self.val_split is not None else []
        seen: dict[str, None] = {}
        for job in self.jobs:
            for split in self.job_splits(job):
                seen[split] = None
        for split in self.confirm_splits:
            seen[split] = None
        return list(seen)

    @property
    def fuse_splits(self) -> list[str]:
        """The splits of its ``kind: sequence`` jobs and their confirmation splits: fused along
        their flights after the evaluation (``benchmark.evaluation.sequence_eval``), calibrated
        on ``val_split``."""
        return self._fused("head")

    @property
    def volume_splits(self) -> list[str]:
        """The splits of its ``beliefs: volume`` sequence jobs and their confirmation splits:
        the pair encoder's own pose volume fused along their flights."""
        return self._fused("volume")

    @property
    def joint_splits(self) -> list[str]:
        """The splits of its ``beliefs: volume_joint`` sequence jobs (and their confirmation
        splits): the pose volume fused jointly over heading and position."""
        return self._fused("volume_joint")

    def _fused(self, beliefs: str) -> list[str]:
        seen: dict[str, None] = {}
        for job in self.jobs:
            if job.fuse and job.beliefs == beliefs:
                seen.update(dict.fromkeys(job.eval_splits))
        # and their confirmation splits, so the fusion claims are decided again there
        for split in list(seen):
            if CONFIRMS.get(split) in self.confirm_splits:
                seen[CONFIRMS[split]] = None
        return list(seen)

    @property
    def title(self) -> str:
        if not self.jobs:
            return (f"shared {self.cfg.model.encoder} encoder on {self.cfg.data.train_split}, "
                    f"seed {self.cfg.seed}")  # fmt: skip
        job = self.jobs[0]
        extra = f" [{job.x}]" if job.x is not None else ""
        return f"{job.label}{extra} on {self.cfg.data.train_split}, seed {self.cfg.seed}"


def val_split_for(train_split: str, available: list[str]) -> str | None:
    """``X/val`` for ``X/train`` when the dataset has it (standard, frames and towns do; the
    height splits do not); for several joined splits (``standard/train+towns/train``), the
    first one's."""
    train_split = train_split.split("+")[0]
    if train_split.endswith("/train"):
        candidate = train_split[: -len("train")] + "val"
        if candidate in available:
            return candidate
    return None


def train_config(
    job: Job,
    profile: ReproProfile,
    seed: int,
    data_root: Path,
    splits: list[str],
    pretrained: PretrainedConfig | None = None,
) -> TrainConfig:
    """The unit config of ``job``: the row's model at the profile's width (the profile's
    encoder when the row names none), the profile's optimiser, device and precision, one torch
    thread, validation on the training family's val split; ``pretrained``: heads only, on that
    frozen encoder."""
    return TrainConfig(
        data=DataConfig(
            root=str(data_root),
            train_split=job.train_split,
            val_split=val_split_for(job.train_split, splits),
            # verify: DataConfig's default, as for `uavbench train` (the same config, the same
            # run key); the default checks sha256 once per file and caches it (issue 14).
        ),
        model=job.row.model_config(profile.width, profile.encoder, profile.encoder_options),
        optim=profile.optim,
        seed=seed,
        threads=1,
        device=profile.device,
        precision=profile.precision,
        pretrained=pretrained or PretrainedConfig(),
    )


def shared_encoder_config(
    profile: ReproProfile, seed: int, data_root: Path, splits: list[str]
) -> TrainConfig:
    """The unit that trains ``profile``'s shared encoder for ``seed`` end to end (its
    ``SharedEncoder``: attitude head, split, optimiser; the encoder's own loss included)."""
    shared = profile.shared_encoder
    if shared is None:
        raise ValueError(f"profile {profile.name!r} has no shared encoder")
    model = ModelConfig(
        encoder=profile.encoder,
        encoder_options=dict(profile.encoder_options),
        variant="/",
        width=profile.width,
        attitude=shared.attitude,
    )
    return TrainConfig(
        data=DataConfig(
            root=str(data_root),
            train_split=shared.train_split,
            val_split=val_split_for(shared.train_split, splits),
        ),
        model=model,
        optim=shared.optim,
        seed=seed,
        threads=1,
        device=profile.device,
        precision=profile.precision,
    )


def _frozen(cfg: TrainConfig, profile: ReproProfile) -> bool:
    """Whether a unit sits on the profile's shared encoder: it uses the profile's encoder with
    the profile's options, apart from the protocol (both protocols train the matcher on the
    sensor priors and the gravity branch on the truth; the protocol only chooses what the
    bird's-eye view and the heads see at test time, so one encoder serves both)."""
    if profile.shared_encoder is None or cfg.model.encoder != profile.encoder:
        return False
    return weight_options(cfg.model.encoder_options) == weight_options(profile.encoder_options)


def unit_key(cfg: TrainConfig, dataset_hash: str) -> str:
    """Stable across machines: ``benchmark.training.identity.run_key``, the key ``uavbench
    train`` gives the same config and data."""
    return run_key(cfg, dataset_hash)


def job_key(job: Job, unit: str) -> str:
    """Identity of one table entry's tracked run: the unit plus where its numbers go."""
    text = json.dumps([job.table, job.label, job.x, list(job.eval_splits), unit])
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def resolved_precision(profile: ReproProfile) -> ReproProfile:
    """``profile`` with ``precision="auto"`` resolved on this machine (bf16 on a CUDA device with
    bf16 support, fp32 on every CPU; ``benchmark.models.device.resolve_precision``); an explicit
    precision is kept. The keys of fp32 units do not change (``run_key`` leaves fp32 out). A
    driver that is not where the units compute (a remote Ray cluster) must be given an explicit
    precision instead (``benchmark.runner.reproduction``)."""
    if profile.precision != "auto":
        return profile
    placement = resolve_placement(profile.device, profile.precision, check=False)
    return dataclasses.replace(profile, precision=placement.precision)


def plan_units(
    specs: list[TableSpec],
    profile: ReproProfile,
    seeds: list[int],
    data_root: Path,
    splits: list[str],
    dataset_hash: str,
    workdir: Path = Path("runs"),
) -> list[Unit]:
    """Deduplicated units in first-appearance order (so ``--only table1`` runs table 1 first),
    the profile's shared encoders (one per seed,
    :class:`~benchmark.runner.plan.repro_profiles.SharedEncoder`)
    before all; ``workdir`` is where the units' checkpoints live (``<workdir>/units/<key>``):
    a unit on a shared encoder loads it from there. The profile's precision is resolved here,
    once, into every unit's config (:func:`resolved_precision`): a unit's key names it, and each
    worker trains in exactly that precision."""
    profile = resolved_precision(profile)
    wanted = {
        s for spec in specs for job in spec.jobs() for s in (job.train_split, *job.eval_splits)
    }
    if profile.shared_encoder is not None:
        wanted.update(profile.shared_encoder.train_split.split("+"))
    missing = sorted(wanted - set(splits))
    if missing:
        raise ValueError(f"{data_root}: the dataset has no split(s) {missing}; it has {splits}")
    units: dict[str, Unit] = {}
    for seed in seeds:
        shared: Unit | None = None
        if profile.shared_encoder is not None:
            cfg = shared_encoder_config(profile, seed, data_root, splits)
            key = unit_key(cfg, dataset_hash)
            shared = units.setdefault(key, Unit(key, cfg))
            shared.shared_encoder = True
        for spec in specs:
            for job in spec.jobs():
                cfg = train_config(job, profile, seed, data_root, splits)
                needs: tuple[str, ...] = ()
                if shared is not None and _frozen(cfg, profile):
                    checkpoint = Path(workdir) / "units" / shared.key / "train" / CHECKPOINT
                    pretrained = PretrainedConfig(checkpoint=str(checkpoint), key=shared.key)
                    cfg = train_config(job, profile, seed, data_root, splits, pretrained)
                    heads_optim = profile.shared_encoder.heads_optim
                    if heads_optim is not None:
                        cfg = dataclasses.replace(cfg, optim=heads_optim)
                    needs = (shared.key,)
                key = unit_key(cfg, dataset_hash)
                units.setdefault(key, Unit(key, cfg, needs=needs)).jobs.append(job)
    for unit in units.values():
        tested = {split for job in unit.jobs for split in job.eval_splits}
        unit.confirm_splits = tuple(
            confirm for test, confirm in CONFIRMS.items() if test in tested and confirm in splits
        )
    # The shared encoders first: their units' checkpoints are what the others load.
    ordered = sorted(units.values(), key=lambda u: not u.shared_encoder)
    return [u for u in ordered if u.jobs or any(u.key in v.needs for v in ordered)]
