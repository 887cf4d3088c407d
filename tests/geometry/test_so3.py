"""SO(3) projection, Gram-Schmidt and distances against scipy and closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from benchmark.geometry import (
    angle_difference,
    geodesic_distance,
    gram_schmidt,
    special_orthogonalize,
)

BATCHES = [1, 3, 8]
DTYPES = [torch.float32, torch.float64]


class TestSpecialOrthogonalize:
    @pytest.mark.parametrize("batch", BATCHES)
    @pytest.mark.parametrize("dtype", DTYPES)
    def test_matches_scipy_nearest_rotation(self, batch, dtype):
        # scipy's from_matrix projects a non-orthogonal matrix to the closest rotation (Markley's
        # quaternion method): an independent algorithm for the same optimum.
        M = torch.randn(
            batch, 3, 3, generator=torch.Generator().manual_seed(batch), dtype=torch.float64
        )
        M = M * torch.linalg.det(M).sign()[:, None, None]  # scipy refuses det < 0: see below
        R = special_orthogonalize(M.to(dtype))
        ref = Rotation.from_matrix(M.numpy()).as_matrix()
        np.testing.assert_allclose(
            R.double().numpy(), ref, atol=1e-5 if dtype == torch.float32 else 1e-9
        )

    @pytest.mark.parametrize("dtype", DTYPES)
    def test_orthonormal_det_plus_one_even_for_reflections(self, dtype):
        M = torch.randn(50, 3, 3, dtype=dtype)
        M[:25] = -M[:25].abs()  # plenty of negative determinants
        R = special_orthogonalize(M)
        eye = torch.eye(3, dtype=dtype).expand(50, 3, 3)
        torch.testing.assert_close(R.transpose(-1, -2) @ R, eye, atol=1e-5, rtol=0)
        torch.testing.assert_close(
            torch.linalg.det(R), torch.ones(50, dtype=dtype), atol=1e-5, rtol=0
        )

    def test_negative_determinant_is_optimal(self):
        # For det M < 0 the answer is the rotation maximising tr(R^T M) (not the nearest
        # orthogonal matrix, which is a reflection). Check against 20000 random rotations and
        # against small perturbations in every direction.
        M = torch.tensor(
            [[-0.8, 1.6, 0.8], [0.5, -1.5, -1.9], [0.25, -0.09, -0.35]], dtype=torch.float64
        )
        assert torch.linalg.det(M) < 0
        R = special_orthogonalize(M)
        best = torch.trace(R.T @ M)
        Q = torch.from_numpy(Rotation.random(20000, random_state=3).as_matrix())
        assert (Q.transpose(-1, -2) @ M).diagonal(dim1=-2, dim2=-1).sum(-1).max() <= best + 1e-12
        steps = torch.from_numpy(Rotation.from_rotvec(1e-4 * np.eye(3)).as_matrix())
        for step in torch.cat([steps, steps.transpose(-1, -2)]):
            assert torch.trace((step @ R).T @ M) <= best + 1e-12

    def test_fixes_rotations(self):
        R = torch.from_numpy(Rotation.random(8, random_state=0).as_matrix())
        torch.testing.assert_close(special_orthogonalize(R), R)

    def test_gradcheck_generic(self):
        M = torch.randn(4, 3, 3, dtype=torch.float64, requires_grad=True)
        assert torch.autograd.gradcheck(special_orthogonalize, (M,))

    def test_gradcheck_close_singular_values(self):
        # Near a rotation all singular values are ~1: torch's generic SVD backward divides by
        # s_i^2 - s_j^2 there. Ours must stay finite and correct.
        R = torch.from_numpy(Rotation.random(3, random_state=1).as_matrix())
        M = (R + 1e-7 * torch.randn(3, 3, 3, dtype=torch.float64)).requires_grad_()
        assert torch.autograd.gradcheck(special_orthogonalize, (M,), eps=1e-9, atol=1e-5)

    def test_gradient_finite_at_exact_rotation(self):
        R = torch.from_numpy(Rotation.random(2, random_state=2).as_matrix()).requires_grad_()
        special_orthogonalize(R).square().sum().backward()
        assert torch.isfinite(R.grad).all()

    def test_rejects_bad_shape(self):
        with pytest.raises(ValueError, match=r"\(\.\.\., 3, 3\), got \(9,\)"):
            special_orthogonalize(torch.zeros(9))


class TestGramSchmidt:
    @pytest.mark.parametrize("batch", BATCHES)
    @pytest.mark.parametrize("dtype", DTYPES)
    def test_matches_qr(self, batch, dtype):
        a = torch.randn(batch, 3, dtype=torch.float64)
        b = torch.randn(batch, 3, dtype=torch.float64)
        R = gram_schmidt(a.to(dtype), b.to(dtype)).double()
        for k in range(batch):
            # numpy's Householder QR of [a b]: same first two columns up to sign.
            q, r = np.linalg.qr(np.stack([a[k].numpy(), b[k].numpy()], axis=1))
            q = q * np.sign(np.diag(r))
            np.testing.assert_allclose(R[k, :, :2].numpy(), q, atol=1e-5)
        assert torch.allclose(
            torch.linalg.det(R), torch.ones(batch, dtype=torch.float64), atol=1e-5
        )

    def test_gradcheck(self):
        a, b = (torch.randn(3, 3, dtype=torch.float64, requires_grad=True) for _ in range(2))
        assert torch.autograd.gradcheck(gram_schmidt, (a, b))

    def test_rejects_parallel(self):
        with pytest.raises(ValueError, match="parallel"):
            gram_schmidt(torch.tensor([1.0, 0, 0]), torch.tensor([2.0, 0, 0]))


class TestGeodesicDistance:
    @pytest.mark.parametrize("batch", BATCHES)
    @pytest.mark.parametrize("dtype", DTYPES)
    def test_matches_scipy(self, batch, dtype):
        a = Rotation.random(batch, random_state=3)
        b = Rotation.random(batch, random_state=4)
        got = geodesic_distance(
            torch.from_numpy(a.as_matrix()).to(dtype), torch.from_numpy(b.as_matrix()).to(dtype)
        )
        np.testing.assert_allclose(got.double().numpy(), (a * b.inv()).magnitude(), atol=1e-5)

    @pytest.mark.parametrize("angle", [0.0, 1e-7, 1e-3, 1.0, math.pi - 1e-6, math.pi])
    def test_eq16_closed_form(self, angle):
        R1 = torch.from_numpy(Rotation.random(random_state=5).as_matrix())
        R2 = torch.from_numpy(Rotation.from_rotvec([0.0, angle, 0.0]).as_matrix()) @ R1
        assert geodesic_distance(R1, R2).item() == pytest.approx(angle, abs=1e-9)

    @pytest.mark.parametrize("angle", [0.0, math.pi])
    def test_finite_gradient_at_0_and_pi(self, angle):
        R1 = torch.from_numpy(Rotation.random(random_state=6).as_matrix()).requires_grad_()
        step = torch.from_numpy(Rotation.from_rotvec([angle, 0.0, 0.0]).as_matrix())
        geodesic_distance(R1, step @ R1.detach()).backward()
        assert torch.isfinite(R1.grad).all()

    def test_gradcheck(self):
        R1 = torch.from_numpy(Rotation.random(3, random_state=7).as_matrix()).requires_grad_()
        R2 = torch.from_numpy(Rotation.random(3, random_state=8).as_matrix())
        assert torch.autograd.gradcheck(lambda r: geodesic_distance(r, R2), (R1,))

    def test_convention_radians(self):
        R = torch.eye(3, dtype=torch.float64)
        Rz90 = torch.tensor([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]], dtype=torch.float64)
        assert geodesic_distance(R, Rz90).item() == pytest.approx(math.pi / 2)


class TestAngleDifference:
    @pytest.mark.parametrize("batch", BATCHES)
    def test_matches_complex_argument(self, batch):
        a = torch.rand(batch, dtype=torch.float64) * 20 - 10
        b = torch.rand(batch, dtype=torch.float64) * 20 - 10
        ref = np.angle(np.exp(1j * (a - b).numpy()))  # in (-pi, pi]
        np.testing.assert_allclose(angle_difference(a, b).numpy(), ref, atol=1e-12)

    def test_convention_range_half_open(self):
        pi = torch.tensor(math.pi, dtype=torch.float64)
        assert angle_difference(-pi, torch.zeros_like(pi)).item() == pytest.approx(math.pi)
        assert angle_difference(pi, torch.zeros_like(pi)).item() == pytest.approx(math.pi)
        # 179 deg - (-179 deg) is -2 deg, not 358 deg
        d = angle_difference(
            torch.deg2rad(torch.tensor(179.0)), torch.deg2rad(torch.tensor(-179.0))
        )
        assert math.degrees(d.item()) == pytest.approx(-2.0, abs=1e-4)

    def test_gradcheck(self):
        a, b = (torch.randn(3, dtype=torch.float64, requires_grad=True) for _ in range(2))
        assert torch.autograd.gradcheck(angle_difference, (a, b))

    def test_rejects_nonfinite(self):
        with pytest.raises(ValueError, match="a contains non-finite"):
            angle_difference(torch.tensor([float("inf")]), torch.tensor([0.0]))
