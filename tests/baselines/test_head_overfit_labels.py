"""Every registered head overfits 8 real labels of the smoke dataset (issue 10), parametrized over
the registry: a new head is tested for free.

The labels are the relative rotations ``R_uav^sat`` and translations ``T = [dE, dN, dU]`` of
``standard/train`` of the session ``smoke_dataset`` (real simulator, tiny), read through
``PairDataset``. Their statistics are what a head meets in training, and unlike N(0, 100^2) they
are hard in the ways that handicapped baselines: relative pitch 50-85 deg (level flight is gimbal
lock for Euler angles), ``|T|`` ~ 925 m with ``dU`` ~ -900 m dominating (a length or direction
target with almost no range). Translation heads get their statistics from all of standard/train
(``fit_statistics``), as in training.

Each head maps a fixed random feature vector per label (no encoder) and is trained alone with Adam
for a few hundred steps; the decoded rotations and translations must come close to the labels.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from benchmark.data import PairDataset
from benchmark.models import create_head, list_heads

N_LABELS = 8
F = 64  # feature width
STEPS = 300
# Adam's default lr. The lattice heads diverged at 1e-3 only inside a whole model (DEVELOPERS.md,
# encoder collapse); alone on fixed features they converge at it, and at 3e-4 they still miss by
# 1-7 deg after 300 steps. One lr for every head, so no head gets a tuned advantage.
LR = 1e-3
# About one grid spacing of the probabilistic heads (3.2 deg on the 4096-point S^2 lattice, 2.8 deg
# Euler bins): a head fits its own training labels to its resolution or better. Measured: regression
# heads < 1e-3 deg, lattice heads 0.4-1.6 deg, 2.6 for Pd-Net-Q with the paper's one-sided target.
ATTITUDE_TOL_DEG = 3.0
# 0.5 % of |T| (~925 m), a third of the spread of the labels' lengths (std ~16 m), far below the
# test errors the tables compare (tens of metres): a head that cannot fit its own training labels to
# 5 m is limited by its parameterisation. The regression head reaches < 1e-3 m. Same bound as the
# slow whole-model overfit test (tests/baselines/test_overfit.py).
TRANSLATION_TOL_M = 5.0
SAT_N = Rotation.from_euler("ZXY", [0.0, -90.0, 0.0], degrees=True)  # R_sat^n, Eq. 5


@pytest.fixture(scope="module")
def labels(smoke_dataset) -> dict[str, torch.Tensor]:
    """R (8, 3, 3), T (8, 3) metres, uav_euler (8, 3) radians of 8 labels spread evenly over
    standard/train; T_train (M, 3) all of its translations (float32, as the data loader gives)."""
    dataset = PairDataset(smoke_dataset, "standard/train", verify="size")
    items = [dataset[i] for i in range(len(dataset))]
    chosen = np.linspace(0, len(items) - 1, N_LABELS).round().astype(int)
    assert len(set(chosen.tolist())) == N_LABELS, f"standard/train has only {len(items)} pairs"
    return {
        "R": torch.stack([items[i]["R"] for i in chosen]),
        "T": torch.stack([items[i]["T"] for i in chosen]),
        "uav_euler": torch.stack([items[i]["uav_euler"] for i in chosen]),
        "T_train": torch.stack([item["T"] for item in items]),
    }


def overfit(name: str, target: torch.Tensor, T_train: torch.Tensor | None = None):
    """Train head ``name`` alone on fixed features for STEPS Adam steps; returns its decoded output
    (eval mode) and the first and last loss."""
    torch.manual_seed(0)
    head = create_head(name, in_features=F)
    if T_train is not None:
        head.fit_statistics(T_train)
    features = torch.randn(target.shape[0], F, generator=torch.Generator().manual_seed(0))
    optimizer = torch.optim.Adam(head.parameters(), lr=LR)
    losses = []
    for _ in range(STEPS):
        loss = head.loss(head(features), target)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    head.eval()
    with torch.no_grad():
        decoded = head.decode(head(features))
    return decoded, losses[0], losses[-1]


def geodesic_deg(R_hat: torch.Tensor, R: torch.Tensor) -> np.ndarray:
    """(B,) angle between rotations in degrees, scipy as the reference."""
    a = Rotation.from_matrix(R_hat.double().numpy())
    b = Rotation.from_matrix(R.double().numpy())
    return np.degrees((a.inv() * b).magnitude())


class TestLabels:
    """The labels are the dataset's, in the conventions the heads assume."""

    def test_convention_R_is_relative_to_the_nadir_satellite(self, labels):
        # R_uav^sat = R_uav^n (R_sat^n)^T with R_b^n = Rz(yaw) Rx(pitch) Ry(roll) (Eq. 1, 2, 5).
        uav = Rotation.from_euler("ZXY", labels["uav_euler"].double().numpy())
        expected = (uav * SAT_N.inv()).as_matrix()
        np.testing.assert_allclose(labels["R"].double().numpy(), expected, atol=1e-5)

    def test_labels_have_the_datasets_statistics(self, labels):
        T = labels["T_train"].double()
        length = T.norm(dim=-1)
        assert 600 < float(length.min()) and float(length.max()) < 1500, length  # heights 600-1400
        assert (T[:, 2].abs() > 0.8 * length).all()  # dU dominates |T|
        pitch = Rotation.from_matrix(labels["R"].double().numpy()).as_euler("ZXY")[:, 1]
        assert (np.degrees(pitch) > 40).all()  # relative pitch between 40 and 90 deg


@pytest.mark.parametrize("name", list_heads("attitude"))
def test_attitude_head_overfits_dataset_labels(name, labels):
    R_hat, first, last = overfit(name, labels["R"])
    errors = geodesic_deg(R_hat, labels["R"])
    assert last < first, (first, last)
    assert errors.max() < ATTITUDE_TOL_DEG, (
        f"{name}: after {STEPS} steps the rotation errors are {np.round(errors, 2).tolist()} deg "
        f"(loss {first:.4g} -> {last:.4g})"
    )


@pytest.mark.parametrize("name", list_heads("translation"))
def test_translation_head_overfits_dataset_labels(name, labels):
    T = labels["T"]
    T_hat, first, last = overfit(name, T, T_train=labels["T_train"])
    errors = (T_hat.double() - T.double()).norm(dim=-1).numpy()
    # Split the error into length and direction, to say which part of the head misses.
    length_err = (T_hat.double().norm(dim=-1) - T.double().norm(dim=-1)).abs().numpy()
    cos = torch.nn.functional.cosine_similarity(T_hat.double(), T.double(), dim=-1)
    direction_deg = np.degrees(np.arccos(cos.clamp(-1, 1).numpy()))
    assert last < first, (first, last)
    assert errors.max() < TRANSLATION_TOL_M, (
        f"{name}: after {STEPS} steps the translation errors are {np.round(errors, 2).tolist()} m "
        f"(length errors {np.round(length_err, 2).tolist()} m, direction errors "
        f"{np.round(direction_deg, 3).tolist()} deg; loss {first:.4g} -> {last:.4g})"
    )
