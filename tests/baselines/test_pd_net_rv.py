"""Pd-Net-Rv (``baselines/pd_net_rv.py``) against scipy and naive numpy references."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from benchmark.geometry import fibonacci_sphere
from benchmark.models import create_head

F = 8
N_POINTS = 4096
N_ANGLE = 128
ANGLE_BIN = math.pi / N_ANGLE


def head(**kwargs):
    torch.manual_seed(0)
    return create_head("pd_net_rv", in_features=F, **kwargs).double()


def as_tensor(rot: Rotation) -> torch.Tensor:
    return torch.tensor(rot.as_matrix(), dtype=torch.float64)


def geodesic_deg(R_hat: torch.Tensor, rot: Rotation) -> np.ndarray:
    return np.degrees((Rotation.from_matrix(R_hat.detach().numpy()) * rot.inv()).magnitude())


def rotations_at_angle(angle_deg: float, batch: int, seed: int = 0) -> Rotation:
    axis = np.random.default_rng(seed).normal(size=(batch, 3))
    return Rotation.from_rotvec(
        np.radians(angle_deg) * axis / np.linalg.norm(axis, axis=-1)[:, None]
    )


class TestTargetDistribution:
    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_convention_axis_and_angle_match_scipy(self, batch):
        rot = Rotation.random(batch, random_state=batch)
        target = head().target_distribution(as_tensor(rot))
        v = rot.as_rotvec()
        angle = np.linalg.norm(v, axis=-1)
        centres = (np.arange(N_ANGLE) + 0.5) * ANGLE_BIN
        expected_angle = np.exp(10.0 * np.cos(centres - angle[:, None]))
        np.testing.assert_allclose(
            target["angle"].numpy(), expected_angle / expected_angle.sum(-1, keepdims=True)
        )
        grid = fibonacci_sphere(N_POINTS, dtype=torch.float64)
        nearest = (torch.tensor(v / angle[:, None]) @ grid.T).argmax(-1)
        assert torch.equal(target["axis"].argmax(-1), nearest)

    def test_identity_has_a_defined_axis(self):
        h = head()
        target = h.target_distribution(torch.eye(3, dtype=torch.float64)[None])
        torch.testing.assert_close(
            h.decode_distribution(target)[0], torch.eye(3, dtype=torch.float64)
        )


class TestDecodeDistribution:
    @pytest.mark.parametrize("batch", [1, 3, 8])
    @pytest.mark.parametrize("angle", [0.5, 30.0, 90.0, 179.0, 179.9, 180.0])
    def test_own_target_decodes_to_the_label(self, batch, angle):
        rot = rotations_at_angle(angle, batch, seed=batch)
        h = head()
        err = geodesic_deg(h.decode_distribution(h.target_distribution(as_tensor(rot))), rot)
        assert err.max() < 0.05

    @pytest.mark.parametrize("batch", [1, 3, 8])
    @pytest.mark.parametrize("angle", [178.0, 179.9])
    def test_convention_perturbed_targets_near_180(self, batch, angle):
        # Near 180 deg the axis flips to its antipode (inherent). Targets made for labels rotated
        # by 2 deg (some across 180, i.e. with the flipped axis) decode within the perturbation.
        rot = rotations_at_angle(angle, batch, seed=batch)
        axis = np.random.default_rng(10 + batch).normal(size=(batch, 3))
        delta = Rotation.from_rotvec(
            math.radians(2.0) * axis / np.linalg.norm(axis, axis=-1)[:, None]
        )
        h = head()
        R_hat = h.decode_distribution(h.target_distribution(as_tensor(delta * rot)))
        assert geodesic_deg(R_hat, rot).max() < 2.1

    @pytest.mark.parametrize("batch", [1, 3, 8])
    @pytest.mark.parametrize("shift", [-3, -1, 1, 3])
    def test_convention_angle_shifted_by_bins_near_180(self, batch, shift):
        # The angle distribution off by `shift` bins at 179.5 deg: the error is at most the shift.
        rot = rotations_at_angle(179.5, batch, seed=batch)
        h = head()
        target = h.target_distribution(as_tensor(rot))
        target["angle"] = h._angle_target(
            torch.full((batch,), math.radians(179.5)) + shift * ANGLE_BIN
        )
        err = geodesic_deg(h.decode_distribution(target), rot)
        assert err.max() < abs(shift) * math.degrees(ANGLE_BIN) + 0.05

    def test_convention_hedged_axis_at_180_is_the_inherent_cost(self):
        # At 180 deg v and -v are one rotation; a prediction hedging between them keeps the right
        # rotation while one side dominates, with a resultant shrinking as (1 - 2 w).
        rot = rotations_at_angle(179.0, 1, seed=3)
        h = head()
        target = h.target_distribution(as_tensor(rot))
        axis = torch.tensor(rot.as_rotvec() / np.linalg.norm(rot.as_rotvec()))
        flipped = torch.softmax(-10.0 * (axis @ h.grid.double().T), -1)
        full = (target["axis"] @ h.grid.double()).norm().item()
        for w in (0.1, 0.3, 0.45):
            hedged = {"axis": (1 - w) * target["axis"] + w * flipped, "angle": target["angle"]}
            assert geodesic_deg(h.decode_distribution(hedged), rot).max() < 0.5
            resultant = (hedged["axis"] @ h.grid.double()).norm().item()
            assert resultant == pytest.approx((1 - 2 * w) * full, rel=1e-3)


class TestLoss:
    @pytest.mark.parametrize("batch", [1, 3, 8])
    @pytest.mark.parametrize("weight", [0.0, 1.0, 2.5])
    def test_loss_matches_naive_reference(self, batch, weight):
        rot = Rotation.random(batch, random_state=batch)
        g = torch.Generator().manual_seed(batch)
        logits = torch.randn(batch, N_POINTS, dtype=torch.float64, generator=g)
        angle_logits = torch.randn(batch, N_ANGLE, dtype=torch.float64, generator=g)
        h = head(angle_weight=weight)
        loss = h.loss({"logits": logits, "angle_logits": angle_logits}, as_tensor(rot)).item()
        # Naive numpy: axis 1 - cos(E x, axis) + alpha * pi / 8192 * sum (p - p*)^2; angle
        # weight * [CE + 1 - cos(m, m*)] on the half circle.
        grid = h.grid.double().numpy()  # the head's float32 lattice, as it uses it
        v = rot.as_rotvec()
        theta = np.linalg.norm(v, axis=-1)
        axis = v / theta[:, None]
        p = torch.softmax(logits, -1).numpy()
        t = np.exp(10.0 * axis @ grid.T)
        t /= t.sum(-1, keepdims=True)
        m = p @ grid
        l_axis = 1 - (m * axis).sum(-1) / np.linalg.norm(m, axis=-1)
        l_axis += 8e7 * (math.pi / 8192) * ((p - t) ** 2).sum(-1)
        c = (np.arange(N_ANGLE) + 0.5) * ANGLE_BIN
        log_q = torch.log_softmax(angle_logits, -1).numpy()
        t_a = np.exp(10.0 * np.cos(c - theta[:, None]))
        t_a /= t_a.sum(-1, keepdims=True)
        e = np.stack([np.cos(c), np.sin(c)], -1)
        m_a, m_t = np.exp(log_q) @ e, t_a @ e
        cos = (m_a * m_t).sum(-1) / np.linalg.norm(m_a, axis=-1) / np.linalg.norm(m_t, axis=-1)
        l_angle = -(t_a * log_q).sum(-1) + 1 - cos
        assert loss == pytest.approx(np.mean(l_axis + weight * l_angle), rel=1e-9)

    def test_bad_options(self):
        with pytest.raises(ValueError, match="angle_weight"):
            head(angle_weight=-1.0)
        with pytest.raises(ValueError, match="n_angle_bins"):
            head(n_angle_bins=2)


class TestLogProb:
    @staticmethod
    def haar_uniform(batch: int) -> dict[str, torch.Tensor]:
        """Uniform axis; angle masses of the Haar marginal (1 - cos t) / pi over each bin,
        integrated here in closed form from the bin edges."""
        edges = np.linspace(0.0, math.pi, N_ANGLE + 1)
        masses = np.diff(edges - np.sin(edges)) / math.pi
        return {
            "logits": torch.zeros(batch, N_POINTS, dtype=torch.float64),
            "angle_logits": torch.tensor(np.log(masses)).expand(batch, -1),
        }

    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_haar_uniform_prediction_scores_zero(self, batch):
        lp = head().log_prob(self.haar_uniform(batch), as_tensor(Rotation.random(batch)))
        torch.testing.assert_close(lp, torch.zeros(batch, dtype=torch.float64))

    def test_density_integrates_to_one_over_haar(self):
        # Monte Carlo: E_{R ~ Haar}[exp(log_prob(R))] = 1 for any prediction.
        g = torch.Generator().manual_seed(0)
        n = 20_000
        raw = {
            "logits": torch.randn(1, N_POINTS, dtype=torch.float64, generator=g).expand(n, -1),
            "angle_logits": torch.randn(1, N_ANGLE, dtype=torch.float64, generator=g).expand(n, -1),
        }
        density = head().log_prob(raw, as_tensor(Rotation.random(n, random_state=1))).exp()
        stderr = density.std().item() / math.sqrt(n)
        assert abs(density.mean().item() - 1) < 4 * stderr + 0.01

    def test_concentrated_prediction_closed_form(self):
        # All mass in one cell: density = 1 / Haar(cell) = n pi / Delta(t - sin t).
        rot = rotations_at_angle(100.0, 1, seed=2)
        h = head()
        v = rot.as_rotvec()[0]
        k = int((torch.tensor(v / np.linalg.norm(v)) @ h.grid.double().T).argmax())
        j = int(math.radians(100.0) // ANGLE_BIN)
        raw = {
            "logits": torch.full((1, N_POINTS), -1e4, dtype=torch.float64),
            "angle_logits": torch.full((1, N_ANGLE), -1e4, dtype=torch.float64),
        }
        raw["logits"][0, k] = 0.0
        raw["angle_logits"][0, j] = 0.0
        lo, hi = j * ANGLE_BIN, (j + 1) * ANGLE_BIN
        expected = math.log(N_POINTS * math.pi / ((hi - math.sin(hi)) - (lo - math.sin(lo))))
        assert h.log_prob(raw, as_tensor(rot)).item() == pytest.approx(expected, rel=1e-12)

    def test_uncertainty_orders_target_and_uniform(self):
        h = head()
        t = h.target_distribution(as_tensor(Rotation.random(1)))
        u_target = h.uncertainty({"logits": t["axis"].log(), "angle_logits": t["angle"].log()})
        u_uniform = h.uncertainty(
            {
                "logits": torch.zeros(1, N_POINTS, dtype=torch.float64),
                "angle_logits": torch.zeros(1, N_ANGLE, dtype=torch.float64),
            }
        )
        assert 0 <= u_target.item() < u_uniform.item() <= 1
