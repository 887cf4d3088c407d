"""Re-Net-SVD (Levinson et al. 2020, "SVD-Train"): decoding against a numpy SVD projection, the loss
after the projection against its closed form, the relation to re_net_r ("SVD-Inf"), and the
backward at repeated singular values (closed form) and where the projection is not unique."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from benchmark.models import create_head

F = 8
D = torch.float64
BATCHES = [1, 3, 8]


def head(name: str = "re_net_svd"):
    torch.manual_seed(0)
    return create_head(name, in_features=F).double()


def matrices(batch: int, seed: int) -> torch.Tensor:
    return torch.randn(batch, 3, 3, generator=torch.Generator().manual_seed(seed), dtype=D)


def rotations(batch: int, seed: int) -> torch.Tensor:
    return torch.from_numpy(Rotation.random(batch, random_state=seed).as_matrix())


def numpy_projection(M: np.ndarray) -> np.ndarray:
    """Closest rotation (Kabsch / Umeyama): U diag(1, 1, det(U V^T)) V^T."""
    U, _, Vt = np.linalg.svd(M)
    d = np.sign(np.linalg.det(U @ Vt))
    return U @ np.diag([1.0, 1.0, d]) @ Vt


class TestReNetSVDDecode:
    @pytest.mark.parametrize("batch", BATCHES)
    def test_matches_numpy_projection(self, batch):
        M = matrices(batch, seed=batch)
        expected = np.stack([numpy_projection(m) for m in M.numpy()])
        np.testing.assert_allclose(head().decode(M).numpy(), expected, atol=1e-12)

    @pytest.mark.parametrize("batch", BATCHES)
    def test_convention_rotation_times_spd_decodes_to_the_rotation(self, batch):
        # M = R S with S symmetric positive definite: its polar factor is R.
        R = rotations(batch, seed=10 + batch)
        B = matrices(batch, seed=20 + batch)
        S = B @ B.transpose(-1, -2) + 0.5 * torch.eye(3, dtype=D)
        torch.testing.assert_close(head().decode(R @ S), R, atol=1e-10, rtol=0)

    @pytest.mark.parametrize("batch", BATCHES)
    def test_same_decoding_as_re_net_r(self, batch):
        M = matrices(batch, seed=30 + batch)
        torch.testing.assert_close(head().decode(M), head("re_net_r").decode(M), atol=0, rtol=0)


class TestReNetSVDLoss:
    @pytest.mark.parametrize("batch", BATCHES)
    def test_closed_form_after_projection(self, batch):
        # ||SVD+(M) - R||_F^2 = 4 (1 - cos angle(SVD+(M), R)), angle from scipy.
        M = matrices(batch, seed=40 + batch)
        R = rotations(batch, seed=50 + batch)
        projected = Rotation.from_matrix(np.stack([numpy_projection(m) for m in M.numpy()]))
        angle = (projected.inv() * Rotation.from_matrix(R.numpy())).magnitude()
        assert head().loss(M, R).item() == pytest.approx(
            np.mean(4 * (1 - np.cos(angle))), abs=1e-12
        )

    @pytest.mark.parametrize("batch", BATCHES)
    def test_convention_svd_train_not_svd_inf(self, batch):
        # M = 3 R: zero loss after the projection (SVD-Train, this head); re_net_r (SVD-Inf)
        # compares the raw 9 numbers, ||3R - R||^2 = 4 * 3 = 12.
        R = rotations(batch, seed=60 + batch)
        assert head().loss(3 * R, R).item() == pytest.approx(0.0, abs=1e-20)
        assert head("re_net_r").loss(3 * R, R).item() == pytest.approx(12.0, abs=1e-12)

    def test_gradcheck_float64(self):
        h = head()
        x = torch.randn(2, F, dtype=D, requires_grad=True)
        R = rotations(2, seed=7)
        assert torch.autograd.gradcheck(lambda f: h.loss(h(f), R), (x,), eps=1e-6, atol=1e-5)


class TestReNetSVDBackward:
    """special_orthogonalize's analytic backward, seen through the head's loss."""

    @pytest.mark.parametrize(
        "singular_values",
        [(1.0, 1.0, 1.0), (2.0, 1.0, 1.0), (3.0, 3.0, 0.5), (1.0, 1.0, 1.0 + 1e-9)],
    )
    def test_closed_form_at_repeated_singular_values(self, singular_values):
        # M = diag(s): R = I and dR = W with W_ij = (dM_ij - dM_ji) / (s_i + s_j). torch's
        # generic SVD backward divides by s_i^2 - s_j^2 and gives NaN at s_i = s_j.
        s = torch.tensor(singular_values, dtype=D)
        M = torch.diag(s).requires_grad_()
        G = matrices(1, seed=8)[0]  # upstream gradient dL/dR
        (head().decode(M) * G).sum().backward()
        expected = (G - G.T) / (s[:, None] + s[None, :])
        torch.testing.assert_close(M.grad, expected, atol=1e-12, rtol=0)
        if len(set(singular_values)) < 3:  # the reason for the analytic backward
            Mt = M.detach().clone().requires_grad_()
            U, _, Vh = torch.linalg.svd(Mt)
            (U @ Vh * G).sum().backward()
            assert not torch.isfinite(Mt.grad).all()

    @pytest.mark.parametrize("batch", BATCHES)
    def test_gradcheck_near_rotations(self, batch):
        # Near-rotation raws: all three singular values ~1 (repeated).
        R = rotations(batch, seed=70 + batch)
        M = (R + 1e-6 * matrices(batch, seed=batch)).requires_grad_()
        target = rotations(batch, seed=80 + batch)
        assert torch.autograd.gradcheck(lambda m: head().loss(m, target), (M,), atol=1e-6)

    def test_finite_where_the_projection_is_not_unique(self):
        # M = diag(2, 1, -1): det M < 0 with s2 = s3, so s'_2 + s'_3 = 0. Every rotation about e1
        # is equally close (tr(R^T M) = 2 for all of them). The denominator is clamped at 1e-8:
        # the gradient is finite, ~1e8 in the ill-defined direction, as documented.
        M = torch.diag(torch.tensor([2.0, 1.0, -1.0], dtype=D)).requires_grad_()
        R_hat = head().decode(M)
        torch.testing.assert_close(torch.linalg.det(R_hat), torch.tensor(1.0, dtype=D))
        (R_hat * matrices(1, seed=9)[0]).sum().backward()
        assert torch.isfinite(M.grad).all()
        assert 1e6 < M.grad.abs().max() <= 2e8
