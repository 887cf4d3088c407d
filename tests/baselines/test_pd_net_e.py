"""Pd-Net-E (``baselines/pd_net_e.py``) against scipy and naive numpy references."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from benchmark.geometry import SAT_R_N, euler_to_rotmat, relative_rotation
from benchmark.models import create_head

F = 8
N_BINS = 128
PITCH_BIN = math.pi / N_BINS


def head(**kwargs):
    torch.manual_seed(0)
    return create_head("pd_net_e", in_features=F, **kwargs).double()


def as_tensor(rot: Rotation) -> torch.Tensor:
    return torch.tensor(rot.as_matrix(), dtype=torch.float64)


def geodesic_deg(R_hat: torch.Tensor, rot: Rotation) -> np.ndarray:
    """Rotation angle of ``R_hat R^T`` in degrees, computed by scipy."""
    return np.degrees((Rotation.from_matrix(R_hat.detach().numpy()) * rot.inv()).magnitude())


def level_flight(batch: int, seed: int = 0) -> Rotation:
    """Relative rotations R_uav^sat for UAV pitch -2..-0.05 deg, roll +-1 deg, any heading:
    relative pitch ``asin(cos(theta) cos(gamma))`` ~ 87.9..89.95 deg."""
    rng = np.random.default_rng(seed)
    yaw = rng.uniform(-180, 180, batch)
    theta = rng.uniform(-2.0, -0.05, batch)
    gamma = rng.uniform(-1.0, 1.0, batch)
    uav = euler_to_rotmat(*(torch.tensor(np.radians(a)) for a in (yaw, theta, gamma)))
    return Rotation.from_matrix(relative_rotation(uav, SAT_R_N).numpy())


class TestConvention:
    def test_convention_rows_are_yaw_pitch_roll(self):
        ypr = np.array([[100.0, 20.0, -30.0]])
        h = head()
        target = h.target_distribution(as_tensor(Rotation.from_euler("ZXY", ypr, degrees=True)))
        centres = np.degrees(h.centres.numpy())  # (3, n)
        peaks = np.take_along_axis(centres, target[0].argmax(-1).numpy()[:, None], -1)[:, 0]
        np.testing.assert_allclose(peaks, ypr[0], atol=360 / N_BINS)

    def test_convention_pitch_bins_cover_the_interval(self):
        c = np.degrees(head().centres[1].numpy())
        np.testing.assert_allclose(c[[0, -1]], [-90 + 90 / N_BINS, 90 - 90 / N_BINS])


class TestDecodeDistribution:
    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_own_target_decodes_to_the_label(self, batch):
        rot = Rotation.random(batch, random_state=batch)
        h = head()
        assert (
            geodesic_deg(h.decode_distribution(h.target_distribution(as_tensor(rot))), rot).max()
            < 1e-2
        )

    @pytest.mark.parametrize("pitch", [85.0, 89.0, 89.9, -88.0, -89.9])
    def test_pitch_near_its_bounds_is_recovered(self, pitch):
        rot = Rotation.from_euler("ZXY", [[40.0, pitch, 10.0]], degrees=True)
        h = head()
        assert (
            geodesic_deg(h.decode_distribution(h.target_distribution(as_tensor(rot))), rot).max()
            < 1e-2
        )

    @pytest.mark.parametrize("batch", [1, 3, 8])
    @pytest.mark.parametrize("shift", [-3, -2, -1, 1, 2, 3])
    def test_convention_level_flight_pitch_shifted_by_bins(self, batch, shift):
        # A prediction off by `shift` pitch bins near +90 deg (the level-flight relative pitch):
        # the error is at most the shift (clipped at the bound), never a jump to -90 deg.
        rot = level_flight(batch, seed=batch)
        h = head()
        angles = h._angles(as_tensor(rot))
        assert math.degrees(angles[:, 1].min()) > 85
        angles[:, 1] += shift * PITCH_BIN
        err = geodesic_deg(h.decode_distribution(h._target(angles)), rot)
        assert err.max() < abs(shift) * math.degrees(PITCH_BIN) + 0.01

    @pytest.mark.parametrize("batch", [1, 3, 8])
    @pytest.mark.parametrize("shift", [1, 2, 3])
    def test_convention_level_flight_shift_towards_the_bound(self, batch, shift):
        # The distribution itself moved towards +90 deg (mass beyond the last bin dropped).
        rot = level_flight(batch, seed=10 + batch)
        h = head()
        target = h.target_distribution(as_tensor(rot))
        pitch = torch.zeros_like(target[:, 1])
        pitch[:, shift:] = target[:, 1, :-shift]
        target[:, 1] = pitch / pitch.sum(-1, keepdim=True)
        assert geodesic_deg(h.decode_distribution(target), rot).max() < 3 * math.degrees(PITCH_BIN)

    @pytest.mark.parametrize("batch", [1, 3, 8])
    @pytest.mark.parametrize("yaw", [179.5, -179.5, 180.0])
    @pytest.mark.parametrize("shift", [-3, 3])
    def test_convention_yaw_and_roll_wrap_at_180(self, batch, yaw, shift):
        # Yaw and roll at +-180 deg, distributions rolled by `shift` bins across the wrap.
        rng = np.random.default_rng(batch)
        ypr = np.stack([np.full(batch, yaw), rng.uniform(-60, 60, batch), np.full(batch, -yaw)], -1)
        rot = Rotation.from_euler("ZXY", ypr, degrees=True)
        h = head()
        target = h.target_distribution(as_tensor(rot))
        for a in (0, 2):
            target[:, a] = torch.roll(target[:, a], shift, dims=-1)
        # Two angles each off by 3 bins of 2.8 deg: at most 2 * 8.4 deg.
        assert geodesic_deg(h.decode_distribution(target), rot).max() < 2 * 3 * 360 / N_BINS

    def test_convention_gimbal_lock_keeps_its_inherent_coupling(self):
        # At pitch 90 deg only yaw + roll is defined: (yaw, roll) = (a, b) and (a + d, b - d) are
        # the same rotation. The label puts it all in yaw; a prediction splitting it differently
        # decodes to the same rotation. An error in yaw alone is an error in yaw + roll (inherent).
        h = head()
        angles = torch.tensor(
            [[0.7, math.pi / 2, 0.0], [0.2, math.pi / 2, 0.5]], dtype=torch.float64
        )
        R_hat = h.decode_distribution(h._target(angles))
        rot = Rotation.from_euler("ZXY", [[0.7, math.pi / 2, 0.0]])
        assert geodesic_deg(R_hat, rot).max() < 1e-2


class TestLoss:
    @staticmethod
    def reference_loss(logits: np.ndarray, ypr: np.ndarray, kappa: float, weight: float) -> float:
        """Naive numpy: per angle, cross-entropy with the discrete von Mises target (pitch bins on
        [-pi/2, pi/2]) plus ``weight * (1 - cos(m, m*))`` of the predicted and target means."""
        n = logits.shape[-1]
        u = (np.arange(n) + 0.5) / n
        centres = [-np.pi + 2 * np.pi * u, -np.pi / 2 + np.pi * u, -np.pi + 2 * np.pi * u]
        total = 0.0
        for b in range(logits.shape[0]):
            for a in range(3):
                c = centres[a]
                target = np.exp(kappa * np.cos(c - ypr[b, a]))
                target /= target.sum()
                log_p = logits[b, a] - np.log(np.exp(logits[b, a]).sum())
                p = np.exp(log_p)
                m = np.array([(p * np.cos(c)).sum(), (p * np.sin(c)).sum()])
                m_t = np.array([(target * np.cos(c)).sum(), (target * np.sin(c)).sum()])
                cos = m @ m_t / np.linalg.norm(m) / np.linalg.norm(m_t)
                total += -(target * log_p).sum() + weight * (1 - cos)
        return total / logits.shape[0]

    @pytest.mark.parametrize("batch", [1, 3, 8])
    @pytest.mark.parametrize("weight", [0.0, 1.0, 2.5])
    def test_loss_matches_naive_reference(self, batch, weight):
        rot = Rotation.random(batch, random_state=batch)
        g = torch.Generator().manual_seed(1)
        logits = torch.randn(batch, 3, N_BINS, dtype=torch.float64, generator=g)
        h = head(direction_weight=weight)
        expected = self.reference_loss(logits.numpy(), rot.as_euler("ZXY"), 10.0, weight)
        assert h.loss(logits, as_tensor(rot)).item() == pytest.approx(expected, rel=1e-9)

    def test_the_target_minimises_the_direction_term(self):
        rot = level_flight(3)
        h = head(direction_weight=1.0)
        target = h.target_distribution(as_tensor(rot))
        ce = -(target * target.log()).sum((-1, -2)).mean()
        assert h.loss(target.log(), as_tensor(rot)).item() == pytest.approx(ce.item(), abs=1e-9)

    def test_direction_term_pulls_a_uniform_prediction_towards_the_label(self):
        rot = Rotation.from_euler("ZXY", [[120.0, 30.0, 0.0]], degrees=True)
        grads = []
        for weight in (0.0, 1.0):
            logits = torch.zeros(1, 3, N_BINS, dtype=torch.float64, requires_grad=True)
            head(direction_weight=weight).loss(logits, as_tensor(rot)).backward()
            grads.append(logits.grad[0, 0])
        label_bin = int((math.radians(120.0) + math.pi) / (2 * math.pi / N_BINS))
        assert grads[1][label_bin] < grads[0][label_bin] < 0

    def test_bad_options(self):
        with pytest.raises(ValueError, match="direction_weight"):
            head(direction_weight=-1.0)
        with pytest.raises(ValueError, match="n_bins"):
            head(n_bins=3)


class TestLogProb:
    @staticmethod
    def haar_uniform_logits(h) -> torch.Tensor:
        """Bin masses of the Haar measure: 1/n for yaw and roll, (sin u - sin l) / 2 for pitch,
        computed here from the bin edges (independently of the head's buffers)."""
        edges = np.radians(np.linspace(-90.0, 90.0, N_BINS + 1))
        pitch = (np.sin(edges[1:]) - np.sin(edges[:-1])) / 2
        masses = np.stack([np.full(N_BINS, 1 / N_BINS), pitch, np.full(N_BINS, 1 / N_BINS)])
        return torch.tensor(np.log(masses))[None]

    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_haar_uniform_prediction_scores_zero(self, batch):
        h = head()
        rot = Rotation.random(batch, random_state=batch)
        lp = h.log_prob(self.haar_uniform_logits(h).expand(batch, -1, -1), as_tensor(rot))
        torch.testing.assert_close(lp, torch.zeros(batch, dtype=torch.float64))

    def test_uniform_bins_closed_form(self):
        # Uniform bins: density 1 / (4 pi^3) per rad^3; the Haar density of the cell at pitch
        # p is cos(p) / (8 pi^2) per rad^3 on average over the bin: ratio 2 / (n (sin u - sin l)).
        h = head()
        rot = Rotation.from_euler("ZXY", [[10.0, 0.3, 20.0]], degrees=True)  # bin [0, 1.4 deg]
        lp = h.log_prob(torch.zeros(1, 3, N_BINS, dtype=torch.float64), as_tensor(rot))
        expected = math.log(2 / (N_BINS * math.sin(PITCH_BIN)))
        assert lp.item() == pytest.approx(expected, rel=1e-12)

    @pytest.mark.parametrize("seed", [0, 1])
    def test_density_integrates_to_one_over_haar(self, seed):
        # Monte Carlo: E_{R ~ Haar}[exp(log_prob(R))] = 1 for any prediction.
        g = torch.Generator().manual_seed(seed)
        logits = torch.randn(1, 3, N_BINS, dtype=torch.float64, generator=g)
        n = 200_000
        R = as_tensor(Rotation.random(n, random_state=seed))
        density = head().log_prob(logits.expand(n, -1, -1), R).exp()
        stderr = density.std().item() / math.sqrt(n)
        assert abs(density.mean().item() - 1) < 4 * stderr
