"""Rotation conversions against scipy's Rotation (an independent implementation)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from benchmark.geometry import (
    SAT_Q_N,
    SAT_R_N,
    angle_difference,
    euler_to_rotmat,
    quat_conjugate,
    quat_multiply,
    quat_to_rotmat,
    relative_rotation,
    rotmat_to_euler,
    rotmat_to_quat,
    rotmat_to_quat_paper,
    rotmat_to_rotvec,
    rotvec_to_rotmat,
)

BATCHES = [1, 3, 8]
DTYPES = [torch.float32, torch.float64]
TOL = {torch.float32: 2e-5, torch.float64: 1e-10}


def random_euler(batch: int, dtype: torch.dtype, seed: int = 0) -> tuple[torch.Tensor, ...]:
    g = torch.Generator().manual_seed(seed)
    yaw = (torch.rand(batch, generator=g, dtype=torch.float64) * 2 - 1) * math.pi
    pitch = (torch.rand(batch, generator=g, dtype=torch.float64) * 2 - 1) * (math.pi / 2 - 1e-3)
    roll = (torch.rand(batch, generator=g, dtype=torch.float64) * 2 - 1) * math.pi
    return yaw.to(dtype), pitch.to(dtype), roll.to(dtype)


def scipy_matrix(yaw, pitch, roll) -> np.ndarray:
    # R = Rz(yaw) Rx(pitch) Ry(roll) is scipy's intrinsic "ZXY" sequence, angles in that order.
    angles = np.stack([t.double().numpy() for t in (yaw, pitch, roll)], -1)
    return Rotation.from_euler("ZXY", angles).as_matrix()


def random_rotmats(batch: int, dtype: torch.dtype, seed: int = 0) -> torch.Tensor:
    return torch.from_numpy(Rotation.random(batch, random_state=seed).as_matrix()).to(dtype)


class TestEulerToRotmat:
    @pytest.mark.parametrize("batch", BATCHES)
    @pytest.mark.parametrize("dtype", DTYPES)
    def test_matches_scipy(self, batch, dtype):
        yaw, pitch, roll = random_euler(batch, dtype)
        R = euler_to_rotmat(yaw, pitch, roll)
        assert R.shape == (batch, 3, 3) and R.dtype == dtype
        np.testing.assert_allclose(
            R.double().numpy(), scipy_matrix(yaw, pitch, roll), atol=TOL[dtype]
        )

    def test_convention_columns_are_body_axes_in_enu(self):
        z = torch.tensor(0.0, dtype=torch.float64)
        # yaw 0: body forward (+y) is north, right (+x) is east, up is up.
        R = euler_to_rotmat(z, z, z)
        torch.testing.assert_close(R, torch.eye(3, dtype=torch.float64))
        # yaw +90 deg is counter-clockwise seen from above: forward points west.
        R = euler_to_rotmat(torch.tensor(math.pi / 2, dtype=torch.float64), z, z)
        torch.testing.assert_close(R[:, 1], torch.tensor([-1.0, 0, 0], dtype=torch.float64))
        # pitch +30 deg raises the nose: forward gains a positive up component sin(30).
        R = euler_to_rotmat(z, torch.tensor(math.radians(30), dtype=torch.float64), z)
        assert R[2, 1] == pytest.approx(0.5)
        # roll +20 deg lowers the right wing: body x gains a negative up component.
        R = euler_to_rotmat(z, z, torch.tensor(math.radians(20), dtype=torch.float64))
        assert R[2, 0] == pytest.approx(-math.sin(math.radians(20)))

    def test_convention_composition_order(self):
        yaw, pitch, roll = (torch.tensor(a, dtype=torch.float64) for a in (0.3, -0.4, 0.2))
        z = torch.tensor(0.0, dtype=torch.float64)
        Rz = euler_to_rotmat(yaw, z, z)
        Rx = euler_to_rotmat(z, pitch, z)
        Ry = euler_to_rotmat(z, z, roll)
        torch.testing.assert_close(euler_to_rotmat(yaw, pitch, roll), Rz @ Rx @ Ry)

    def test_paper_eq1_entries(self):
        # Spot-check entries printed in Eq. 1: R12 = -s_psi c_theta, R32 = s_theta.
        yaw, pitch, roll = (torch.tensor(a, dtype=torch.float64) for a in (1.1, -0.7, 0.3))
        R = euler_to_rotmat(yaw, pitch, roll)
        assert R[0, 1] == pytest.approx(-math.sin(1.1) * math.cos(-0.7))
        assert R[2, 1] == pytest.approx(math.sin(-0.7))
        assert R[2, 2] == pytest.approx(math.cos(-0.7) * math.cos(0.3))

    def test_gradcheck(self):
        args = [a.requires_grad_() for a in random_euler(3, torch.float64)]
        assert torch.autograd.gradcheck(euler_to_rotmat, args)

    def test_broadcasting(self):
        R = euler_to_rotmat(torch.zeros(4, 1), torch.zeros(1, 5), torch.tensor(0.1))
        assert R.shape == (4, 5, 3, 3)

    def test_rejects_nonfinite(self):
        with pytest.raises(ValueError, match=r"pitch.*non-finite"):
            euler_to_rotmat(torch.zeros(2), torch.tensor([0.0, float("nan")]), torch.zeros(2))


class TestRotmatToEuler:
    @pytest.mark.parametrize("batch", BATCHES)
    @pytest.mark.parametrize("dtype", DTYPES)
    def test_matches_scipy(self, batch, dtype):
        R = random_rotmats(batch, dtype)
        yaw, pitch, roll = rotmat_to_euler(R)
        ref = Rotation.from_matrix(R.double().numpy()).as_euler("ZXY")
        for got, want in zip((yaw, pitch, roll), ref.T, strict=True):
            diff = angle_difference(got.double(), torch.from_numpy(want))
            assert diff.abs().max() < 10 * TOL[dtype]

    @pytest.mark.parametrize("dtype", DTYPES)
    def test_round_trip(self, dtype):
        yaw, pitch, roll = random_euler(8, dtype, seed=3)
        out = rotmat_to_euler(euler_to_rotmat(yaw, pitch, roll))
        for got, want in zip(out, (yaw, pitch, roll), strict=True):
            assert angle_difference(got, want).abs().max() < 10 * TOL[dtype]

    def test_convention_ranges(self):
        yaw, pitch, roll = rotmat_to_euler(random_rotmats(200, torch.float64))
        assert pitch.abs().max() <= math.pi / 2
        assert yaw.min() > -math.pi and yaw.max() <= math.pi
        assert roll.min() > -math.pi and roll.max() <= math.pi

    @pytest.mark.parametrize("pitch_deg", [90.0, -90.0])
    def test_gimbal_lock_is_defined_and_reconstructs(self, pitch_deg):
        yaw = torch.tensor([0.3, -2.0], dtype=torch.float64)
        roll = torch.tensor([0.5, 1.0], dtype=torch.float64)
        pitch = torch.full((2,), math.radians(pitch_deg), dtype=torch.float64)
        R = euler_to_rotmat(yaw, pitch, roll)
        y2, p2, r2 = rotmat_to_euler(R)
        assert torch.all(r2 == 0)
        torch.testing.assert_close(euler_to_rotmat(y2, p2, r2), R)

    def test_gradcheck(self):
        R = euler_to_rotmat(*random_euler(3, torch.float64)).requires_grad_()
        assert torch.autograd.gradcheck(lambda m: torch.stack(rotmat_to_euler(m)), (R,))

    def test_rejects_bad_shape(self):
        with pytest.raises(ValueError, match=r"\(\.\.\., 3, 3\), got \(2, 4\)"):
            rotmat_to_euler(torch.zeros(2, 4))


class TestRotmatToQuat:
    @pytest.mark.parametrize("batch", BATCHES)
    @pytest.mark.parametrize("dtype", DTYPES)
    def test_matches_scipy(self, batch, dtype):
        R = random_rotmats(batch, dtype, seed=1)
        q = rotmat_to_quat(R)
        ref = Rotation.from_matrix(R.double().numpy()).as_quat(scalar_first=True)
        ref = ref * np.where(ref[:, :1] < 0, -1.0, 1.0)
        np.testing.assert_allclose(q.double().numpy(), ref, atol=10 * TOL[dtype])

    def test_convention_w_first_nonnegative(self):
        q = rotmat_to_quat(random_rotmats(500, torch.float64, seed=2))
        assert torch.all(q[:, 0] >= 0)
        # 90 deg about +z: (cos 45, 0, 0, sin 45), scalar first.
        Rz = torch.tensor([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]], dtype=torch.float64)
        expected = torch.tensor([math.sqrt(0.5), 0, 0, math.sqrt(0.5)], dtype=torch.float64)
        torch.testing.assert_close(rotmat_to_quat(Rz), expected)

    @pytest.mark.parametrize("axis", [0, 1, 2])
    def test_near_pi_is_accurate(self, axis):
        rotvec = np.zeros(3)
        rotvec[axis] = math.pi - 1e-9
        R = torch.from_numpy(Rotation.from_rotvec(rotvec).as_matrix())
        torch.testing.assert_close(quat_to_rotmat(rotmat_to_quat(R)), R)

    def test_gradcheck(self):
        R = random_rotmats(3, torch.float64, seed=4).requires_grad_()
        assert torch.autograd.gradcheck(rotmat_to_quat, (R,))


class TestRotmatToQuatPaper:
    @pytest.mark.parametrize("dtype", DTYPES)
    def test_represents_same_rotation(self, dtype):
        R = random_rotmats(300, dtype, seed=5)
        q = rotmat_to_quat_paper(R)
        torch.testing.assert_close(quat_to_rotmat(q), R, atol=10 * TOL[dtype], rtol=0)
        torch.testing.assert_close(q.norm(dim=-1), torch.ones(300, dtype=dtype))

    def test_case_selection_follows_paper_order(self):
        # Each case's pivot component is the one divided by; the paper's conditions guarantee it
        # is >= 1/2 in magnitude and keep its sign positive.
        R = random_rotmats(1000, torch.float64, seed=6)
        q = rotmat_to_quat_paper(R)
        r11, r22, r33 = R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]
        case_x = r11 >= r22 + r33
        case_y = ~case_x & (r22 >= r11 + r33)
        case_z = ~case_x & ~case_y & (r33 >= r11 + r22)
        case_w = ~(case_x | case_y | case_z)
        for mask, comp in ((case_w, 0), (case_x, 1), (case_y, 2), (case_z, 3)):
            assert mask.any()
            assert torch.all(q[mask, comp] >= 0.5 - 1e-12)

    def test_jumps_where_case_changes(self):
        # Paper Fig. 2 setting: pitch -20 deg, roll -10 deg; the paper places a jump near -63 deg.
        heading = torch.deg2rad(torch.tensor([-63.2, -62.9], dtype=torch.float64))
        R = euler_to_rotmat(
            heading,
            torch.tensor(math.radians(-20.0)).double(),
            torch.tensor(math.radians(-10.0)).double(),
        )
        q = rotmat_to_quat_paper(R)
        assert (q[0] - q[1]).abs().max() > 0.5  # a sign flip, not a small step
        torch.testing.assert_close(rotmat_to_quat(R)[0], rotmat_to_quat(R)[1], atol=0.01, rtol=0)


class TestQuatToRotmat:
    @pytest.mark.parametrize("batch", BATCHES)
    @pytest.mark.parametrize("dtype", DTYPES)
    def test_matches_scipy(self, batch, dtype):
        q = torch.from_numpy(Rotation.random(batch, random_state=7).as_quat(scalar_first=True))
        R = quat_to_rotmat(q.to(dtype))
        ref = Rotation.from_quat(q.numpy(), scalar_first=True).as_matrix()
        np.testing.assert_allclose(R.double().numpy(), ref, atol=TOL[dtype])

    def test_normalises_and_ignores_sign(self):
        q = torch.tensor([0.3, -0.2, 0.5, 0.1], dtype=torch.float64)
        torch.testing.assert_close(quat_to_rotmat(3 * q), quat_to_rotmat(-q))

    def test_gradcheck(self):
        q = torch.randn(3, 4, dtype=torch.float64, requires_grad=True)
        assert torch.autograd.gradcheck(quat_to_rotmat, (q,))

    def test_rejects_zero_and_bad_shape(self):
        with pytest.raises(ValueError, match="zero quaternion"):
            quat_to_rotmat(torch.zeros(2, 4))
        with pytest.raises(ValueError, match=r"got \(3, 3\)"):
            quat_to_rotmat(torch.zeros(3, 3))


class TestQuatMultiply:
    @pytest.mark.parametrize("batch", BATCHES)
    def test_matches_scipy_composition(self, batch):
        a = Rotation.random(batch, random_state=8)
        b = Rotation.random(batch, random_state=9)
        p = torch.from_numpy(a.as_quat(scalar_first=True))
        q = torch.from_numpy(b.as_quat(scalar_first=True))
        got = quat_to_rotmat(quat_multiply(p, q)).numpy()
        np.testing.assert_allclose(got, (a * b).as_matrix(), atol=1e-12)

    def test_convention_hamilton(self):
        i = torch.tensor([0.0, 1, 0, 0])
        j = torch.tensor([0.0, 0, 1, 0])
        torch.testing.assert_close(quat_multiply(i, j), torch.tensor([0.0, 0, 0, 1]))  # ij = k

    def test_gradcheck(self):
        p, q = (torch.randn(3, 4, dtype=torch.float64, requires_grad=True) for _ in range(2))
        assert torch.autograd.gradcheck(quat_multiply, (p, q))


class TestQuatConjugate:
    @pytest.mark.parametrize("batch", BATCHES)
    def test_is_inverse(self, batch):
        q = torch.from_numpy(Rotation.random(batch, random_state=10).as_quat(scalar_first=True))
        ident = quat_multiply(q, quat_conjugate(q))
        expected = torch.zeros(batch, 4, dtype=torch.float64)
        expected[:, 0] = 1
        torch.testing.assert_close(ident, expected)

    def test_paper_eq4_relative_quaternion(self):
        # Eq. 4: Q_uav^sat = Q_uav^n (x) conj(Q_sat^n) is the quaternion of Eq. 2's matrix.
        R = random_rotmats(5, torch.float64, seed=11)
        q = quat_multiply(rotmat_to_quat(R), quat_conjugate(SAT_Q_N))
        torch.testing.assert_close(quat_to_rotmat(q), relative_rotation(R, SAT_R_N))


class TestRotvecToRotmat:
    @pytest.mark.parametrize("batch", BATCHES)
    @pytest.mark.parametrize("dtype", DTYPES)
    def test_matches_scipy(self, batch, dtype):
        v = torch.from_numpy(Rotation.random(batch, random_state=12).as_rotvec())
        R = rotvec_to_rotmat(v.to(dtype))
        np.testing.assert_allclose(
            R.double().numpy(), Rotation.from_rotvec(v.numpy()).as_matrix(), atol=TOL[dtype]
        )

    @pytest.mark.parametrize("scale", [0.0, 1e-9, 1e-4, 1e-3])
    def test_near_zero(self, scale):
        v = torch.tensor([[0.3, -0.5, 0.8]], dtype=torch.float64) * scale
        ref = Rotation.from_rotvec(v.numpy()).as_matrix()
        np.testing.assert_allclose(rotvec_to_rotmat(v).numpy(), ref, atol=1e-14)

    def test_gradcheck_including_zero(self):
        v = torch.tensor(
            [[0.0, 0.0, 0.0], [1e-5, 2e-5, -1e-5], [1.0, -2.0, 0.5]], dtype=torch.float64
        )
        assert torch.autograd.gradcheck(rotvec_to_rotmat, (v.requires_grad_(),))


class TestRotmatToRotvec:
    @pytest.mark.parametrize("batch", BATCHES)
    @pytest.mark.parametrize("dtype", DTYPES)
    def test_matches_scipy(self, batch, dtype):
        R = random_rotmats(batch, dtype, seed=13)
        ref = Rotation.from_matrix(R.double().numpy()).as_rotvec()
        np.testing.assert_allclose(rotmat_to_rotvec(R).double().numpy(), ref, atol=20 * TOL[dtype])

    @pytest.mark.parametrize("angle", [0.0, 1e-8, 1e-3, math.pi - 1e-6, math.pi])
    def test_near_zero_and_pi(self, angle):
        axis = np.array([0.2, -0.6, 0.77])
        axis /= np.linalg.norm(axis)
        R = torch.from_numpy(Rotation.from_rotvec(axis * angle).as_matrix())
        v = rotmat_to_rotvec(R)
        assert v.norm().item() == pytest.approx(angle, abs=1e-9)
        torch.testing.assert_close(rotvec_to_rotmat(v), R)

    def test_gradcheck(self):
        R = random_rotmats(3, torch.float64, seed=14).requires_grad_()
        assert torch.autograd.gradcheck(rotmat_to_rotvec, (R,))


class TestRelativeRotation:
    @pytest.mark.parametrize("batch", BATCHES)
    def test_eq2_against_scipy(self, batch):
        a = Rotation.random(batch, random_state=15)
        sat = Rotation.from_euler("ZXY", [0.0, -90.0, 0.0], degrees=True)
        got = relative_rotation(torch.from_numpy(a.as_matrix()), SAT_R_N)
        np.testing.assert_allclose(got.numpy(), (a * sat.inv()).as_matrix(), atol=1e-12)

    def test_convention_satellite_camera(self):
        # Eq. 5: pitch -90 deg, heading 0. The camera (body +y) looks down; the image top
        # (body +z) points north.
        torch.testing.assert_close(SAT_R_N[:, 1], torch.tensor([0.0, 0, -1], dtype=torch.float64))
        torch.testing.assert_close(SAT_R_N[:, 2], torch.tensor([0.0, 1, 0], dtype=torch.float64))
        z = torch.tensor(0.0, dtype=torch.float64)
        torch.testing.assert_close(
            euler_to_rotmat(z, torch.tensor(-math.pi / 2).double(), z), SAT_R_N
        )
        # The paper's printed Q_sat^n = [-0.7071, 0.7071, 0, 0] is the same rotation.
        paper_q = torch.tensor([-0.7071, 0.7071, 0.0, 0.0], dtype=torch.float64)
        torch.testing.assert_close(quat_to_rotmat(paper_q), SAT_R_N)
        torch.testing.assert_close(quat_to_rotmat(SAT_Q_N), SAT_R_N)

    def test_inverse_recovers_uav_attitude(self):
        R = random_rotmats(4, torch.float64, seed=16)
        torch.testing.assert_close(relative_rotation(R, SAT_R_N) @ SAT_R_N, R)
