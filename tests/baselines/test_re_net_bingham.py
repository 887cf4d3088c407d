"""Re-Net-A / Bingham (Peretroukhin et al. 2020): the A layout, the smallest eigenpair and its
backward against numpy and finite differences, the decoder against brute force over a dense
rotation grid, the loss and uncertainty against closed forms, and the log density's normaliser
against independent references (Monte Carlo over scipy's uniform rotations, a Haar grid on S^3,
a 1-D scipy quadrature, Laplace asymptotics)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import torch
from scipy import integrate, special
from scipy.spatial.transform import Rotation

from baselines.re_net_bingham import (
    GAP_EPS,
    log_mean_bingham,
    smallest_eigenpair,
    symmetric_matrix,
)
from benchmark.geometry import super_fibonacci
from benchmark.models import create_head

F = 8
D = torch.float64
BATCHES = [1, 3, 8]
TRIU = torch.triu_indices(4, 4)


def head():
    torch.manual_seed(0)
    return create_head("re_net_bingham", in_features=F).double()


def raws(batch: int, seed: int, scale: float = 2.0) -> torch.Tensor:
    return scale * torch.randn(batch, 10, generator=torch.Generator().manual_seed(seed), dtype=D)


def raw_of(A: torch.Tensor) -> torch.Tensor:
    """(..., 4, 4) symmetric -> (..., 10) upper triangle, row by row."""
    return A[..., TRIU[0], TRIU[1]]


def quats(batch: int, seed: int) -> np.ndarray:
    return Rotation.random(batch, random_state=seed).as_quat(scalar_first=True)


def with_eigen(q: np.ndarray, values: tuple[float, ...], seed: int) -> torch.Tensor:
    """A (B, 4, 4) with smallest eigenvalue values[0] along q and the others along a random
    orthonormal complement of q."""
    rng = np.random.default_rng(seed)
    out = []
    for qk in np.atleast_2d(q):
        basis, _ = np.linalg.qr(np.column_stack([qk, rng.normal(size=(4, 3))]))
        basis[:, 0] = qk
        out.append(basis @ np.diag(values) @ basis.T)
    return torch.tensor(np.stack(out))


def haar_grid_log_mean(A: torch.Tensor) -> torch.Tensor:
    """log E_{u ~ S^3}[exp(-(u^T A u - lambda_1))] by a 2^17-point super-Fibonacci average."""
    q = super_fibonacci(2**17, dtype=D)
    lam = torch.linalg.eigvalsh(A)[..., :1]
    energy = torch.einsum("mi,bij,mj->bm", q, A, q) - lam
    return torch.logsumexp(-energy, -1) - math.log(q.shape[0])


class TestSymmetricMatrix:
    def test_convention_upper_triangle_row_by_row(self):
        A = symmetric_matrix(torch.arange(10.0)[None])[0]
        expected = [[0, 1, 2, 3], [1, 4, 5, 6], [2, 5, 7, 8], [3, 6, 8, 9]]
        torch.testing.assert_close(A, torch.tensor(expected, dtype=torch.float32))

    @pytest.mark.parametrize("batch", BATCHES)
    def test_round_trip(self, batch):
        raw = raws(batch, seed=batch)
        A = symmetric_matrix(raw)
        torch.testing.assert_close(A, A.transpose(-1, -2), atol=0, rtol=0)
        torch.testing.assert_close(raw_of(A), raw, atol=0, rtol=0)


class TestSmallestEigenpair:
    @pytest.mark.parametrize("batch", BATCHES)
    def test_matches_numpy(self, batch):
        A = symmetric_matrix(raws(batch, seed=10 + batch))
        values, vector = smallest_eigenpair(A)
        w, V = np.linalg.eigh(A.numpy())
        np.testing.assert_allclose(values.numpy(), w, atol=1e-12)
        sign = np.sign((vector.numpy() * V[:, :, 0]).sum(-1, keepdims=True))
        np.testing.assert_allclose(vector.numpy(), sign * V[:, :, 0], atol=1e-10)

    @pytest.mark.parametrize("batch", BATCHES)
    def test_gradcheck_float64(self, batch):
        raw = raws(batch, seed=20 + batch).requires_grad_()
        weights = torch.arange(1.0, 17.0, dtype=D).view(4, 4)

        def f(r):  # sign-invariant: the eigenvector's sign is arbitrary
            values, q = smallest_eigenpair(symmetric_matrix(r))
            return (q[..., :, None] * q[..., None, :] * weights).sum((-1, -2)) + values @ weights[0]

        assert torch.autograd.gradcheck(f, (raw,))

    def test_ties_among_the_other_eigenvalues(self):
        # lambda = (0, 1, 1, 1): the smallest eigenvector is smooth although the others are tied.
        # Our backward divides only by the gaps to lambda_1, so it must be finite at the exact tie
        # and equal first-order perturbation theory, dq = -sum_{j>1} v_j v_j^T dA q /
        # (lambda_j - lambda_1) = -(I - q q^T) dA q here (independent of how the tied basis is
        # chosen). What torch's own eigh backward does at a tie is torch's business (NaN on AVX2
        # builds, finite on an AVX-512 machine): not asserted here.
        qk = quats(1, seed=1)
        A = with_eigen(qk, (0.0, 1.0, 1.0, 1.0), seed=1)
        raw = raw_of(A).requires_grad_()
        weights = torch.arange(1.0, 17.0, dtype=D).view(4, 4)
        _, q = smallest_eigenpair(symmetric_matrix(raw))
        ((q[..., :, None] * q[..., None, :]) * weights).sum().backward()
        assert torch.isfinite(raw.grad).all()
        q0 = qk[0] * np.sign(qk[0] @ q.detach().numpy()[0])
        projector = np.eye(4) - np.outer(q0, q0)  # sum_{j>1} v_j v_j^T / (lambda_j - 0), gaps 1
        W = weights.numpy()
        expected = []
        for k in range(10):  # the derivative along each raw entry, closed form
            dA = symmetric_matrix(torch.eye(10, dtype=D)[k]).numpy()
            dq = -projector @ dA @ q0
            expected.append(float((W * (np.outer(dq, q0) + np.outer(q0, dq))).sum()))
        np.testing.assert_allclose(raw.grad.numpy()[0], expected, atol=1e-10)
        # ... and the loss through it matches finite differences (gradcheck perturbs one entry at
        # a time, which splits the tie smoothly).
        R = torch.from_numpy(Rotation.random(1, random_state=2).as_matrix())
        h = head()
        assert torch.autograd.gradcheck(lambda r: h.loss(r, R), (raw.detach().requires_grad_(),))

    def test_tie_with_the_smallest_is_finite(self):
        # lambda_1 = lambda_2: the minimiser is not unique; the gap is clamped at GAP_EPS.
        A = with_eigen(quats(1, seed=3), (0.0, 0.0, 1.0, 2.0), seed=3)
        raw = raw_of(A).requires_grad_()
        R = torch.from_numpy(Rotation.random(1, random_state=4).as_matrix())
        head().loss(raw, R).backward()
        assert torch.isfinite(raw.grad).all() and raw.grad.abs().max() < 10 / GAP_EPS


class TestReNetBinghamDecode:
    @pytest.mark.parametrize("batch", BATCHES)
    def test_brute_force_over_a_dense_rotation_grid(self, batch):
        raw = raws(batch, seed=30 + batch)
        A = symmetric_matrix(raw)
        grid = torch.from_numpy(quats(500_000, seed=5))  # uniform rotations, w first
        energy = torch.einsum("mi,bij,mj->bm", grid, A, grid)
        best = grid[energy.argmin(-1)]
        R_hat = head().decode(raw)
        q_hat = torch.from_numpy(Rotation.from_matrix(R_hat.numpy()).as_quat(scalar_first=True))
        # No grid rotation has a lower q^T A q than the decoded one ...
        assert (torch.einsum("bi,bij,bj->b", q_hat, A, q_hat) <= energy.min(-1).values).all()
        # ... and the grid's best lies within its resolution (~3 deg spacing) of it.
        best_rotation = Rotation.from_quat(best.numpy(), scalar_first=True)
        angle = (best_rotation.inv() * Rotation.from_matrix(R_hat.numpy())).magnitude()
        assert np.degrees(angle).max() < 5.0

    @pytest.mark.parametrize("batch", BATCHES)
    def test_convention_w_first(self, batch):
        # A = I - q0 q0^T: the smallest eigenvalue (0) belongs to q0 = (w, x, y, z).
        q0 = quats(batch, seed=40 + batch)
        A = torch.eye(4, dtype=D) - torch.from_numpy(q0[:, :, None] * q0[:, None, :])
        expected = Rotation.from_quat(q0, scalar_first=True).as_matrix()
        np.testing.assert_allclose(head().decode(raw_of(A)).numpy(), expected, atol=1e-12)

    @pytest.mark.parametrize("batch", BATCHES)
    def test_invariant_to_shift_and_positive_scale(self, batch):
        raw = raws(batch, seed=50 + batch)
        shifted = raw_of(3.0 * symmetric_matrix(raw) + 7.0 * torch.eye(4, dtype=D))
        torch.testing.assert_close(head().decode(shifted), head().decode(raw), atol=1e-10, rtol=0)


class TestReNetBinghamLoss:
    @pytest.mark.parametrize("batch", BATCHES)
    def test_closed_form_half_angle(self, batch):
        # min(|q - q*|^2, |q + q*|^2) = 2 (1 - |q.q*|) = 2 (1 - cos(angle / 2)), scipy angle.
        raw = raws(batch, seed=60 + batch)
        R = torch.from_numpy(Rotation.random(batch, random_state=batch).as_matrix())
        h = head()
        decoded = Rotation.from_matrix(h.decode(raw).numpy())
        angle = (decoded.inv() * Rotation.from_matrix(R.numpy())).magnitude()
        expected = np.mean(2 * (1 - np.cos(angle / 2)))
        assert h.loss(raw, R).item() == pytest.approx(expected, abs=1e-12)

    @pytest.mark.parametrize("batch", BATCHES)
    def test_zero_at_the_label(self, batch):
        q0 = quats(batch, seed=70 + batch)
        A = with_eigen(q0, (-1.0, 0.5, 2.0, 3.0), seed=batch)
        R = torch.from_numpy(Rotation.from_quat(q0, scalar_first=True).as_matrix())
        assert head().loss(raw_of(A), R).item() == pytest.approx(0.0, abs=1e-20)

    def test_gradcheck_float64(self):
        h = head()
        x = torch.randn(2, F, dtype=D, requires_grad=True)
        R = torch.from_numpy(Rotation.random(2, random_state=6).as_matrix())
        assert torch.autograd.gradcheck(lambda f: h.loss(h(f), R), (x,), eps=1e-6, atol=1e-5)


class TestReNetBinghamUncertainty:
    @pytest.mark.parametrize("batch", BATCHES)
    def test_is_one_over_one_plus_the_eigen_gap(self, batch):
        raw = raws(batch, seed=80 + batch)
        w = np.linalg.eigvalsh(symmetric_matrix(raw).numpy())
        expected = 1 / (1 + w[:, 1] - w[:, 0])
        np.testing.assert_allclose(head().uncertainty(raw).numpy(), expected, atol=1e-12)

    def test_decreases_as_the_density_concentrates(self):
        raw = raws(4, seed=9)
        u = [head().uncertainty(s * raw) for s in (0.0, 0.5, 1.0, 4.0)]
        torch.testing.assert_close(u[0], torch.ones(4, dtype=D))
        assert all((a > b).all() for a, b in itertools.pairwise(u))
        assert ((u[-1] > 0) & (u[-1] <= 1)).all()

    def test_gradcheck_float64(self):
        assert torch.autograd.gradcheck(head().uncertainty, (raws(3, seed=10).requires_grad_(),))


class TestLogMeanBingham:
    def test_zero_gaps_is_uniform(self):
        torch.testing.assert_close(
            log_mean_bingham(torch.zeros(2, 3, dtype=D)), torch.zeros(2, dtype=D)
        )

    @pytest.mark.parametrize("gap", [0.01, 1.0, 30.0, 1e3, 1e5])
    def test_one_gap_against_scipy_quad(self, gap):
        # One coordinate t of a uniform point on S^3 has density (2/pi) sqrt(1 - t^2) on [-1, 1].
        value, _ = integrate.quad(
            lambda t: 2 / math.pi * math.sqrt(1 - t * t) * math.exp(-gap * t * t),
            -1,
            1,
            points=[0.0],
            epsabs=0,
            epsrel=1e-12,
            limit=200,
        )
        got = log_mean_bingham(torch.tensor([0.0, 0.0, gap], dtype=D))
        # Measured: < 1e-12 up to gap 1e3, 2e-6 at 1e5 (both other gaps 0: the sharpest case).
        assert got.item() == pytest.approx(math.log(value), abs=1e-5 if gap > 1e3 else 1e-9)

    @pytest.mark.parametrize("gaps", [(1e3, 2e3, 5e3), (1e4, 1e4, 1e4), (3e5, 1e6, 1e6)])
    def test_laplace_limit(self, gaps):
        # Two antipodal Gaussian peaks: E = 1 / sqrt(pi g1 g2 g3), relative error O(1/g).
        got = log_mean_bingham(torch.tensor(gaps, dtype=D)).item()
        assert got == pytest.approx(-0.5 * math.log(math.pi * math.prod(gaps)), abs=1e-3)

    @pytest.mark.parametrize("small", [0.0, 1.0, 10.0])
    def test_great_circle_limit(self, small):
        # g2 = g3 = g >> g1: mass on the great circle of e1, e2; the exact circle average of
        # exp(-g1 sin^2) times the transverse Gaussian pi / g over the volume 2 pi^2.
        g = 1e6
        expected = math.log(special.i0e(small / 2)) - math.log(g)
        got = log_mean_bingham(torch.tensor([small, g, g], dtype=D)).item()
        assert got == pytest.approx(expected, abs=1e-4)

    def test_matches_a_haar_grid_for_broad_densities(self):
        A = symmetric_matrix(raws(3, seed=11))
        gaps = torch.linalg.eigvalsh(A)
        got = log_mean_bingham(gaps[:, 1:] - gaps[:, :1])
        torch.testing.assert_close(got, haar_grid_log_mean(A), atol=1e-4, rtol=0)


class TestReNetBinghamLogProb:
    def test_uniform_prediction_scores_zero(self):
        raw = raw_of(2.5 * torch.eye(4, dtype=D).expand(3, 4, 4))
        R = torch.from_numpy(Rotation.random(3, random_state=12).as_matrix())
        torch.testing.assert_close(head().log_prob(raw, R), torch.zeros(3, dtype=D))

    @pytest.mark.parametrize("seed", [13, 14])
    def test_monte_carlo_over_uniform_rotations(self, seed):
        # E_{R ~ Haar}[p(R)] = 1 for a density w.r.t. the normalised Haar measure.
        n = 4000
        R = torch.from_numpy(Rotation.random(n, random_state=seed).as_matrix())
        raw = raws(1, seed=seed).expand(n, 10)
        h = head()
        chunks = zip(raw.split(1000), R.split(1000), strict=True)
        density = torch.cat([h.log_prob(r, m).exp() for r, m in chunks])
        stderr = density.std().item() / math.sqrt(n)
        assert abs(density.mean().item() - 1) < 4 * stderr, (density.mean().item(), stderr)

    @pytest.mark.parametrize("batch", BATCHES)
    def test_matches_explicit_haar_quadrature(self, batch):
        raw = raws(batch, seed=90 + batch)
        A = symmetric_matrix(raw)
        q = torch.from_numpy(quats(batch, seed=batch))
        R = torch.from_numpy(Rotation.from_quat(q.numpy(), scalar_first=True).as_matrix())
        energy = torch.einsum("bi,bij,bj->b", q, A, q) - torch.linalg.eigvalsh(A)[:, 0]
        expected = -energy - haar_grid_log_mean(A)
        torch.testing.assert_close(head().log_prob(raw, R), expected, atol=1e-4, rtol=0)

    def test_sharp_density_at_its_mode(self):
        q0 = quats(2, seed=15)
        A = with_eigen(q0, (5.0, 5.0 + 2e3, 5.0 + 3e3, 5.0 + 4e3), seed=15)
        R = torch.from_numpy(Rotation.from_quat(q0, scalar_first=True).as_matrix())
        got = head().log_prob(raw_of(A), R)
        expected = 0.5 * math.log(math.pi * 2e3 * 3e3 * 4e3)  # Laplace, error O(1/gap)
        torch.testing.assert_close(got, torch.full((2,), expected, dtype=D), atol=1e-3, rtol=0)

    def test_gradcheck_float64(self):
        h = head()
        R = torch.from_numpy(Rotation.random(2, random_state=16).as_matrix())
        x = torch.randn(2, F, dtype=D, requires_grad=True)
        assert torch.autograd.gradcheck(lambda f: h.log_prob(h(f), R), (x,), eps=1e-6, atol=1e-5)

    def test_declares_what_it_gives(self):
        cls = type(head())
        assert cls.gives_log_prob and cls.gives_uncertainty and not cls.is_probabilistic
