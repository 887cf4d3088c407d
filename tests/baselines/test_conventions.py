"""Per-head conventions and numerics against independent references (scipy, closed forms)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation
from scipy.stats import vonmises_fisher

from benchmark.geometry import discrete_vmf, fibonacci_sphere, rotmat_to_quat_paper
from benchmark.models import create_head, distribution_loss_scale

F = 8


def head(name: str, **kwargs):
    torch.manual_seed(0)
    return create_head(name, in_features=F, **kwargs).double()


def scipy_rotations(n: int, seed: int = 0) -> Rotation:
    return Rotation.random(n, random_state=seed)


def as_tensor(rot: Rotation) -> torch.Tensor:
    return torch.tensor(rot.as_matrix(), dtype=torch.float64)


def vmf_on_equirectangular(mu: np.ndarray, kappa: float, size: int = 64) -> tuple:
    """DirectionNet-style grid: colatitude/longitude pixel centres, vMF density, sin weights."""
    colat = (np.arange(size) + 0.5) * np.pi / size
    lon = (np.arange(size) + 0.5) * 2 * np.pi / size
    t, p = np.meshgrid(colat, lon, indexing="ij")
    x = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    return vonmises_fisher(mu, kappa).pdf(x), np.sin(t).reshape(-1)


class TestDistributionLossScale:
    @pytest.mark.parametrize("n_points", [4096, 1024])
    @pytest.mark.parametrize("angle_deg", [10.0, 40.0, 120.0])
    def test_matches_directionnet_loss(self, n_points, angle_deg):
        # DirectionNet: q = f / sum(f sin), loss = mean(sin (q1 - q2)^2) on its 64 x 64 grid.
        a = math.radians(angle_deg)
        mu1, mu2 = np.array([0.0, 0.0, 1.0]), np.array([math.sin(a), 0.0, math.cos(a)])
        (f1, w), (f2, _) = vmf_on_equirectangular(mu1, 10.0), vmf_on_equirectangular(mu2, 10.0)
        q1, q2 = f1 / (f1 * w).sum(), f2 / (f2 * w).sum()
        directionnet = np.mean(w * (q1 - q2) ** 2)
        grid = fibonacci_sphere(n_points, dtype=torch.float64)
        p1 = discrete_vmf(torch.tensor(mu1), 10.0, grid)
        p2 = discrete_vmf(torch.tensor(mu2), 10.0, grid)
        ours = distribution_loss_scale(n_points) * ((p1 - p2) ** 2).sum().item()
        assert ours == pytest.approx(directionnet, rel=0.03)

    def test_closed_form(self):
        assert distribution_loss_scale(4096) == pytest.approx(math.pi / 8192)
        assert distribution_loss_scale(4096, dim=4) == pytest.approx(1 / 4096)


class TestPdReNet:
    def test_convention_target_rows_are_columns_of_R(self):
        h = head("pd_re_net")
        rot = scipy_rotations(4, seed=1)
        target = h.target_distribution(as_tensor(rot))
        grid = fibonacci_sphere(4096, dtype=torch.float64)
        for j in range(3):
            nearest = (as_tensor(rot)[:, :, j] @ grid.T).argmax(-1)
            assert torch.equal(target[:, j].argmax(-1), nearest)

    def test_uniform_prediction_closed_forms(self):
        # log_prob is w.r.t. the normalised Haar measure (issue 10): uniform scores 0. The density
        # itself is checked against the matrix Fisher distribution in test_pd_re_net.py.
        h = head("pd_re_net")
        raw = torch.zeros(2, 3, 4096, dtype=torch.float64)
        lp = h.log_prob(raw, as_tensor(scipy_rotations(2)))
        torch.testing.assert_close(lp, torch.zeros(2, dtype=torch.float64), atol=1e-6, rtol=0)
        assert (h.uncertainty(raw) > 0.999).all()

    def test_loss_vanishes_at_the_target(self):
        h = head("pd_re_net")
        R = as_tensor(scipy_rotations(4, seed=5))
        assert h.loss(torch.log(h.target_distribution(R)), R) < 1e-4
        assert h.loss(torch.zeros(4, 3, 4096, dtype=torch.float64), R) > 100

    def test_alpha_zero_is_eq13(self):
        h = head("pd_re_net", alpha=0.0)
        R = as_tensor(scipy_rotations(2, seed=6))
        raw = torch.randn(2, 3, 4096, dtype=torch.float64)
        p = torch.softmax(raw, -1).numpy()
        grid = fibonacci_sphere(4096, dtype=torch.float64).numpy()
        eq13 = 0.0
        for b in range(2):
            for j in range(3):
                m, r = p[b, j] @ grid, R[b, :, j].numpy()
                eq13 += 1 - m @ r / np.linalg.norm(m)
        # The head keeps its lattice in the module dtype (float32 points here, then cast).
        assert h.loss(raw, R).item() == pytest.approx(eq13 / 2, rel=1e-6)


class TestReNetR:
    def test_decode_is_closest_rotation_like_scipy(self):
        rng = np.random.default_rng(0)
        M = scipy_rotations(5).as_matrix() + 0.05 * rng.standard_normal((5, 3, 3))
        got = head("re_net_r").decode(torch.tensor(M))
        np.testing.assert_allclose(got.numpy(), Rotation.from_matrix(M).as_matrix(), atol=1e-6)

    def test_loss_is_squared_frobenius(self):
        R = as_tensor(scipy_rotations(2))
        raw = R + 0.1
        assert head("re_net_r").loss(raw, R).item() == pytest.approx(9 * 0.01)


class TestReNetE:
    def test_convention_yaw_pitch_roll_order(self):
        # R = Rz(yaw) Rx(pitch) Ry(roll): scipy's intrinsic "ZXY".
        ypr = np.array([[30.0, -20.0, 10.0], [-170.0, 45.0, -5.0]])
        raw = torch.tensor(np.radians(ypr))
        expected = Rotation.from_euler("ZXY", ypr, degrees=True).as_matrix()
        np.testing.assert_allclose(head("re_net_e").decode(raw).numpy(), expected, atol=1e-12)

    def test_loss_has_no_wrapping(self):
        # A yaw of +179 deg predicted as -179 deg costs (358 deg)^2, not (2 deg)^2.
        R = as_tensor(Rotation.from_euler("ZXY", [[179.0, 30.0, 0.0]], degrees=True))
        raw = torch.tensor(np.radians([[-179.0, 30.0, 0.0]]))
        assert head("re_net_e").loss(raw, R).item() == pytest.approx(math.radians(358) ** 2)


class TestReNetQ:
    def test_convention_w_first(self):
        q = scipy_rotations(3, seed=2).as_quat()  # scipy: (x, y, z, w)
        raw = torch.tensor(np.roll(q, 1, axis=-1) * 3.0)  # (w, x, y, z), not normalised
        expected = Rotation.from_quat(q).as_matrix()
        np.testing.assert_allclose(head("re_net_q").decode(raw).numpy(), expected, atol=1e-12)

    def test_label_is_eq3_without_sign_folding(self):
        R = as_tensor(scipy_rotations(3, seed=4))
        label = rotmat_to_quat_paper(R)
        h = head("re_net_q")
        assert h.loss(label, R).item() == pytest.approx(0.0, abs=1e-20)
        assert h.loss(-label, R).item() == pytest.approx(4.0)  # |(-q) - q|^2 = 4


class TestReNetRv:
    def test_decode_and_label_match_scipy(self):
        rot = scipy_rotations(4, seed=3)
        raw = torch.tensor(rot.as_rotvec())
        h = head("re_net_rv")
        np.testing.assert_allclose(h.decode(raw).numpy(), rot.as_matrix(), atol=1e-12)
        assert h.loss(raw, as_tensor(rot)).item() == pytest.approx(0.0, abs=1e-20)


class TestPdNetRv:
    # The axis/angle conventions and the angle distribution: tests/baselines/test_pd_net_rv.py.
    def test_identity_has_a_defined_axis(self):
        h = head("pd_net_rv")
        target = h.target_distribution(torch.eye(3, dtype=torch.float64)[None])
        torch.testing.assert_close(
            h.decode_distribution(target)[0], torch.eye(3, dtype=torch.float64)
        )


# Pd-Net-E and Pd-Net-Q (paper target and the symmetric pd_net_q_sym): test_pd_net_e.py,
# test_pd_net_q.py.


class TestReNetT:
    def test_scale_statistics_are_the_standardised_lengths_mean_and_std(self):
        # Version 3: the scale branch regresses |u|, u = (T - mean) / std per axis (issue 10).
        h = head("re_net_t")
        T = torch.randn(2000, 3, dtype=torch.float64) * torch.tensor([80.0, 40, 5]) + 30
        h.fit_statistics(T)
        u = (T.numpy() - T.numpy().mean(0)) / T.numpy().std(0)
        r = np.linalg.norm(u, axis=-1)
        assert h.scale_mean.item() == pytest.approx(r.mean())
        assert h.scale_std.item() == pytest.approx(r.std())
