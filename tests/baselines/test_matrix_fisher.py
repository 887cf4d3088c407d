"""Matrix Fisher head (baselines/matrix_fisher.py) against independent references: scipy ``quad``
of Mohlin et al.'s 1-D integral with ``scipy.special.ive``, Monte Carlo integration over SO(3) with
scipy's Haar-uniform ``Rotation.random``, numpy's SVD, and brute force over a rotation grid."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import torch
from scipy import integrate, special
from scipy.spatial.transform import Rotation

from baselines.matrix_fisher import (
    log_normaliser,
    mean_trace,
    proper_singular_values,
)
from benchmark.geometry import quat_to_rotmat, super_fibonacci
from benchmark.models import create_head

# From tiny (the integrand is ~1/2 everywhere) to 1e3-1e4, where it lives in boundary layers of
# width 1e-3..1e-4 at u = +-1; s2 + s3 = 0 (no concentration along one direction) included.
SINGULAR_VALUES = [
    (1e-4, 1e-4, 1e-4),
    (1e-4, 0.0, -1e-4),
    (1.0, 0.5, 0.2),
    (3.0, 2.0, -1.0),
    (10.0, 5.0, 1.0),
    (30.0, 30.0, 30.0),
    (100.0, 50.0, -40.0),
    (1e3, 1e3, 1e3),
    (1e3, 0.0, 0.0),
    (1e3, 1.0, -1.0),
    (1e3, 500.0, -499.0),
    (3e3, 2e3, 1e3),
    (1e4, 1e4, 1e4),
]


def scipy_log_normaliser(s: tuple[float, float, float]) -> float:
    """log c(S) by scipy quad of Mohlin et al.'s integral, scaled by exp(-(s1 + s2 + s3)), with
    break points near both ends where the boundary layers are."""
    s1, s2, s3 = s

    def f(u: float) -> float:
        return (
            0.5
            * special.ive(0, 0.5 * (s1 - s2) * (1 - u))
            * special.ive(0, 0.5 * (s1 + s2) * (1 + u))
            * math.exp((s2 + s3) * (u - 1))
        )

    points = [-1, -1 + 1e-6, -1 + 1e-4, -1 + 1e-2, 0, 1 - 1e-2, 1 - 1e-4, 1 - 1e-6, 1]
    total = sum(
        integrate.quad(f, a, b, epsabs=0, epsrel=1e-13, limit=200)[0]
        for a, b in itertools.pairwise(points)
    )
    return s1 + s2 + s3 + math.log(total)


def haar(n: int, seed: int) -> torch.Tensor:
    return torch.tensor(Rotation.random(n, random_state=seed).as_matrix())


def random_F(batch: int, seed: int, scale: float = 3.0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return scale * torch.randn(batch, 3, 3, generator=g, dtype=torch.float64)


def numpy_mode(F: np.ndarray) -> np.ndarray:
    """The proper polar factor U diag(1, 1, det(U V^T)) V^T by numpy's SVD."""
    U, _, Vt = np.linalg.svd(F)
    return U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt


def make(hidden: int = 32):
    """A small head with F = raw (output_scale 1), so tests can pass F as the raw."""
    torch.manual_seed(0)
    return create_head("matrix_fisher", in_features=8, hidden=hidden, output_scale=1.0).double()


class TestProperSingularValues:
    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_against_numpy_svd_with_determinant_fix(self, batch):
        F = random_F(batch, seed=batch)
        s = proper_singular_values(F)
        for Fi, si in zip(F.numpy(), s.numpy(), strict=True):
            U, S, Vt = np.linalg.svd(Fi)
            d = np.linalg.det(U) * np.linalg.det(Vt)
            U[:, 2] *= np.linalg.det(U)
            Vt[2] *= np.linalg.det(Vt)
            np.testing.assert_allclose(si, S * [1, 1, d], atol=1e-12)
            np.testing.assert_allclose(U @ np.diag(si) @ Vt, Fi, atol=1e-12)  # U, V rotations

    def test_convention_sign_of_s3_is_sign_of_det(self):
        F = torch.diag(torch.tensor([3.0, 2.0, -1.0], dtype=torch.float64))
        torch.testing.assert_close(
            proper_singular_values(F), torch.tensor([3.0, 2.0, -1.0]).double()
        )


class TestLogNormaliser:
    @pytest.mark.parametrize("s", SINGULAR_VALUES)
    def test_against_scipy_quad(self, s):
        ours = log_normaliser(torch.tensor(s, dtype=torch.float64)).item()
        assert ours == pytest.approx(scipy_log_normaliser(s), abs=1e-9, rel=1e-13)

    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_against_monte_carlo_over_so3(self, batch):
        # c(F) = E_Haar[exp(tr(F^T R))], estimated with 400k scipy Haar rotations. Moderate F so the
        # estimator's relative standard error is small (it is measured and bounds the tolerance).
        F = random_F(batch, seed=10 + batch, scale=1.0)
        R = haar(400_000, seed=batch)
        for Fi in F:
            values = torch.exp((R * Fi).sum(dim=(-1, -2)))
            estimate = math.log(values.mean().item())
            rel_se = (values.std() / values.mean()).item() / math.sqrt(len(values))
            expected = log_normaliser(proper_singular_values(Fi)).item()
            assert estimate == pytest.approx(expected, abs=5 * rel_se)

    def test_uniform_is_zero_and_float32_agrees(self):
        assert log_normaliser(torch.zeros(3, dtype=torch.float64)).item() == pytest.approx(
            0.0, abs=1e-14
        )
        s = torch.tensor(SINGULAR_VALUES, dtype=torch.float64)
        s32 = log_normaliser(s.float())
        assert s32.dtype == torch.float32
        torch.testing.assert_close(s32.double(), log_normaliser(s), rtol=1e-6, atol=1e-6)

    def test_gradcheck_float64(self):
        s = torch.tensor(
            [[3.0, 2.0, -1.0], [0.5, 0.5, 0.5], [40.0, 10.0, -9.0]], dtype=torch.float64
        )
        assert torch.autograd.gradcheck(log_normaliser, (s.requires_grad_(),))

    @pytest.mark.parametrize("s", [(1.0, 0.5, 0.2), (30.0, 30.0, 30.0), (1e3, 500.0, -499.0)])
    def test_gradient_against_scipy_finite_differences(self, s):
        s_t = torch.tensor(s, dtype=torch.float64, requires_grad=True)
        log_normaliser(s_t).backward()
        for i in range(3):
            h = 1e-3  # log c curves on the scale 1 / (s2 + s3): keep the step well below
            up, down = list(s), list(s)
            up[i] += h
            down[i] -= h
            fd = (scipy_log_normaliser(tuple(up)) - scipy_log_normaliser(tuple(down))) / (2 * h)
            assert s_t.grad[i].item() == pytest.approx(fd, abs=1e-6)


class TestMeanTrace:
    def test_equals_autograd_sum_of_derivatives(self):
        s = torch.tensor(SINGULAR_VALUES, dtype=torch.float64, requires_grad=True)
        log_normaliser(s).sum().backward()
        torch.testing.assert_close(mean_trace(s.detach()), s.grad.sum(-1), atol=1e-10, rtol=1e-9)

    def test_against_monte_carlo_expectation(self):
        # E[tr(F-mode^T R)] under p, by self-normalised importance sampling of Haar rotations.
        F = random_F(3, seed=5, scale=1.5)
        R = haar(300_000, seed=7)
        for Fi in F:
            w = torch.softmax((R * Fi).sum(dim=(-1, -2)), dim=0)
            mode = torch.tensor(numpy_mode(Fi.numpy()))
            expected = (w * (R * mode).sum(dim=(-1, -2))).sum().item()
            assert mean_trace(proper_singular_values(Fi)).item() == pytest.approx(
                expected, abs=0.01
            )


class TestDecode:
    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_against_brute_force_over_a_rotation_grid(self, batch):
        # The mode maximises tr(F^T R): no rotation of a 2^15-point grid may beat it, and the best
        # grid rotation is within the grid's spacing (~6 deg) of it.
        F = random_F(batch, seed=20 + batch)
        head = make()
        mode = head.decode(F)
        grid = quat_to_rotmat(super_fibonacci(2**15, dtype=torch.float64))
        scores = torch.einsum("bij,mij->bm", F, grid)
        assert ((F * mode).sum(dim=(-1, -2)) >= scores.max(-1).values - 1e-10).all()
        best = Rotation.from_matrix(grid[scores.argmax(-1)].numpy())
        assert (np.degrees((best.inv() * Rotation.from_matrix(mode.numpy())).magnitude()) < 7).all()

    def test_convention_F_equal_k_R0_has_mode_R0(self):
        R0 = haar(4, seed=3)
        torch.testing.assert_close(make().decode(5.0 * R0), R0, atol=1e-12, rtol=0)


class TestLogProb:
    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_density_integrates_to_one_over_haar(self, batch):
        head = make()
        F = random_F(batch, seed=30 + batch, scale=1.0)
        R = haar(200_000, seed=11)
        # head.log_prob at one rotation per F fixes its normaliser (log p is tr(F^T R) minus a
        # constant); the density at all the Haar samples follows without 200k SVDs.
        log_norm = (F * R[:batch]).sum(dim=(-1, -2)) - head.log_prob(F, R[:batch])
        for Fi, ci in zip(F, log_norm, strict=True):
            density = torch.exp((R * Fi).sum(dim=(-1, -2)) - ci)
            se = (density.std() / math.sqrt(len(R))).item()
            assert density.mean().item() == pytest.approx(1.0, abs=5 * se)

    def test_convention_uniform_scores_zero_and_the_mode_scores_highest(self):
        head = make()
        R = haar(5, seed=2)
        torch.testing.assert_close(
            head.log_prob(torch.zeros(5, 3, 3).double(), R), torch.zeros(5).double()
        )
        F = 10.0 * R
        at_mode = head.log_prob(F, R)
        elsewhere = head.log_prob(F, haar(5, seed=9))
        assert (at_mode > elsewhere).all()


class TestLossAndUncertainty:
    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_loss_is_nll_and_gradcheck(self, batch):
        head = make()
        x = torch.randn(
            batch, 8, dtype=torch.float64, generator=torch.Generator().manual_seed(batch)
        )
        R = haar(batch, seed=batch)
        raw = head(x)
        torch.testing.assert_close(head.loss(raw, R), -head.log_prob(raw, R).mean())
        assert torch.autograd.gradcheck(
            lambda f: head.loss(head(f), R), (x.requires_grad_(),), eps=1e-6, atol=1e-6
        )

    @pytest.mark.parametrize(
        "F", [torch.zeros(3, 3), 7.0 * torch.eye(3), torch.diag(torch.tensor([4.0, 4.0, -4.0]))]
    )
    def test_gradient_finite_at_repeated_singular_values(self, F):
        F = F.double()[None].requires_grad_()
        make().loss(F, haar(1, seed=0)).backward()
        assert torch.isfinite(F.grad).all()

    def test_uncertainty_range_and_order(self):
        head = make()
        R0 = haar(1, seed=1)
        u = torch.cat([head.uncertainty(k * R0) for k in (0.0, 1.0, 10.0, 1e3)])
        assert u[0].item() == pytest.approx(0.75, abs=1e-12)  # uniform: E[sin^2] = 3/4
        assert (u[1:] < u[:-1]).all() and (u >= 0).all() and u[-1] < 1e-3

    def test_uncertainty_against_monte_carlo(self):
        F = random_F(2, seed=8, scale=2.0)
        R = haar(300_000, seed=12)
        head = make()
        mode = head.decode(F)
        for Fi, Mi, ui in zip(F, mode, head.uncertainty(F), strict=True):
            w = torch.softmax((R * Fi).sum(dim=(-1, -2)), dim=0)
            cos = ((R * Mi).sum(dim=(-1, -2)) - 1) / 2
            assert ui.item() == pytest.approx((w * (1 - cos) / 2).sum().item(), abs=0.005)


class TestOptions:
    @pytest.mark.parametrize("hidden", [0, -3, 2.5, True])
    def test_bad_hidden(self, hidden):
        with pytest.raises(ValueError, match=f"hidden.*{hidden!r}"):
            create_head("matrix_fisher", in_features=8, hidden=hidden)

    @pytest.mark.parametrize("scale", [0.0, -1.0, float("nan"), "10"])
    def test_bad_output_scale(self, scale):
        with pytest.raises(ValueError, match="output_scale"):
            create_head("matrix_fisher", in_features=8, output_scale=scale)

    def test_convention_F_is_output_scale_times_raw(self):
        torch.manual_seed(0)
        head = create_head("matrix_fisher", in_features=8, output_scale=30.0).double()
        raw = torch.randn(3, 3, 3, dtype=torch.float64)
        R = haar(3, seed=1)
        expected = (30 * raw * R).sum(dim=(-1, -2)) - log_normaliser(
            proper_singular_values(30 * raw)
        )
        torch.testing.assert_close(head.log_prob(raw, R), expected)
