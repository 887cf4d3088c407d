"""Re-Net-6D (Zhou et al. 2019): column convention, Gram-Schmidt against numpy's QR, the degenerate
inputs, the loss against its closed form (scipy angles), float64 gradcheck."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from baselines.re_net_6d import EPS, safe_gram_schmidt
from benchmark.geometry import gram_schmidt
from benchmark.models import create_head

F = 8
D = torch.float64
BATCHES = [1, 3, 8]


def head(**options):
    torch.manual_seed(0)
    return create_head("re_net_6d", in_features=F, **options).double()


def rotations(batch: int, seed: int) -> torch.Tensor:
    return torch.from_numpy(Rotation.random(batch, random_state=seed).as_matrix())


def vectors(batch: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return torch.randn(batch, 3, generator=g, dtype=D), torch.randn(batch, 3, generator=g, dtype=D)


def assert_rotation(R: torch.Tensor) -> None:
    eye = torch.eye(3, dtype=R.dtype).expand_as(R)
    torch.testing.assert_close(R.transpose(-1, -2) @ R, eye, atol=1e-12, rtol=0)
    torch.testing.assert_close(torch.linalg.det(R), torch.ones(R.shape[:-2], dtype=R.dtype))


class TestSafeGramSchmidt:
    @pytest.mark.parametrize("batch", BATCHES)
    def test_matches_numpy_qr(self, batch):
        a, b = vectors(batch, seed=batch)
        R = safe_gram_schmidt(a, b)
        for k in range(batch):
            # Householder QR of [a b] with a positive diagonal: the same first two columns.
            q, r = np.linalg.qr(np.stack([a[k].numpy(), b[k].numpy()], axis=1))
            q = q * np.sign(np.diag(r))
            np.testing.assert_allclose(R[k, :, :2].numpy(), q, atol=1e-12)
            np.testing.assert_allclose(R[k, :, 2].numpy(), np.cross(q[:, 0], q[:, 1]), atol=1e-12)

    @pytest.mark.parametrize("batch", BATCHES)
    def test_equals_gram_schmidt_away_from_degeneracy(self, batch):
        a, b = vectors(batch, seed=10 + batch)
        torch.testing.assert_close(safe_gram_schmidt(a, b), gram_schmidt(a, b), atol=0, rtol=0)

    @pytest.mark.parametrize("scale", [0.0, 1e-9, 0.5 * EPS])
    def test_degenerate_first_vector_falls_back_to_e_x(self, scale):
        a = torch.tensor([[0.3, -0.2, 0.9]], dtype=D) * scale
        b = torch.tensor([[0.1, 1.0, 0.2]], dtype=D, requires_grad=True)
        a.requires_grad_()
        R = safe_gram_schmidt(a, b)
        assert_rotation(R.detach())
        torch.testing.assert_close(R[0, :, 0].detach(), torch.tensor([1.0, 0, 0], dtype=D))
        R.sum().backward()
        assert torch.isfinite(a.grad).all() and (a.grad == 0).all()  # replaced: no gradient
        assert torch.isfinite(b.grad).all()

    @pytest.mark.parametrize("offset", [0.0, 1e-12, 0.5 * EPS])
    def test_parallel_second_vector_falls_back_to_a_perpendicular(self, offset):
        a = torch.tensor([[0.3, -0.2, 0.9]], dtype=D, requires_grad=True)
        b = (2.5 * a.detach() + torch.tensor([[offset, 0.0, 0.0]], dtype=D)).requires_grad_()
        R = safe_gram_schmidt(a, b)
        assert_rotation(R.detach())
        e1 = a.detach() / a.detach().norm()
        torch.testing.assert_close(R[:, :, 0].detach(), e1)  # the first column is kept
        # Fallback: e1 x e_k with e_k the axis least aligned with a: e_y (|a_y| = 0.2 smallest).
        expected = torch.linalg.cross(e1, torch.tensor([[0.0, 1.0, 0.0]], dtype=D))
        torch.testing.assert_close(R[:, :, 1].detach(), expected / expected.norm())
        R.square().sum().backward()
        assert torch.isfinite(a.grad).all() and torch.isfinite(b.grad).all()

    def test_gradient_bounded_just_above_the_threshold(self):
        # |a| = 2 EPS: kept, and the derivative of a/|a| is ~1/|a| = 1/(2 EPS), finite.
        a = torch.tensor([[2 * EPS, 0.0, 0.0]], dtype=D, requires_grad=True)
        b = torch.tensor([[0.0, 1.0, 0.0]], dtype=D, requires_grad=True)
        safe_gram_schmidt(a, b)[..., 1, 0].sum().backward()
        assert torch.isfinite(a.grad).all() and a.grad.abs().max() <= 1 / EPS

    def test_gradcheck_float64(self):
        a, b = (v.requires_grad_() for v in vectors(3, seed=4))
        assert torch.autograd.gradcheck(safe_gram_schmidt, (a, b))


class TestReNet6DDecode:
    @pytest.mark.parametrize("batch", BATCHES)
    def test_convention_raw_is_the_first_two_columns(self, batch):
        R = rotations(batch, seed=batch)
        raw = R[:, :, :2].clone()  # columns r1, r2: raw[:, :, 0] = a, raw[:, :, 1] = b
        torch.testing.assert_close(head().decode(raw), R, atol=1e-12, rtol=0)

    @pytest.mark.parametrize("batch", BATCHES)
    def test_convention_rows_decode_to_the_transpose(self, batch):
        # The first two ROWS are R^T's columns: they decode to R^T, not R (columns, not rows).
        R = rotations(batch, seed=20 + batch)
        raw = R.transpose(-1, -2)[:, :, :2].clone()
        decoded = head().decode(raw)
        torch.testing.assert_close(decoded, R.transpose(-1, -2), atol=1e-12, rtol=0)

    @pytest.mark.parametrize("batch", BATCHES)
    def test_invariant_to_scale_and_to_b_along_a(self, batch):
        R = rotations(batch, seed=30 + batch)
        g = torch.Generator().manual_seed(batch)
        scale_a = torch.rand(batch, 1, generator=g, dtype=D) * 5 + 0.1
        scale_b = torch.rand(batch, 1, generator=g, dtype=D) * 5 + 0.1
        along = torch.randn(batch, 1, generator=g, dtype=D) * 3
        a = R[:, :, 0] * scale_a
        b = R[:, :, 1] * scale_b + along * R[:, :, 0]
        torch.testing.assert_close(head().decode(torch.stack([a, b], -1)), R, atol=1e-12, rtol=0)

    @pytest.mark.parametrize("batch", BATCHES)
    def test_matches_scipy_on_network_outputs(self, batch):
        h = head()
        raw = h(torch.randn(batch, F, dtype=D))
        a, b = raw[..., 0].detach().numpy(), raw[..., 1].detach().numpy()
        e1 = a / np.linalg.norm(a, axis=-1, keepdims=True)
        e2 = b - (e1 * b).sum(-1, keepdims=True) * e1
        e2 /= np.linalg.norm(e2, axis=-1, keepdims=True)
        expected = np.stack([e1, e2, np.cross(e1, e2)], axis=-1)
        assert np.allclose(Rotation.from_matrix(expected).as_matrix(), expected, atol=1e-12)
        np.testing.assert_allclose(h.decode(raw).detach().numpy(), expected, atol=1e-12)


class TestReNet6DLoss:
    @pytest.mark.parametrize("batch", BATCHES)
    def test_closed_form_without_conditioning(self, batch):
        # ||R_hat - R||_F^2 = 2 (3 - tr(R_hat^T R)) = 4 (1 - cos angle), angle from scipy.
        h = head(raw_weight=0.0)
        raw = h(torch.randn(batch, F, dtype=D)).detach()
        R = rotations(batch, seed=40 + batch)
        angle = (
            Rotation.from_matrix(h.decode(raw).numpy()).inv() * Rotation.from_matrix(R.numpy())
        ).magnitude()
        expected = np.mean(4 * (1 - np.cos(angle)))
        assert h.loss(raw, R).item() == pytest.approx(expected, abs=1e-12)

    @pytest.mark.parametrize("batch", BATCHES)
    def test_conditioning_term(self, batch):
        h0, h = head(raw_weight=0.0), head(raw_weight=0.3)
        raw = torch.randn(batch, 3, 2, dtype=D, generator=torch.Generator().manual_seed(batch))
        R = rotations(batch, seed=50 + batch)
        extra = 0.3 * ((raw - R[:, :, :2]) ** 2).sum(dim=(-1, -2)).mean()
        assert h.loss(raw, R).item() == pytest.approx((h0.loss(raw, R) + extra).item(), abs=1e-12)

    @pytest.mark.parametrize("batch", BATCHES)
    def test_zero_at_the_label_columns(self, batch):
        R = rotations(batch, seed=60 + batch)
        assert head().loss(R[:, :, :2].clone(), R).item() == pytest.approx(0.0, abs=1e-24)

    def test_finite_at_degenerate_raw(self):
        raw = torch.zeros(2, 3, 2, dtype=D)
        raw[1, :, 1] = raw[1, :, 0] = torch.tensor([1.0, 2.0, 3.0], dtype=D)  # b parallel to a
        raw.requires_grad_()
        loss = head().loss(raw, rotations(2, seed=7))
        loss.backward()
        assert torch.isfinite(loss) and torch.isfinite(raw.grad).all()

    def test_gradcheck_float64(self):
        h = head()
        x = torch.randn(2, F, dtype=D, requires_grad=True)
        R = rotations(2, seed=8)
        assert torch.autograd.gradcheck(lambda f: h.loss(h(f), R), (x,), eps=1e-6, atol=1e-5)


class TestReNet6DOptions:
    @pytest.mark.parametrize("value", [-0.1, math.inf, "0.1", True])
    def test_bad_raw_weight(self, value):
        with pytest.raises(ValueError, match="raw_weight"):
            create_head("re_net_6d", in_features=F, raw_weight=value)

    def test_bad_hidden(self):
        with pytest.raises(ValueError, match="hidden"):
            create_head("re_net_6d", in_features=F, hidden=0)

    def test_raw_shape(self):
        assert head(hidden=16)(torch.randn(5, F, dtype=D)).shape == (5, 3, 2)
