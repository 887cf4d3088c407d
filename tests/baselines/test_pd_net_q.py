"""Pd-Net-Q (the paper's label) and Pd-Net-Q-sym (``baselines/pd_net_q*.py``) against scipy, the
paper's Eq. 6 and naive numpy references."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from benchmark.geometry import SAT_R_N, euler_to_rotmat, relative_rotation
from benchmark.models import create_head

F = 8
N_POINTS = 4096


def head(name: str = "pd_net_q", **kwargs):
    torch.manual_seed(0)
    return create_head(name, in_features=F, **kwargs).double()


def as_tensor(rot: Rotation) -> torch.Tensor:
    return torch.tensor(rot.as_matrix(), dtype=torch.float64)


def geodesic_deg(R_hat: torch.Tensor, rot: Rotation) -> np.ndarray:
    return np.degrees((Rotation.from_matrix(R_hat.detach().numpy()) * rot.inv()).magnitude())


def hamilton(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Naive Hamilton product of (w, x, y, z) quaternions, (..., 4)."""
    pw, px, py, pz = np.moveaxis(p, -1, 0)
    qw, qx, qy, qz = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ],
        -1,
    )


def paper_label_reference(rot: Rotation) -> np.ndarray:
    """Eq. 3-5 from scipy: the quaternion of R_uav^n with the sign that makes the pivot of the
    first Eq. 3 case that holds positive, times the conjugate of the printed Q_sat^n."""
    R_n = rot.as_matrix() @ SAT_R_N.numpy()
    q = np.roll(Rotation.from_matrix(R_n).as_quat(), 1, -1)  # (w, x, y, z)
    r11, r22, r33 = R_n[:, 0, 0], R_n[:, 1, 1], R_n[:, 2, 2]
    pivot = np.select([r11 >= r22 + r33, r22 >= r11 + r33, r33 >= r11 + r22], [1, 2, 3], 0)
    q *= np.sign(q[np.arange(len(q)), pivot])[:, None]
    sat_conj = np.array([-math.sqrt(0.5), -math.sqrt(0.5), 0.0, 0.0])  # conj of Eq. 5 as printed
    return hamilton(q, sat_conj)


def paper_sweep(psi_deg: np.ndarray, theta: float = -20.0, gamma: float = -10.0) -> Rotation:
    """Relative rotations for UAV heading psi, pitch theta, roll gamma (the paper's Fig. 2)."""
    psi = torch.tensor(np.radians(psi_deg))
    uav = euler_to_rotmat(psi, torch.tensor(math.radians(theta)), torch.tensor(math.radians(gamma)))
    return Rotation.from_matrix(relative_rotation(uav, SAT_R_N).numpy())


def eq6_heading_deg(theta: float = -20.0, gamma: float = -10.0) -> float:
    """Paper Eq. 6: the (negative) heading where R33 >= R11 + R22 stops holding."""
    ct, cg = math.cos(math.radians(theta)), math.cos(math.radians(gamma))
    st, sg = math.sin(math.radians(theta)), math.sin(math.radians(gamma))
    c = (ct * cg * (ct + cg) - math.sqrt((1 + 2 * ct * cg) * st**2 * sg**2)) / (1 + ct * cg) ** 2
    return -math.degrees(math.acos(c))


SWITCH = eq6_heading_deg()


class TestPaperLabel:
    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_convention_label_is_eq3_to_5(self, batch):
        rot = Rotation.random(batch, random_state=batch)
        q = head().encode(as_tensor(rot)).numpy()
        np.testing.assert_allclose(q, paper_label_reference(rot), atol=1e-12)
        np.testing.assert_allclose(
            Rotation.from_quat(np.roll(q, -1, -1)).as_matrix(), rot.as_matrix(), atol=1e-12
        )

    def test_convention_label_jumps_once_at_eq6(self):
        # Fig. 2: heading swept over the circle at pitch -20, roll -10 deg; the label jumps to
        # its antipode once, at the heading of Eq. 6 (the paper reads -63.03 deg).
        assert SWITCH == pytest.approx(-63.03, abs=0.05)
        step = 0.01
        psi = np.arange(-180.0, 180.0, step)
        q = head().encode(as_tensor(paper_sweep(psi))).numpy()
        jumps = np.flatnonzero(np.linalg.norm(np.diff(q, axis=0), axis=-1) > 1.0)
        assert len(jumps) == 1
        assert psi[jumps[0]] <= SWITCH + 1e-9 and SWITCH <= psi[jumps[0] + 1] + 1e-9
        assert np.linalg.norm(q[jumps[0] + 1] + q[jumps[0]]) < 0.01  # q -> -q


class TestDecode:
    @pytest.mark.parametrize("name", ["pd_net_q", "pd_net_q_sym"])
    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_own_target_decodes_to_the_label(self, name, batch):
        rot = Rotation.random(batch, random_state=batch)
        h = head(name)
        assert (
            geodesic_deg(h.decode_distribution(h.target_distribution(as_tensor(rot))), rot).max()
            < 0.5
        )

    @pytest.mark.parametrize("name", ["pd_net_q", "pd_net_q_sym"])
    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_convention_perturbed_targets_at_the_case_switch(self, name, batch):
        # Labels within 0.5 deg of heading on either side of the switch, targets made for labels
        # rotated by 2 deg: decoding errs by the perturbation (+ lattice), never by a jump.
        rng = np.random.default_rng(batch)
        rot = paper_sweep(SWITCH + rng.uniform(-0.5, 0.5, batch))
        axis = rng.normal(size=(batch, 3))
        delta = Rotation.from_rotvec(
            math.radians(2.0) * axis / np.linalg.norm(axis, axis=-1)[:, None]
        )
        h = head(name)
        R_hat = h.decode_distribution(h.target_distribution(as_tensor(delta * rot)))
        assert geodesic_deg(R_hat, rot).max() < 2.5

    def test_convention_mixed_hemispheres_are_the_inherent_cost(self):
        # Near the switch a network hedges between the labels q and -q. The paper's decoding (the
        # mean) survives a minority share of the wrong sign but its resultant shrinks with it and
        # vanishes at one half; the symmetric head's eigenvector decoding does not care.
        rot = paper_sweep(np.array([SWITCH - 0.1]))
        q_head, sym = head(), head("pd_net_q_sym")
        t = q_head.target_distribution(as_tensor(rot))
        flipped = torch.softmax(
            -q_head.kappa * (q_head.encode(as_tensor(rot)) @ q_head.grid.double().T), -1
        )
        full = 1 - q_head.uncertainty(t.log()).item()
        for w in (0.1, 0.3, 0.45):
            p = (1 - w) * t + w * flipped
            assert geodesic_deg(q_head.decode_distribution(p), rot).max() < 0.5
            assert geodesic_deg(sym.decode_distribution(p), rot).max() < 0.5
            # |sum p x| = (1 - 2 w) |sum t x|: at w = 1/2 the mean, and the decoding, is undefined.
            resultant = 1 - q_head.uncertainty(p.log()).item()
            assert resultant == pytest.approx((1 - 2 * w) * full, rel=1e-3)  # grid ~ -grid

    def test_symmetric_target_is_continuous_across_the_switch(self):
        rot = paper_sweep(np.array([SWITCH - 0.01, SWITCH + 0.01]))
        for name, continuous in (("pd_net_q", False), ("pd_net_q_sym", True)):
            t = head(name).target_distribution(as_tensor(rot))
            l1 = (t[0] - t[1]).abs().sum().item()
            assert (l1 < 0.01) if continuous else (l1 > 1.9), (name, l1)

    def test_symmetric_target_is_sign_invariant(self):
        h = head("pd_net_q_sym")
        q = torch.tensor(np.roll(Rotation.random(3).as_quat(), 1, -1))
        grid = h.grid.double()
        torch.testing.assert_close(h.target(q, grid), h.target(-q, grid))


class TestLoss:
    @staticmethod
    def reference(p: np.ndarray, target: np.ndarray, m: np.ndarray, q: np.ndarray) -> float:
        """``1 - cos(m, q) + alpha * s * sum (p - p*)^2`` with s = (2 pi^2/4096) n /
        (4096 * 2 pi^2) = n / 4096^2 (DirectionNet's units on S^3), mean over the batch."""
        cos = (m * q).sum(-1) / np.linalg.norm(m, axis=-1) / np.linalg.norm(q, axis=-1)
        s = p.shape[-1] / 4096**2
        return float(np.mean(1 - cos + 8e7 * s * ((p - target) ** 2).sum(-1)))

    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_paper_loss_matches_naive_reference(self, batch):
        rot = Rotation.random(batch, random_state=batch)
        g = torch.Generator().manual_seed(batch)
        logits = torch.randn(batch, N_POINTS, dtype=torch.float64, generator=g)
        h = head()
        grid = h.grid.double().numpy()
        p = torch.softmax(logits, -1).numpy()
        q = paper_label_reference(rot)
        target = np.exp(10.0 * q @ grid.T)
        target /= target.sum(-1, keepdims=True)
        expected = self.reference(p, target, p @ grid, q)
        assert h.loss(logits, as_tensor(rot)).item() == pytest.approx(expected, rel=1e-9)

    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_symmetric_loss_matches_naive_reference(self, batch):
        rot = Rotation.random(batch, random_state=batch)
        g = torch.Generator().manual_seed(batch)
        logits = torch.randn(batch, N_POINTS, dtype=torch.float64, generator=g)
        h = head("pd_net_q_sym")
        grid = h.grid.double().numpy()
        p = torch.softmax(logits, -1).numpy()
        q = np.roll(rot.as_quat(), 1, -1) * -1  # the sign must not matter
        target = np.exp(10.0 * q @ grid.T) + np.exp(-10.0 * q @ grid.T)
        target /= target.sum(-1, keepdims=True)
        folded = (p * np.sign(q @ grid.T)) @ grid
        expected = self.reference(p, target, folded, q)
        assert h.loss(logits, as_tensor(rot)).item() == pytest.approx(expected, rel=1e-9)

    def test_loss_gradient_finite_at_uniform(self):
        for name in ("pd_net_q", "pd_net_q_sym"):
            raw = torch.zeros(2, N_POINTS, dtype=torch.float64, requires_grad=True)
            head(name).loss(raw, as_tensor(Rotation.random(2))).backward()
            assert torch.isfinite(raw.grad).all() and raw.grad.abs().sum() > 0


@pytest.mark.parametrize("name", ["pd_net_q", "pd_net_q_sym"])
class TestLogProb:
    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_uniform_prediction_scores_zero(self, name, batch):
        h = head(name)
        lp = h.log_prob(
            torch.zeros(batch, N_POINTS, dtype=torch.float64), as_tensor(Rotation.random(batch))
        )
        torch.testing.assert_close(lp, torch.zeros(batch, dtype=torch.float64))

    def test_density_integrates_to_one_over_haar(self, name):
        # Monte Carlo: E_{R ~ Haar}[exp(log_prob(R))] = 1 (up to the lattice cells' unequal sizes).
        g = torch.Generator().manual_seed(0)
        logits = torch.randn(1, N_POINTS, dtype=torch.float64, generator=g)
        n = 30_000
        density = (
            head(name)
            .log_prob(logits.expand(n, -1), as_tensor(Rotation.random(n, random_state=1)))
            .exp()
        )
        stderr = density.std().item() / math.sqrt(n)
        assert abs(density.mean().item() - 1) < 4 * stderr + 0.01

    def test_concentrated_prediction_matches_the_lattice_cell(self, name):
        # All mass on the lattice point nearest q (and none on -q): the density is n / 2 there.
        h = head(name)
        rot = Rotation.random(1, random_state=5)
        q = torch.tensor(np.roll(rot.as_quat(), 1, -1))
        logits = torch.full((1, N_POINTS), -1e4, dtype=torch.float64)
        logits[0, (q @ h.grid.double().T).argmax()] = 0.0
        assert h.log_prob(logits, as_tensor(rot)).item() == pytest.approx(math.log(N_POINTS / 2))

    def test_uncertainty_range(self, name):
        h = head(name)
        u_uniform = h.uncertainty(torch.zeros(1, N_POINTS, dtype=torch.float64)).item()
        t = h.target_distribution(as_tensor(Rotation.random(1)))
        u_target = h.uncertainty(t.log()).item()
        assert 0 <= u_target < u_uniform <= 1
