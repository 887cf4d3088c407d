"""Pd/Re-Net: DirectionNet decoding (normalise, then SVD) and the Haar log density.

References: a numpy SVD of the normalised column expectations (decoding); the matrix Fisher
distribution with its normaliser from the 1-D integral of Mohlin et al. 2020 (scipy quad), and Monte
Carlo over scipy ``Rotation.random`` (log density w.r.t. the normalised Haar measure).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.integrate import quad
from scipy.spatial.transform import Rotation
from scipy.special import ive

from benchmark.geometry import (
    euler_to_rotmat,
    fibonacci_sphere,
    geodesic_distance,
    special_orthogonalize,
)
from benchmark.models import create_head

F = 8


def head(**kwargs):
    torch.manual_seed(0)
    return create_head("pd_re_net", in_features=F, **kwargs).double()


def rotations(n: int, seed: int = 0) -> torch.Tensor:
    return torch.tensor(Rotation.random(n, random_state=seed).as_matrix(), dtype=torch.float64)


def numpy_decode(p: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """Naive reference: normalised expectations as columns, SVD, det fix (Umeyama / Kabsch)."""
    out = []
    for pb in p:
        m = pb @ grid  # (3 columns, 3)
        m = (m / np.linalg.norm(m, axis=-1, keepdims=True)).T
        u, _, vt = np.linalg.svd(m)
        d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
        out.append(u @ d @ vt)
    return np.stack(out)


def log_matrix_fisher_normaliser(s: float) -> float:
    """log c(S) for S = diag(s, s, s): Mohlin et al. 2020 Eq. (1-D integral over u in [-1, 1]),
    ``c = int 1/2 I0((s1-s2)(1-u)/2) I0((s1+s2)(1+u)/2) exp(s3 u) du``, scaled Bessel for range."""

    def integrand(u: float) -> float:
        # ive(0, x) = I0(x) exp(-x): pull out exp((s1+s2)(1+u)/2 + s3 u - 3 s), bounded by 1.
        return 0.5 * ive(0, 0.0) * ive(0, s * (1 + u)) * math.exp(s * (1 + u) + s * u - 3 * s)

    value, _ = quad(integrand, -1.0, 1.0, limit=200)
    return math.log(value) + 3 * s


def perturbed_logits(h, R: torch.Tensor, noise: float, seed: int) -> torch.Tensor:
    """Target logits of ``R`` plus Gaussian logit noise: a perturbed, not exact, prediction."""
    g = torch.Generator().manual_seed(seed)
    logits = torch.log(h.target_distribution(R))
    return logits + noise * torch.randn(logits.shape, generator=g, dtype=torch.float64)


class TestDecodeDistribution:
    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_matches_numpy_svd_of_normalised_expectations(self, batch):
        h = head()
        g = torch.Generator().manual_seed(batch)
        p = torch.softmax(3 * torch.randn(batch, 3, 4096, generator=g, dtype=torch.float64), -1)
        expected = numpy_decode(p.numpy(), h.grid.double().numpy())
        np.testing.assert_allclose(h.decode_distribution(p).numpy(), expected, atol=1e-9)

    def test_columns_weigh_alike_whatever_their_spread(self):
        # A broad column (short resultant) must count as much as a sharp one: decoding the target
        # of R with one column broadened (same mean direction) gives R back exactly, and a
        # broadened column that is off by 10 deg pulls the result as far as a sharp one does.
        h = head()
        R = rotations(3, seed=3)
        off = torch.tensor(Rotation.from_rotvec([0, 0, math.radians(10)]).as_matrix())
        R_off = R @ off
        sharp = h.target_distribution(R).clone()
        sharp[:, 0] = h.target_distribution(R_off)[:, 0]
        broad = sharp.clone()
        broad[:, 0] = 0.3 * broad[:, 0] + 0.7 / 4096  # same mean direction, resultant x 0.3
        # (the lattice's own resultant is ~1e-5, not 0: hence 1e-4, not machine precision)
        torch.testing.assert_close(
            h.decode_distribution(broad), h.decode_distribution(sharp), atol=1e-4, rtol=0
        )
        # Without the normalisation the broad column would count less: a visible difference.
        unnormalised = special_orthogonalize((broad @ h.grid.double()).transpose(-1, -2))
        moved = geodesic_distance(unnormalised, h.decode_distribution(sharp))
        assert moved.min() > math.radians(1.0)

    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_nearly_antipodal_mass_on_a_column(self, batch):
        # Column 0 gets 52 % of its mass around r0 and 48 % around -r0 (resultant ~0.04 |E|):
        # the direction is still r0, and the SVD decides the rest from the other two columns.
        h = head()
        R = rotations(batch, seed=4)
        p = h.target_distribution(R).clone()
        flipped = h.target_distribution(-R)
        p[:, 0] = 0.52 * p[:, 0] + 0.48 * flipped[:, 0]
        err = geodesic_distance(h.decode_distribution(p), R)
        assert err.max() < math.radians(0.5)

    @pytest.mark.parametrize("batch", [1, 3, 8])
    @pytest.mark.parametrize("uav_pitch_deg", [-0.5, 0.0, 0.5, -2.0])
    def test_level_flight_relative_pitch_near_90(self, batch, uav_pitch_deg):
        # Relative attitude of level flight to a nadir camera: pitch ~90 deg (gimbal lock for
        # Euler angles, nothing special for three directions). Perturbed targets decode close.
        h = head()
        g = torch.Generator().manual_seed(batch)
        yaw = (torch.rand(batch, generator=g, dtype=torch.float64) * 2 - 1) * math.pi
        pitch = torch.full((batch,), math.radians(90 + uav_pitch_deg), dtype=torch.float64)
        roll = torch.randn(batch, generator=g, dtype=torch.float64) * 0.05
        R = euler_to_rotmat(yaw, pitch, roll)
        raw = perturbed_logits(h, R, noise=0.3, seed=batch)
        err = geodesic_distance(h.decode(raw), R)
        assert err.max() < math.radians(2.0)

    def test_gradcheck_float64(self):
        h = head(n_points=64)
        g = torch.Generator().manual_seed(0)
        logits = torch.randn(2, 3, 64, generator=g, dtype=torch.float64, requires_grad=True)
        assert torch.autograd.gradcheck(lambda x: h.decode(x), (logits,))


class TestLogProb:
    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_uniform_prediction_scores_zero(self, batch):
        h = head()
        lp = h.log_prob(torch.zeros(batch, 3, 4096, dtype=torch.float64), rotations(batch))
        torch.testing.assert_close(lp, torch.zeros(batch, dtype=torch.float64))

    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_convention_vmf_columns_give_the_matrix_fisher_density(self, batch):
        # Three lattice vMF columns around R0 (the training target, kappa 10): the density on SO(3)
        # is the matrix Fisher exp(tr(F^T R)) / c(F), F = kappa R0, at R0 and at perturbed R.
        kappa = 10.0
        h = head(kappa=kappa)
        R0 = rotations(batch, seed=7)
        small = torch.tensor(Rotation.random(batch, random_state=8).as_rotvec()) * 0.15
        R = R0 @ torch.tensor(Rotation.from_rotvec(small.numpy()).as_matrix())
        raw = torch.log(h.target_distribution(R0))
        # The lattice density is constant on each cell: evaluate tr(F^T R) with every column of R
        # replaced by its nearest lattice point (numpy), so only the quadrature error remains.
        grid = fibonacci_sphere(4096, dtype=torch.float64).numpy()
        cols = R.transpose(-1, -2).numpy()  # (B, 3 columns, 3)
        snapped = grid[np.argmax(cols @ grid.T, axis=-1)]  # (B, 3, 3)
        tr = torch.tensor(np.einsum("bji,bji->b", R0.transpose(-1, -2).numpy(), snapped))
        expected = kappa * tr - log_matrix_fisher_normaliser(kappa)
        torch.testing.assert_close(h.log_prob(raw, R), expected, atol=0.02, rtol=0)
        # At the mode (columns on lattice points up to < 2 deg): within 0.02 nat of the continuum.
        at_mode = 3 * kappa - log_matrix_fisher_normaliser(kappa)
        assert (h.log_prob(raw, R0) - at_mode).abs().max() < 0.03

    def test_normaliser_reference_agrees_with_monte_carlo(self):
        # Checks the reference itself: mean over Haar-uniform R of exp(tr(kappa R)) = c(kappa I).
        R = Rotation.random(200_000, random_state=0).as_matrix()
        mc = np.log(np.exp(2.0 * np.trace(R, axis1=1, axis2=2)).mean())
        assert mc == pytest.approx(log_matrix_fisher_normaliser(2.0), abs=0.01)

    @pytest.mark.parametrize(("noise", "tol"), [(0.5, 0.03), (1.0, 0.1)])
    def test_integrates_to_one_over_haar_monte_carlo(self, noise, tol):
        # exp(log_prob) integrates to 1 over Haar: the head's normaliser log Z = s(R) - log_prob(R)
        # equals the Monte Carlo log E_{R ~ Haar}[exp(s(R))] over scipy ``Rotation.random``, with
        # s(R) the summed column log-probabilities at the nearest lattice points (numpy). Random
        # logits are a rough field (log-normal density): MC and quadrature both scatter more as
        # the noise grows, hence the tolerances (MC std 0.005 and 0.02 nat at N = 50k).
        h = head()
        g = torch.Generator().manual_seed(11)
        raw = noise * torch.randn(1, 3, 4096, generator=g, dtype=torch.float64)
        log_z = self.head_log_normaliser(h, raw)
        mc = self.monte_carlo_log_normaliser(raw, 50_000, seed=12)
        assert log_z == pytest.approx(mc, abs=tol)

    def test_kappa_3_integrates_to_one_monte_carlo(self):
        h = head(kappa=3.0)
        raw = torch.log(h.target_distribution(rotations(1, seed=13)))
        log_z = self.head_log_normaliser(h, raw)
        assert log_z == pytest.approx(self.monte_carlo_log_normaliser(raw, 50_000, 14), abs=0.03)

    @staticmethod
    def head_log_normaliser(h, raw: torch.Tensor) -> float:
        R = rotations(4, seed=99)
        log_p = torch.log_softmax(raw, -1)[0].numpy()  # (3, n)
        s = TestLogProb.scores(log_p, R.numpy())
        lz = torch.tensor(s) - h.log_prob(raw.expand(4, -1, -1), R)
        assert float(lz.max() - lz.min()) < 1e-9  # one constant for every R
        return float(lz[0])

    @staticmethod
    def scores(log_p: np.ndarray, R: np.ndarray) -> np.ndarray:
        """s(R) = sum_j log p_j(nearest lattice point to R e_j); R (N, 3, 3) -> (N,)."""
        grid = fibonacci_sphere(log_p.shape[-1], dtype=torch.float64).numpy()
        total = np.zeros(len(R))
        for j in range(3):
            total += log_p[j, np.argmax(R[:, :, j] @ grid.T, axis=-1)]
        return total

    @staticmethod
    def monte_carlo_log_normaliser(raw: torch.Tensor, n: int, seed: int) -> float:
        log_p = torch.log_softmax(raw, -1)[0].numpy()
        s = np.concatenate(
            [
                TestLogProb.scores(
                    log_p, Rotation.random(10_000, random_state=seed + k).as_matrix()
                )
                for k in range(n // 10_000)
            ]
        )
        return float(np.log(np.mean(np.exp(s - s.max()))) + s.max())

    def test_gradcheck_float64(self):
        h = head(n_points=64)
        g = torch.Generator().manual_seed(2)
        logits = torch.randn(3, 3, 64, generator=g, dtype=torch.float64, requires_grad=True)
        R = rotations(3, seed=15)
        assert torch.autograd.gradcheck(lambda x: h.log_prob(x, R), (logits,))

    def test_grid_lattice_matches_the_head_grid(self):
        # The cached quadrature indices refer to the same Fibonacci lattice as the head's grid.
        h = head(n_points=64)
        torch.testing.assert_close(h.grid.double(), fibonacci_sphere(64, dtype=torch.float64))
