"""Sphere lattices and vMF against scipy.stats.vonmises_fisher and closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation
from scipy.stats import vonmises_fisher

from benchmark.geometry import (
    discrete_vmf,
    fibonacci_sphere,
    geodesic_distance,
    quat_to_rotmat,
    spherical_mean,
    super_fibonacci,
    vmf_density,
    vmf_log_density,
)

BATCHES = [1, 3, 8]
DTYPES = [torch.float32, torch.float64]


def unit(
    batch: int, dim: int = 3, seed: int = 0, dtype: torch.dtype = torch.float64
) -> torch.Tensor:
    x = torch.randn(batch, dim, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)
    return (x / x.norm(dim=-1, keepdim=True)).to(dtype)


def nearest_neighbour_angles(points: np.ndarray) -> np.ndarray:
    dist, _ = cKDTree(points).query(points, k=2)
    return 2 * np.arcsin(np.clip(dist[:, 1] / 2, 0, 1))


class TestFibonacciSphere:
    def test_shape_unit_and_default_is_paper_grid(self):
        g = fibonacci_sphere()
        assert g.shape == (64 * 64, 3) and g.dtype == torch.float32
        torch.testing.assert_close(g.norm(dim=-1), torch.ones(4096))

    def test_uniformity_nearest_neighbour_spread(self):
        g = fibonacci_sphere(4096, dtype=torch.float64).numpy()
        nn = nearest_neighbour_angles(g)
        # An ideal hexagonal packing of 4096 points has spacing sqrt(8 pi / (sqrt(3) n)).
        ideal = math.sqrt(8 * math.pi / (math.sqrt(3) * 4096))
        assert abs(nn.mean() / ideal - 1) < 0.1
        assert nn.std() / nn.mean() < 0.1
        assert nn.min() > 0.6 * ideal
        # i.i.d. uniform points for comparison are far less regular
        rnd = unit(4096, seed=1).numpy()
        assert nearest_neighbour_angles(rnd).std() > 3 * nn.std()

    def test_equal_area_caps(self):
        g = fibonacci_sphere(4096, dtype=torch.float64)
        for axis in unit(5, seed=2):
            for half_angle in (0.3, 1.0, 2.0):
                cap_fraction = (1 - math.cos(half_angle)) / 2
                count = int(((g @ axis) >= math.cos(half_angle)).sum())
                assert abs(count - 4096 * cap_fraction) < 0.02 * 4096 * cap_fraction + 8

    def test_deterministic_across_dtypes(self):
        torch.testing.assert_close(
            fibonacci_sphere(100, torch.float64).float(), fibonacci_sphere(100)
        )

    @pytest.mark.parametrize("n", [0, -3, 2.5])
    def test_rejects_bad_count(self, n):
        with pytest.raises(ValueError, match="positive int"):
            fibonacci_sphere(n)


class TestSuperFibonacci:
    def test_unit_quaternions(self):
        q = super_fibonacci(4096, dtype=torch.float64)
        assert q.shape == (4096, 4)
        torch.testing.assert_close(q.norm(dim=-1), torch.ones(4096, dtype=torch.float64))

    def test_uniformity_beats_random(self):
        q = super_fibonacci(4096, dtype=torch.float64).numpy()
        nn = nearest_neighbour_angles(q)
        rnd = nearest_neighbour_angles(unit(4096, dim=4, seed=3).numpy())
        assert nn.std() / nn.mean() < 0.5 * rnd.std() / rnd.mean()
        assert nn.min() > 3 * rnd.min()

    def test_covers_so3(self):
        # Every rotation has a lattice rotation close by: nearest-lattice geodesic distance of 500
        # random rotations. 4096 quaternions = 2048 rotations; a ball of radius r in SO(3) has
        # volume fraction (r - sin r)/pi, so uniform covering needs r of about 0.2 rad.
        grid = quat_to_rotmat(super_fibonacci(4096, dtype=torch.float64))
        R = torch.from_numpy(Rotation.random(500, random_state=4).as_matrix())
        dist = geodesic_distance(R[:, None], grid[None]).min(dim=1).values
        assert dist.max() < math.radians(25)
        assert dist.mean() < math.radians(12)


class TestVmfDensity:
    @pytest.mark.parametrize("dim", [3, 4])
    @pytest.mark.parametrize("kappa", [0.1, 1.0, 10.0, 100.0, 1e4])
    def test_matches_scipy(self, dim, kappa):
        mu = unit(1, dim, seed=5)[0]
        x = unit(8, dim, seed=6)
        # include points near mu, where the density is largest
        near = mu + 0.01 * x[0]
        x = torch.cat([x, mu[None], (near / near.norm())[None]])
        ref = vonmises_fisher(mu.numpy(), kappa).logpdf(x.numpy())
        got = vmf_log_density(x, mu, kappa).numpy()
        np.testing.assert_allclose(got, ref, rtol=1e-9, atol=1e-9)

    @pytest.mark.parametrize("dtype", DTYPES)
    def test_stable_large_kappa_float32(self, dtype):
        mu = unit(3, seed=7, dtype=dtype)
        dens = vmf_density(mu, mu, 1e4)
        # closed form at the mode on S^2: kappa / (2 pi (1 - exp(-2 kappa)))
        torch.testing.assert_close(dens, torch.full((3,), 1e4 / (2 * math.pi), dtype=dtype))

    def test_integrates_to_one_on_lattice(self):
        g = fibonacci_sphere(4096, dtype=torch.float64)
        for kappa in (1.0, 10.0):
            total = vmf_density(g, unit(1, seed=8)[0], kappa).sum() * 4 * math.pi / 4096
            assert total.item() == pytest.approx(1.0, rel=1e-3)

    @pytest.mark.parametrize("kappa", [0.0, -1.0, float("nan")])
    def test_rejects_bad_kappa(self, kappa):
        with pytest.raises(ValueError, match="kappa must be finite and > 0"):
            vmf_density(unit(2), unit(2), kappa)

    def test_rejects_non_unit_and_bad_shape(self):
        with pytest.raises(ValueError, match="unit vectors"):
            vmf_density(2 * unit(2), unit(2), 1.0)
        with pytest.raises(ValueError, match=r"got \(2, 5\)"):
            vmf_density(torch.ones(2, 5), torch.ones(2, 5), 1.0)

    def test_gradcheck_mu(self):
        x = unit(3, seed=9)
        mu = unit(1, seed=10).requires_grad_()
        assert torch.autograd.gradcheck(lambda m: vmf_log_density(x, m, 5.0), (mu,))


class TestDiscreteVmf:
    @pytest.mark.parametrize("batch", BATCHES)
    @pytest.mark.parametrize("dtype", DTYPES)
    def test_normalised(self, batch, dtype):
        p = discrete_vmf(unit(batch, dtype=dtype), 10.0, fibonacci_sphere(dtype=dtype))
        assert p.shape == (batch, 4096)
        torch.testing.assert_close(p.sum(-1), torch.ones(batch, dtype=dtype))

    @pytest.mark.parametrize("kappa", [1.0, 5.0, 10.0, 20.0, 50.0])
    def test_mean_resultant_length_closed_form(self, kappa):
        # E[x] = (coth k - 1/k) mu for the vMF on S^2.
        grid = fibonacci_sphere(4096, dtype=torch.float64)
        mu = unit(1, seed=11)
        resultant = discrete_vmf(mu, kappa, grid) @ grid
        expected = 1 / math.tanh(kappa) - 1 / kappa
        assert resultant.norm().item() == pytest.approx(expected, rel=2e-3)

    def test_proportional_to_continuous_density(self):
        grid = fibonacci_sphere(4096, dtype=torch.float64)
        mu = unit(1, seed=12)[0]
        p = discrete_vmf(mu, 10.0, grid)
        torch.testing.assert_close(
            p * 4096 / (4 * math.pi), vmf_density(grid, mu, 10.0), rtol=3e-3, atol=0
        )

    def test_per_sample_kappa(self):
        grid = fibonacci_sphere(dtype=torch.float64)
        mu = unit(2, seed=13)
        p = discrete_vmf(mu, torch.tensor([1.0, 50.0], dtype=torch.float64), grid)
        torch.testing.assert_close(p[0], discrete_vmf(mu[0], 1.0, grid))
        torch.testing.assert_close(p[1], discrete_vmf(mu[1], 50.0, grid))

    def test_rejects_bad_kappa(self):
        with pytest.raises(ValueError, match="kappa"):
            discrete_vmf(unit(1), 0.0, fibonacci_sphere(16, dtype=torch.float64))


class TestSphericalMean:
    @pytest.mark.parametrize("batch", BATCHES)
    @pytest.mark.parametrize("kappa", [1.0, 10.0, 50.0])
    def test_recovers_mean_of_target(self, batch, kappa):
        grid = fibonacci_sphere(dtype=torch.float64)
        mu = unit(batch, seed=14)
        got = spherical_mean(discrete_vmf(mu, kappa, grid), grid)
        angle = torch.arccos((got * mu).sum(-1).clamp(-1, 1))
        assert angle.max() < math.radians(0.5)

    def test_eq9_sample_mean(self):
        x = unit(20, seed=15)
        got = spherical_mean(torch.ones(20, dtype=torch.float64), x)
        torch.testing.assert_close(got, x.sum(0) / x.sum(0).norm())

    def test_gradcheck(self):
        grid = fibonacci_sphere(64, dtype=torch.float64)
        p = torch.rand(3, 64, dtype=torch.float64, requires_grad=True)
        assert torch.autograd.gradcheck(lambda w: spherical_mean(w, grid), (p,))

    def test_rejects_mismatched_grid(self):
        with pytest.raises(ValueError, match=r"p must have shape \(\.\.\., 64\)"):
            spherical_mean(torch.rand(2, 65), fibonacci_sphere(64))
