"""Regression heads near the singular and boundary configurations of their representations.

Per head: decoding against scipy / numpy, perturbed (not exact) labels near each boundary decode
close to the rotation, the inherent discontinuity is shown as a ``test_convention_*`` (it is what
the comparison measures, so it stays), and float64 gradcheck. Level flight seen against the nadir
satellite camera has a relative pitch near 90 deg (gimbal lock of Eq. 1) and, over all headings,
rotation angles up to 180 deg and Eq. 3 case switches.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from benchmark.geometry import (
    SAT_R_N,
    euler_to_rotmat,
    geodesic_distance,
    relative_rotation,
    rotmat_to_euler,
    rotmat_to_quat_paper,
    rotmat_to_rotvec,
)
from benchmark.models import create_head

F = 8
D = torch.float64
BATCHES = [1, 3, 8]


def head(name: str):
    torch.manual_seed(0)
    return create_head(name, in_features=F).double()


def noise(shape, scale: float, seed: int) -> torch.Tensor:
    return scale * torch.randn(shape, generator=torch.Generator().manual_seed(seed), dtype=D)


def level_flight(
    batch: int, uav_pitch_deg: float, seed: int, roll_std: float = 0.01
) -> torch.Tensor:
    """Relative attitudes R_uav^sat of level flight (UAV roll ~ N(0, roll_std^2) rad) at random
    headings: (B, 3, 3)."""
    g = torch.Generator().manual_seed(seed)
    yaw = (torch.rand(batch, generator=g, dtype=D) * 2 - 1) * math.pi
    pitch = torch.full((batch,), math.radians(uav_pitch_deg), dtype=D)
    roll = torch.randn(batch, generator=g, dtype=D) * roll_std
    return relative_rotation(euler_to_rotmat(yaw, pitch, roll), SAT_R_N.to(D))


def euler_label(R: torch.Tensor) -> torch.Tensor:
    return torch.stack(rotmat_to_euler(R), dim=-1)


class TestReNetE:
    @pytest.mark.parametrize("batch", BATCHES)
    def test_decode_matches_scipy(self, batch):
        raw = noise((batch, 3), 2.0, seed=batch)
        expected = Rotation.from_euler("ZXY", raw.numpy()).as_matrix()  # Rz(yaw) Rx(pitch) Ry(roll)
        np.testing.assert_allclose(head("re_net_e").decode(raw).numpy(), expected, atol=1e-12)

    @pytest.mark.parametrize("batch", BATCHES)
    @pytest.mark.parametrize("uav_pitch_deg", [-2.0, -0.5, 0.0, 0.5])
    def test_perturbed_label_near_gimbal_lock(self, batch, uav_pitch_deg):
        R = level_flight(batch, uav_pitch_deg, seed=batch)
        raw = euler_label(R) + noise((batch, 3), 0.01, seed=10 + batch)
        err = geodesic_distance(head("re_net_e").decode(raw), R)
        assert err.max() < 0.03  # |dR| <= |dyaw| + |dpitch| + |droll|

    @pytest.mark.parametrize("batch", BATCHES)
    def test_perturbed_label_at_the_yaw_wrap(self, batch):
        sign = torch.where(torch.arange(batch) % 2 == 0, 1.0, -1.0).to(D)
        yaw = sign * (math.pi - 1e-4)
        R = euler_to_rotmat(yaw, torch.full_like(yaw, 0.3), torch.full_like(yaw, -0.2))
        raw = euler_label(R) + noise((batch, 3), 0.01, seed=20 + batch)
        assert geodesic_distance(head("re_net_e").decode(raw), R).max() < 0.03

    def test_convention_inherent_yaw_wrap(self):
        # 0.2 deg apart across yaw = +-180: labels ~2 pi apart (inherent, kept).
        a = torch.tensor([math.pi - 0.0017, -math.pi + 0.0017], dtype=D)
        R = euler_to_rotmat(a, torch.zeros_like(a), torch.zeros_like(a))
        assert geodesic_distance(R[0], R[1]) < math.radians(0.25)
        yaw = euler_label(R)[:, 0]
        assert (yaw[0] - yaw[1]).abs() > 6.0

    def test_convention_inherent_gimbal_lock_in_level_flight(self):
        # UAV pitch +0.25 and -0.25 deg: 0.5 deg apart, relative yaw labels ~180 deg apart.
        up = level_flight(1, 0.25, seed=3, roll_std=0.0)
        down = level_flight(1, -0.25, seed=3, roll_std=0.0)
        assert geodesic_distance(up, down).item() == pytest.approx(math.radians(0.5), abs=1e-3)
        labels_up, labels_down = euler_label(up)[0], euler_label(down)[0]
        assert math.degrees(float(labels_up[1])) == pytest.approx(89.75, abs=0.02)
        dyaw = math.remainder(float(labels_up[0] - labels_down[0]), 2 * math.pi)
        assert abs(math.degrees(dyaw)) == pytest.approx(180.0, abs=1.0)

    @pytest.mark.parametrize("batch", BATCHES)
    def test_loss_vanishes_at_the_label(self, batch):
        R = level_flight(batch, -1.0, seed=batch)
        assert head("re_net_e").loss(euler_label(R), R).item() < 1e-20

    def test_gradcheck_float64(self):
        h = head("re_net_e")
        R = level_flight(3, -1.0, seed=4)
        raw = noise((3, 3), 1.0, seed=5).requires_grad_()
        assert torch.autograd.gradcheck(h.decode, (raw,))
        assert torch.autograd.gradcheck(lambda x: h.loss(x, R), (raw,))


def yaw_sweep_at_pitch_89(n: int = 3601) -> torch.Tensor:
    yaw = torch.linspace(-math.pi, math.pi, n, dtype=D)
    return euler_to_rotmat(yaw, torch.full_like(yaw, math.radians(89)), torch.zeros_like(yaw))


class TestReNetQ:
    @pytest.mark.parametrize("batch", BATCHES)
    def test_decode_matches_scipy(self, batch):
        raw = noise((batch, 4), 1.0, seed=batch)
        expected = Rotation.from_quat(raw[:, [1, 2, 3, 0]].numpy()).as_matrix()  # scalar-last
        np.testing.assert_allclose(head("re_net_q").decode(raw).numpy(), expected, atol=1e-12)

    def test_convention_inherent_case_switch_jump(self):
        # Along the yaw sweep at relative pitch 89 deg the Eq. 3 label jumps to near -q once,
        # between rotations 0.1 deg apart (the paper's discontinuity, kept).
        R = yaw_sweep_at_pitch_89()
        q = rotmat_to_quat_paper(R)
        jumps = ((q[1:] - q[:-1]).norm(dim=-1) > 1.0).nonzero().flatten()
        assert len(jumps) == 1
        k = int(jumps[0])
        assert geodesic_distance(R[k], R[k + 1]) < math.radians(0.11)

    @pytest.mark.parametrize("batch", BATCHES)
    def test_perturbed_labels_at_the_case_switch_decode_close(self, batch):
        R = yaw_sweep_at_pitch_89()
        q = rotmat_to_quat_paper(R)
        k = int(((q[1:] - q[:-1]).norm(dim=-1) > 1.0).nonzero()[0])
        idx = torch.arange(k - batch // 2, k - batch // 2 + batch).clamp(0, len(R) - 1)
        raw = q[idx] + noise((batch, 4), 0.01, seed=batch)
        # angle error ~ 2 x the noise orthogonal to q (3 components of 0.01): < 0.1 rad
        assert geodesic_distance(head("re_net_q").decode(raw), R[idx]).max() < 0.1

    @pytest.mark.parametrize("batch", BATCHES)
    def test_loss_vanishes_at_the_label(self, batch):
        R = level_flight(batch, -1.0, seed=batch)
        assert head("re_net_q").loss(rotmat_to_quat_paper(R), R).item() < 1e-20

    def test_gradcheck_float64(self):
        h = head("re_net_q")
        R = level_flight(3, -1.0, seed=6)
        raw = noise((3, 4), 1.0, seed=7).requires_grad_()
        assert torch.autograd.gradcheck(h.decode, (raw,))
        assert torch.autograd.gradcheck(lambda x: h.loss(x, R), (raw,))


class TestReNetRv:
    @pytest.mark.parametrize("batch", BATCHES)
    def test_decode_matches_scipy(self, batch):
        raw = noise((batch, 3), 1.5, seed=batch)
        expected = Rotation.from_rotvec(raw.numpy()).as_matrix()
        np.testing.assert_allclose(head("re_net_rv").decode(raw).numpy(), expected, atol=1e-12)

    @pytest.mark.parametrize("batch", BATCHES)
    @pytest.mark.parametrize("angle", [1e-7, 0.5, math.pi - 1e-6])
    def test_perturbed_label_near_zero_and_pi(self, batch, angle):
        axes = noise((batch, 3), 1.0, seed=batch)
        axes = axes / axes.norm(dim=-1, keepdim=True)
        R = torch.tensor(Rotation.from_rotvec((axes * angle).numpy()).as_matrix())
        label = rotmat_to_rotvec(R)
        h = head("re_net_rv")
        assert geodesic_distance(h.decode(label), R).max() < 1e-6  # label decodes to R
        raw = label + noise((batch, 3), 0.01, seed=30 + batch)
        assert geodesic_distance(h.decode(raw), R).max() < 0.03

    def test_convention_inherent_flip_at_pi(self):
        # Rotations about one axis by pi -/+ 0.001 rad: 0.002 rad apart, labels ~2 pi apart.
        axis = np.array([0.6, 0.0, 0.8])
        R = torch.tensor(
            Rotation.from_rotvec([axis * (math.pi - 1e-3), axis * (math.pi + 1e-3)]).as_matrix()
        )
        assert geodesic_distance(R[0], R[1]).item() == pytest.approx(2e-3, rel=1e-3)
        label = rotmat_to_rotvec(R)
        assert (label[0] - label[1]).norm().item() == pytest.approx(2 * math.pi - 2e-3, abs=1e-6)

    def test_convention_level_flight_reaches_angle_pi(self):
        # Over all headings, level-flight relative rotations reach the flip at pi.
        yaw = torch.linspace(-math.pi, math.pi, 721, dtype=D)
        R_uav = euler_to_rotmat(yaw, torch.full_like(yaw, math.radians(-1)), torch.zeros_like(yaw))
        angles = rotmat_to_rotvec(relative_rotation(R_uav, SAT_R_N.to(D))).norm(dim=-1)
        assert angles.max().item() == pytest.approx(math.pi, abs=1e-3)

    def test_gradcheck_float64(self):
        h = head("re_net_rv")
        R = level_flight(3, -1.0, seed=8)
        raw = torch.cat([noise((2, 3), 1.0, seed=9), noise((1, 3), 1e-5, seed=10)]).requires_grad_()
        assert torch.autograd.gradcheck(h.decode, (raw,))
        assert torch.autograd.gradcheck(lambda x: h.loss(x, R), (raw,))


def numpy_procrustes(M: np.ndarray) -> np.ndarray:
    out = []
    for m in M:
        u, _, vt = np.linalg.svd(m)
        out.append(u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))]) @ vt)
    return np.stack(out)


class TestReNetR:
    @pytest.mark.parametrize("batch", BATCHES)
    def test_decode_matches_numpy_procrustes(self, batch):
        raw = noise((batch, 3, 3), 1.0, seed=batch)
        expected = numpy_procrustes(raw.numpy())
        np.testing.assert_allclose(head("re_net_r").decode(raw).numpy(), expected, atol=1e-10)

    @pytest.mark.parametrize("batch", BATCHES)
    @pytest.mark.parametrize("uav_pitch_deg", [-20.0, -0.5, 0.5])
    def test_perturbed_label_decodes_close(self, batch, uav_pitch_deg):
        # Nothing special at level flight (no gimbal lock in 9 numbers).
        R = level_flight(batch, uav_pitch_deg, seed=batch)
        raw = R + noise((batch, 3, 3), 0.01, seed=40 + batch)
        assert geodesic_distance(head("re_net_r").decode(raw), R).max() < 0.03

    def test_convention_reflected_output_projects_to_a_rotation(self):
        # A near-reflection (det < 0) is projected to the closest det +1 matrix, as numpy does.
        raw = level_flight(2, -1.0, seed=11) @ torch.diag(torch.tensor([1.0, 1.0, -1.0], dtype=D))
        raw = raw + noise((2, 3, 3), 0.01, seed=12)
        out = head("re_net_r").decode(raw)
        torch.testing.assert_close(torch.linalg.det(out), torch.ones(2, dtype=D))
        np.testing.assert_allclose(out.numpy(), numpy_procrustes(raw.numpy()), atol=1e-10)

    @pytest.mark.parametrize("batch", BATCHES)
    def test_loss_is_frobenius(self, batch):
        R = level_flight(batch, -1.0, seed=batch)
        raw = noise((batch, 3, 3), 1.0, seed=50 + batch)
        expected = ((raw - R) ** 2).sum(dim=(-1, -2)).mean()
        torch.testing.assert_close(head("re_net_r").loss(raw, R), expected)

    def test_gradcheck_float64(self):
        h = head("re_net_r")
        raw = noise((3, 3, 3), 1.0, seed=13).requires_grad_()
        assert torch.autograd.gradcheck(h.decode, (raw,))


class TestTranslationRegression:
    @pytest.mark.parametrize("batch", BATCHES)
    def test_decode_unstandardises_and_loss_is_standardised(self, batch):
        h = create_head("regression", in_features=F).double()
        mean, std = torch.tensor([5.0, -3.0, -900.0]), torch.tensor([150.0, 140.0, 100.0])
        h.set_statistics(mean, std)
        raw = noise((batch, 3), 1.0, seed=batch)
        T = raw * std.double() + mean.double()
        torch.testing.assert_close(h.decode(raw), T)
        assert h.loss(raw, T).item() < 1e-20
        shifted = T + torch.tensor([150.0, 0.0, 0.0], dtype=D)  # one std along dE: loss 1
        assert h.loss(raw, shifted).item() == pytest.approx(1.0)

    def test_gradcheck_float64(self):
        h = create_head("regression", in_features=F).double()
        h.set_statistics(torch.tensor([0.0, 0.0, -900.0]), torch.tensor([150.0, 150.0, 100.0]))
        T = noise((3, 3), 100.0, seed=14)
        raw = noise((3, 3), 1.0, seed=15).requires_grad_()
        assert torch.autograd.gradcheck(lambda x: h.loss(x, T), (raw,))
