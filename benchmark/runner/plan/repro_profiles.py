"""Reproduction profiles: how big the data, the encoder and the training are.

``smoke`` runs every table end to end in CI in a couple of minutes (tiny images, one epoch): it
checks the pipeline, not the paper. ``quick`` (the default) runs every table and figure with
two training seeds on one dataset within the 2-hour budget on a 2-core CPU (issue 10: verdicts
need seeds and flight-bootstrap intervals; three seeds until issue 21, whose matching encoder and
frozen-head units put three seeds of the whole profile at about 2.5-3 hours). To fit, it trains
5 epochs (15 before issue 10, when one seed of 32 runs took 74.5 min, 136 worker-minutes of it
training). It departs from the paper's optimiser (Adam with a cosine schedule instead of SGD with
momentum at 1e-3) because SGD at 1e-3 barely moves a from-scratch network in the few epochs a CPU
affords. Its lr is 3e-4: at 1e-3 Pd-Net-Rv and Re-Net-Q did not learn (training loss flat), at
3e-4 they do; one rate for every head, as in the paper. ``paper`` uses the paper's settings
(224 px, full-width GoogLeNet, SGD with momentum, lr 1e-3, batch 20): meant for a GPU.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from benchmark.training.config import OptimConfig


@dataclass(frozen=True)
class SharedEncoder:
    """Train the profile's encoder once per seed, then every row that uses it trains only its
    heads on the encoder's frozen features (``TrainConfig.pretrained``).

    The encoder trains end to end in a unit of its own: ``attitude`` (Pd/Re-Net) and the
    regression translation head on ``train_split`` with ``optim``, the encoder's own loss
    included (its ``volume_nll_weight``). Its checkpoint is the ``pretrained`` checkpoint of the
    rows' units, which the runner therefore trains first. The rows' heads train with
    ``heads_optim`` (cheap: a few seconds an epoch on cached features), each head's gradient
    clipped by its own norm (``benchmark.training.loop.clip_groups``)."""

    optim: OptimConfig
    train_split: str = "standard/train"  # several joined by "+" (one training set)
    attitude: str = "pd_re_net"
    # The heads' optimiser on the frozen features (None: the profile's ``optim``, which the rows
    # that train end to end, e.g. Fig. 9's GoogLeNet, keep).
    heads_optim: OptimConfig | None = None


@dataclass(frozen=True)
class ReproProfile:
    """A reproduction's scale: the dataset profile, the encoder width every table row trains at
    (the rest of the model comes from the row, ``benchmark.runner.plan.specs``) and the optimiser
    (``TrainConfig.optim`` of every unit)."""

    name: str
    dataset: str  # ``uavbench simulate`` profile
    width: float  # GoogLeNet width multiplier (paper: 1.0)
    optim: OptimConfig
    seeds: int = 1  # default number of seeds
    dataset_size: int | None = None  # standard-split pairs; None: the dataset profile's own
    # Where and in what precision every unit trains (``TrainConfig.device``/``precision``; set by
    # ``reproduce --device/--precision``). The device is never part of a unit's identity; a
    # precision other than fp32 is (a bf16 unit is another model).
    device: str = "auto"
    precision: str = "auto"
    # The encoder of every row that names none (``benchmark.runner.plan.specs.RowSpec``)
    # and its options; rows that name an encoder (Fig. 9's GoogLeNet) keep theirs.
    encoder: str = "googlenet"
    encoder_options: dict[str, Any] = field(default_factory=dict)
    shared_encoder: SharedEncoder | None = None  # None: every unit trains end to end


# quick (issue 21): the matching encoder, trained once per seed end to end (Pd/Re-Net and the
# encoder's own loss) on standard/train + towns/train; then every row's heads on its frozen
# features. Chosen on standard/val, seed 0 (DEVELOPERS.md, "The quick profile's matching
# encoder"): on standard/train alone (8 epochs) the matcher's own yaw was 4.2 deg median on its
# training pairs and 8.3 on val; with the 1,600 towns pairs added (6 epochs, the same number of
# steps) 3.6 and 4.4.
QUICK_ENCODER_OPTIM = OptimConfig(
    name="adam", lr=1e-3, lr_schedule="cosine", batch_size=20, epochs=6, grad_clip=10.0
)
QUICK_ENCODER_SPLITS = "standard/train+towns/train"
# The fixed grey-level and gradient channels beside the learned features (``grey_gradient``),
# chosen on a held-out training style (DEVELOPERS.md, "features that transfer"): matchers trained
# on oxford frames only, 4 epochs, seeds 0 and 1, median yaw on cambridge val frames 46 and 41 deg
# with them against 73 and 65 without (oxford val: 34 / 53 against 35 / 51); the photometric
# jitter alone was worse at that budget (67 / 84), so it stays off.
QUICK_ENCODER_OPTIONS: dict[str, Any] = {"grey_gradient": True}
# The heads on its frozen features (standard/val, seed 0, vision-only, median yaw / mean pitch
# error): Pd/Re-Net 6.5 / 9.3 deg after 5 epochs, 6.1 / 5.9 after 10, 5.9 / 4.0 after 30;
# Re-Net-R 8.3 / 2.1 after 10. 30 epochs cost ~3 min a lattice-head unit on one core (135 units
# would not fit the budget); 10 do.
QUICK_FROZEN_HEADS_OPTIM = OptimConfig(
    name="adam", lr=3e-4, lr_schedule="cosine", batch_size=20, epochs=10, grad_clip=10.0
)
QUICK_HEADS_OPTIM = OptimConfig(
    name="adam", lr=3e-4, lr_schedule="cosine", batch_size=20, epochs=5, grad_clip=10.0
)

PROFILES: dict[str, ReproProfile] = {
    "smoke": ReproProfile(
        name="smoke",
        dataset="smoke",
        width=0.25,
        optim=OptimConfig(name="adam", lr=1e-3, lr_schedule="constant", batch_size=8, epochs=1),
    ),
    "quick": ReproProfile(
        name="quick",
        dataset="quick",
        width=0.25,
        optim=QUICK_HEADS_OPTIM,
        seeds=3,
        encoder="matching",
        encoder_options=QUICK_ENCODER_OPTIONS,
        shared_encoder=SharedEncoder(
            optim=QUICK_ENCODER_OPTIM,
            train_split=QUICK_ENCODER_SPLITS,
            heads_optim=QUICK_FROZEN_HEADS_OPTIM,
        ),
    ),
    "paper": ReproProfile(
        name="paper",
        dataset="paper",
        width=1.0,
        optim=OptimConfig(name="sgd", lr=1e-3, lr_schedule="constant", batch_size=20, epochs=30),
    ),
}


def get_repro_profile(name: str) -> ReproProfile:
    if name not in PROFILES:
        raise ValueError(f"unknown profile {name!r}; expected one of {sorted(PROFILES)}")
    return PROFILES[name]
