"""Flight fusion (issue 39, item 3) against independent references: a closed-form Kalman filter and
RTS smoother written here, the wrapped normal's characteristic function, scipy.stats densities,
and the odometry noise's own figures over many draws. Float64 throughout."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch
from scipy import stats

from benchmark.evaluation.fusion import (
    CircularGrid,
    OdometryNoise,
    PlanarGrid,
    PositionFlights,
    YawFlights,
    carry_position,
    carry_yaw,
    filter_and_smooth_position,
    filter_and_smooth_yaw,
    filter_position,
    filter_yaw,
    gaussian_belief,
    normalize_log_density,
    position_transition_covariance,
    robust_log_likelihood,
    simulate_odometry,
    smooth_position,
    smooth_yaw,
    von_mises_belief,
    yaw_transition_sigma,
)
from benchmark.evaluation.fusion_grid import (
    exp_floored,
    exp_floored_,
    logaddexp_constant,
    logsumexp_floored,
)

DEG = math.pi / 180
F64 = torch.float64
YAW = CircularGrid(720)


def t(x: np.ndarray | float) -> torch.Tensor:
    return torch.as_tensor(x, dtype=F64)


def wrap(a: np.ndarray) -> np.ndarray:
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def yaw_centres(n: int) -> np.ndarray:
    return -np.pi + 2 * np.pi * np.arange(n) / n


def masses(log_density: torch.Tensor, cell: float) -> np.ndarray:
    return np.exp(log_density.numpy()) * cell


def moments(p: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and variance of masses ``p (..., n)`` on points ``x (n,)`` (linear, no wrap)."""
    mean = (p * x).sum(-1)
    return mean, (p * (x - mean[..., None]) ** 2).sum(-1)


def kalman(z, u, q, r, observed):
    """Scalar Kalman filter and RTS smoother, flat prior (the first sample must be observed):
    ``z (K,)`` measurements of variance ``r``, ``u (K-1,)`` increments of variance ``q (K-1,)``.
    Returns filtered and smoothed (mean, variance), each ``(K,)``."""
    K = len(z)
    xf, Pf = np.zeros(K), np.zeros(K)
    x, P = z[0], r
    for k in range(K):
        if k:
            x, P = x + u[k - 1], P + q[k - 1]
            if observed[k]:
                gain = P / (P + r)
                x, P = x + gain * (z[k] - x), (1 - gain) * P
        xf[k], Pf[k] = x, P
    xs, Ps = xf.copy(), Pf.copy()
    for k in range(K - 2, -1, -1):
        x_pred, P_pred = xf[k] + u[k], Pf[k] + q[k]
        gain = Pf[k] / P_pred
        xs[k] = xf[k] + gain * (xs[k + 1] - x_pred)
        Ps[k] = Pf[k] + gain**2 * (Ps[k + 1] - P_pred)
    return (xf, Pf), (xs, Ps)


def gaussian_yaw_beliefs(z: np.ndarray, r: float, n: int) -> torch.Tensor:
    """Unnormalised wrapped-difference Gaussian log-densities ``(..., n)`` around ``z``."""
    return t(-0.5 * wrap(yaw_centres(n) - np.asarray(z)[..., None]) ** 2 / r**2)


# ---------------------------------------------------------------------------------------- grids


class TestCircularGrid:
    def test_centres_and_measure(self):
        np.testing.assert_allclose(YAW.centres().numpy(), yaw_centres(720), atol=1e-15)
        assert YAW.spacing == pytest.approx(0.5 * DEG)
        assert math.exp(YAW.log_uniform) * YAW.cell * 720 == pytest.approx(1.0)

    def test_rejects_small(self):
        with pytest.raises(ValueError, match="n_bins"):
            CircularGrid(4)


class TestPlanarGrid:
    def test_around_covers_points_with_margin(self):
        points = np.array([[10.0, -5.0], [130.0, 42.0]])
        grid = PlanarGrid.around(points, spacing=2.0, margin=20.0)
        east, north = grid.centres()
        assert east[0] == -10.0 and north[0] == -25.0
        assert east[-1] >= 150.0 and north[-1] >= 62.0
        assert grid.shape == (grid.n_east, grid.n_north) and grid.cell == 4.0

    def test_rejects_bad_spacing(self):
        with pytest.raises(ValueError, match="spacing"):
            PlanarGrid(0.0, 0.0, 0.0, 10, 10)


class TestNormalizeLogDensity:
    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_mass_one(self, batch):
        logits = torch.randn(batch, 720, dtype=F64, generator=torch.Generator().manual_seed(batch))
        out = normalize_log_density(logits, YAW)
        np.testing.assert_allclose(masses(out, YAW.cell).sum(-1), 1.0, atol=1e-13)
        np.testing.assert_allclose((out - logits).std(-1).numpy(), 0.0, atol=1e-13)


# -------------------------------------------------------------------------------------- beliefs


class TestExpFloored:
    def test_equals_exp_above_the_floor_and_zero_below(self):
        x = t(np.concatenate([np.linspace(-699.9, 5.0, 501), [-700.5, -708.4, -745.2, -1e4]]))
        x = torch.cat([x, torch.tensor([-math.inf], dtype=F64)])
        out = exp_floored(x)
        assert torch.equal(out[:501], torch.exp(x[:501]))
        assert torch.equal(out[501:], torch.zeros(5, dtype=F64))

    def test_the_in_place_form_gives_the_same_bits_in_its_argument(self):
        g = torch.Generator().manual_seed(3)
        x = 400.0 * torch.randn(2000, dtype=F64, generator=g)  # a third below the floor
        x[:3] = torch.tensor([-math.inf, math.nan, -700.0], dtype=F64)
        buffer = x.clone()
        out = exp_floored_(buffer)
        assert out.data_ptr() == buffer.data_ptr()  # in place
        reference = torch.where(x < -700.0, 0.0, torch.exp(x))  # exp's slow path, same values
        assert torch.equal(out[2:], reference[2:])  # -700 itself: exp(-700), kept
        assert bool(out[0] == 0) and bool(out[1].isnan())  # -inf -> 0; NaN stays NaN
        assert torch.equal(exp_floored(x)[2:], out[2:]) and bool(exp_floored(x)[1].isnan())


class TestLogsumexpFloored:
    def test_against_torch_logsumexp(self):
        rng = np.random.default_rng(0)
        x = t(rng.normal(0, 200, (5, 30, 40)))  # spans the floor: terms 700 below the peak
        x[1] = -math.inf  # every term -inf: -inf, as torch's
        x[2, :3] = math.nan
        ours = logsumexp_floored(x, (-2, -1))
        ref = torch.logsumexp(x, dim=(-2, -1), keepdim=True)
        assert ours.shape == ref.shape == (5, 1, 1)
        torch.testing.assert_close(ours, ref, rtol=1e-15, atol=0, equal_nan=True)


class TestLogaddexpConstant:
    @pytest.mark.parametrize("c", [-750.0, -12.3, 0.0, 40.0])
    def test_against_torch_logaddexp(self, c):
        x = t(np.concatenate([np.linspace(-2000, 100, 3001), [-math.inf, math.inf]]))
        ref = torch.logaddexp(x, torch.full_like(x, c))
        # the clamp at c - 700 adds at most log1p(e^-700) ~ 1e-304, absolute
        torch.testing.assert_close(logaddexp_constant(x, c), ref, rtol=1e-15, atol=1e-303)

    def test_gradient_float64(self):
        x = t(np.linspace(-5, 5, 7)).requires_grad_()
        assert torch.autograd.gradcheck(lambda v: logaddexp_constant(v, 0.7), (x,))

    def test_constant_must_be_finite(self):
        with pytest.raises(ValueError, match="finite"):
            logaddexp_constant(t(np.zeros(3)), -math.inf)


class TestVonMisesBelief:
    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_matches_scipy(self, batch):
        rng = np.random.default_rng(batch)
        mu, kappa = rng.uniform(-np.pi, np.pi, batch), rng.uniform(0.5, 500.0, batch)
        got = von_mises_belief(YAW, t(mu), t(kappa)).numpy()
        ref = stats.vonmises.logpdf(yaw_centres(720), kappa[:, None], loc=mu[:, None])
        np.testing.assert_allclose(got, ref, atol=1e-10)

    def test_float_arguments(self):
        out = von_mises_belief(YAW, 0.3, 50.0)
        assert out.shape == (720,) and out.dtype == F64


class TestGaussianBelief:
    @pytest.mark.parametrize("batch", [1, 3])
    def test_matches_scipy(self, batch):
        grid = PlanarGrid(-100.0, -60.0, 1.0, 200, 120)
        rng = np.random.default_rng(batch)
        mean, sigma = rng.uniform(-20, 20, (batch, 2)), rng.uniform(5, 10, batch)
        got = gaussian_belief(grid, t(mean), t(sigma)).numpy()
        east, north = (c.numpy() for c in grid.centres())
        ref = stats.norm.logpdf(
            east[:, None], mean[:, None, None, 0], sigma[:, None, None]
        ) + stats.norm.logpdf(north, mean[:, None, None, 1], sigma[:, None, None])
        np.testing.assert_allclose(got, ref, atol=1e-9)


# ----------------------------------------------------------------------------------- transition


class TestCarryYaw:
    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_forward_and_back_returns_and_conserves_mass(self, batch):
        # Stated tolerance: 1e-11 of the peak density for a belief resolved by the grid (a von
        # Mises of at least ~2 bins' width); the Fourier shift is unitary, only rounding remains.
        rng = np.random.default_rng(batch)
        belief = von_mises_belief(YAW, t(rng.uniform(-3.2, 3.2, batch)), 1000.0)
        shift = t(rng.uniform(-0.5, 0.5, batch))
        there = carry_yaw(belief, YAW, shift, 0.0)
        back = carry_yaw(there, YAW, -shift, 0.0)
        peak = belief.exp().amax().item()
        np.testing.assert_allclose(back.exp().numpy(), belief.exp().numpy(), atol=1e-11 * peak)
        np.testing.assert_allclose(masses(there, YAW.cell).sum(-1), 1.0, atol=1e-13)

    def test_moments_are_the_wrapped_normal_ones(self):
        # E exp(i psi) is multiplied by exp(i d - sigma^2 / 2): the wrapped normal's
        # characteristic function, exact on the grid.
        psi = yaw_centres(720)
        belief = von_mises_belief(YAW, t([0.4, -2.0]), t([30.0, 3.0]))
        shift, sigma = t([2.9, -1.7]), t([0.05, 0.8])
        out = carry_yaw(belief, YAW, shift, sigma)
        z_in = (masses(belief, YAW.cell) * np.exp(1j * psi)).sum(-1)
        z_out = (masses(out, YAW.cell) * np.exp(1j * psi)).sum(-1)
        expected = z_in * np.exp(1j * shift.numpy() - 0.5 * sigma.numpy() ** 2)
        np.testing.assert_allclose(z_out, expected, atol=1e-13)
        np.testing.assert_allclose(masses(out, YAW.cell).sum(-1), 1.0, atol=1e-13)

    def test_wrap_around(self):
        # A belief at +179 deg shifted by +3 deg lands at -178 deg, across the boundary.
        belief = von_mises_belief(YAW, t(179 * DEG), 3000.0)
        out = carry_yaw(belief, YAW, 3 * DEG, 0.2 * DEG)
        p = masses(out, YAW.cell)
        mean = np.angle((p * np.exp(1j * yaw_centres(720))).sum())
        assert mean == pytest.approx(-178 * DEG, abs=1e-10)
        assert p.sum() == pytest.approx(1.0, abs=1e-13)

    def test_float32(self):
        belief = von_mises_belief(YAW, torch.tensor([1.0]), 100.0)
        out = carry_yaw(belief, YAW, 0.3, 0.01)
        assert out.dtype == torch.float32
        assert float((out.exp() * YAW.cell).sum()) == pytest.approx(1.0, abs=1e-5)

    def test_rejects_negative_sigma(self):
        with pytest.raises(ValueError, match="sigma"):
            carry_yaw(von_mises_belief(YAW, 0.0, 10.0), YAW, 0.0, -1.0)


class TestCarryPosition:
    GRID = PlanarGrid(-100.0, -80.0, 1.0, 200, 160)

    @pytest.mark.parametrize("batch", [1, 3])
    def test_forward_and_back_returns_and_conserves_mass(self, batch):
        # Stated tolerance: 1e-11 of the peak for a Gaussian of 6 cells' width far from the edge.
        rng = np.random.default_rng(batch)
        belief = gaussian_belief(self.GRID, t(rng.uniform(-20, 20, (batch, 2))), 6.0)
        d = t(rng.uniform(-15, 15, (batch, 2)))
        zero = torch.zeros(2, 2, dtype=F64)
        there, lost = carry_position(belief, self.GRID, d, zero)
        back, _ = carry_position(there, self.GRID, -d, zero)
        peak = belief.exp().amax().item()
        np.testing.assert_allclose(back.exp().numpy(), belief.exp().numpy(), atol=1e-11 * peak)
        np.testing.assert_allclose(masses(there, self.GRID.cell).sum((-2, -1)), 1.0, atol=1e-13)
        np.testing.assert_allclose(lost.numpy(), 0.0, atol=1e-15)

    def test_moments_shift_and_covariances_add(self):
        belief = gaussian_belief(self.GRID, t([[-10.0, 5.0]]), 4.0)
        d, cov = t([[12.3, -7.9]]), t([[[9.0, 3.0], [3.0, 4.0]]])
        out, _ = carry_position(belief, self.GRID, d, cov)
        p = masses(out, self.GRID.cell)[0]
        east, north = (c.numpy() for c in self.GRID.centres())
        E, N = np.meshgrid(east, north, indexing="ij")
        mean = np.array([(p * E).sum(), (p * N).sum()])
        dE, dN = E - mean[0], N - mean[1]
        got = np.array([[(p * dE * dE).sum(), (p * dE * dN).sum()], [0, (p * dN * dN).sum()]])
        got[1, 0] = got[0, 1]
        np.testing.assert_allclose(mean, [2.3, -2.9], atol=1e-10)
        np.testing.assert_allclose(got, 16.0 * np.eye(2) + cov[0].numpy(), atol=1e-8)

    def test_escaped_mass_is_the_gaussian_tail(self):
        # A Gaussian pushed to 1.5 sigma of the east edge loses the tail beyond it (scipy).
        grid = self.GRID
        edge = grid.east0 + grid.spacing * (grid.n_east - 0.5)  # the last cell's outer side
        belief = gaussian_belief(grid, t([[edge - 40.0, 0.0]]), 5.0)
        out, lost = carry_position(belief, grid, t([[32.5, 0.0]]), torch.zeros(2, 2, dtype=F64))
        assert float(lost[0]) == pytest.approx(stats.norm.sf(1.5), rel=2e-2)
        assert masses(out, grid.cell).sum() == pytest.approx(1.0, abs=1e-13)


# -------------------------------------------------------------------------- measurement update


class TestRobustLogLikelihood:
    @pytest.mark.parametrize("weight", [0.0, 0.3, 1.0])
    def test_closed_form(self, weight):
        logits = torch.randn(3, 720, dtype=F64, generator=torch.Generator().manual_seed(0))
        b = np.exp(logits.numpy())
        b /= b.sum(-1, keepdims=True) * YAW.cell
        expected = np.log((1 - weight) * b + weight / (2 * np.pi))
        got = robust_log_likelihood(logits, YAW, weight).numpy()
        np.testing.assert_allclose(got, expected, atol=1e-12)

    def test_rejects_weight(self):
        with pytest.raises(ValueError, match="outlier_weight"):
            robust_log_likelihood(torch.zeros(720, dtype=F64), YAW, 1.5)


# ------------------------------------------------------------------------- filter and smoother


def linear_gaussian_yaw(seed: int, K: int = 25):
    """Measurements near 0 (far from +-pi), odometry with per-step noise, frames 7 and 8 missing."""
    rng = np.random.default_rng(seed)
    truth = np.cumsum(np.r_[-0.4, rng.normal(0.03, 1.0 * DEG, K - 1)])
    u = np.diff(truth) + rng.normal(0, 1.0 * DEG, K - 1)
    q = np.full(K - 1, (1.0 * DEG) ** 2)
    r = 3.0 * DEG
    z = truth + rng.normal(0, r, K)
    observed = np.ones(K, bool)
    observed[[7, 8]] = False
    return z, u, q, r, observed


def fused_yaw(fuse, z, u, q, r, observed):
    beliefs = gaussian_yaw_beliefs(z, r, 720)[None]  # r: standard deviation
    observed = torch.tensor(observed)[None]
    return fuse(YawFlights(beliefs, t(u)[None], t(np.sqrt(q))[None], observed), YAW, 0.0)


def assert_kalman_yaw(fuse, seed: int, smoothed: bool):
    z, u, q, r, observed = inputs = linear_gaussian_yaw(seed)
    reference = kalman(z, u, q, r**2, observed)[smoothed]
    post = fused_yaw(fuse, *inputs)
    # Stated tolerance: means 1e-9 rad, variances 1e-7 relative (beliefs of 6 bins' width; the
    # wrapped normal equals the normal to exp(-pi^2 / (2 sigma^2)) this far from +-pi).
    mean, var = moments(masses(post.log_density[0], YAW.cell), yaw_centres(720))
    np.testing.assert_allclose(mean, reference[0], atol=1e-9)
    np.testing.assert_allclose(var, reference[1], rtol=1e-7)
    np.testing.assert_allclose(post.map[0].numpy(), reference[0], atol=1e-9)
    np.testing.assert_allclose(post.mean[0].numpy(), reference[0], atol=1e-9)


def synthetic_yaw_flights(seed: int, B: int = 6, K: int = 40, outliers: float = 0.3):
    """True yaw (B, K) turning flights, von Mises beliefs (5 deg) with outliers, odometry."""
    rng = np.random.default_rng(seed)
    truth = wrap(
        np.cumsum(rng.normal(0, 10 * DEG, (B, K)), axis=1) + rng.uniform(-np.pi, np.pi, (B, 1))
    )
    wrong = rng.random((B, K)) < outliers
    centre = np.where(
        wrong, rng.uniform(-np.pi, np.pi, (B, K)), truth + rng.normal(0, 5 * DEG, (B, K))
    )
    beliefs = von_mises_belief(YAW, t(centre), 1 / (5 * DEG) ** 2)
    noise = OdometryNoise()
    odo = simulate_odometry(truth, np.zeros((B, K, 2)), 2.0, noise, rng)
    return truth, centre, YawFlights(beliefs, t(odo.dyaw), yaw_transition_sigma(noise, 2.0))


def mean_abs_deg(a, truth) -> float:
    return float(np.degrees(np.abs(wrap(np.asarray(a) - truth))).mean())


CHANGES = ["belief", "odometry"]


def causality_yaw_inputs(change: str):
    """Two flights of 20 samples, and the same with flight 0's sample 12 changed: its belief or
    the odometry increment into it."""
    _, _, flights = synthetic_yaw_flights(seed=0, B=2, K=20)
    beliefs, dyaw = flights.beliefs.clone(), flights.dyaw.clone()
    if change == "belief":
        beliefs[0, 12] = von_mises_belief(YAW, 2.0, 300.0)
    else:
        dyaw[0, 11] += 0.3
    return flights, replace(flights, beliefs=beliefs, dyaw=dyaw)


def assert_fields(a, b, names, index, same: bool) -> None:
    for name in names:
        x, y = getattr(a, name)[index], getattr(b, name)[index]
        assert torch.equal(x, y) == same, (name, index)


def assert_causal(a, b, fields) -> None:
    """Flight 0's sample 12 changed: the filter's samples 0-11 keep their bits, sample 12 moves,
    the other flight of the batch keeps its bits."""
    assert_fields(a, b, fields, (0, slice(0, 12)), same=True)
    assert_fields(a, b, ("log_density",), (0, 12), same=False)
    assert_fields(a, b, fields, 1, same=True)


def assert_reads_later(a, b) -> None:
    """The smoother's earlier samples of flight 0 move; the other flight keeps its bits."""
    for k in (0, 6, 11):
        assert_fields(a, b, ("log_density",), (0, k), same=False)
    assert_fields(a, b, ("log_density", "map"), 1, same=True)


class TestFilterYaw:
    @pytest.mark.parametrize("seed", [0, 1])
    def test_linear_gaussian_equals_kalman(self, seed):
        assert_kalman_yaw(filter_yaw, seed, smoothed=False)

    @pytest.mark.parametrize("change", CHANGES)
    def test_causal_bit_identical(self, change):
        before, after = causality_yaw_inputs(change)
        fields = ("log_density", "map", "mean", "resultant")
        assert_causal(filter_yaw(before, YAW), filter_yaw(after, YAW), fields)

    def test_synthetic_flight_far_below_per_frame(self):
        truth, centre, flights = synthetic_yaw_flights(seed=3)
        post = filter_yaw(flights, YAW)
        per_frame, fused = mean_abs_deg(centre, truth), mean_abs_deg(post.map, truth)
        assert per_frame > 20.0
        # The first samples, before the filter has seen enough, dominate its mean error.
        assert fused < per_frame / 4, (per_frame, fused)

    def test_unobserved_frame_is_a_prediction(self):
        _, _, flights = synthetic_yaw_flights(seed=4, B=1, K=3)
        flights.beliefs[:, 2] = math.nan  # never read
        post = filter_yaw(replace(flights, observed=torch.tensor([[True, True, False]])), YAW)
        expected = carry_yaw(post.log_density[:, 1], YAW, flights.dyaw[:, 1], flights.sigma)
        torch.testing.assert_close(post.log_density[:, 2], expected, atol=1e-12, rtol=0)


class TestSmoothYaw:
    @pytest.mark.parametrize("seed", [0, 1])
    def test_linear_gaussian_equals_rts(self, seed):
        assert_kalman_yaw(smooth_yaw, seed, smoothed=True)

    @pytest.mark.parametrize("change", CHANGES)
    def test_a_later_sample_changes_earlier_estimates(self, change):
        before, after = causality_yaw_inputs(change)
        assert_reads_later(smooth_yaw(before, YAW), smooth_yaw(after, YAW))

    def test_synthetic_flight_below_the_filter(self):
        truth, centre, flights = synthetic_yaw_flights(seed=3)
        filtered = mean_abs_deg(filter_yaw(flights, YAW).map, truth)
        smoothed = mean_abs_deg(smooth_yaw(flights, YAW).map, truth)
        assert smoothed < filtered, (filtered, smoothed)
        assert smoothed < mean_abs_deg(centre, truth) / 8


# -------------------------------------------------------------------------------------- position


def linear_gaussian_position(seed: int, K: int = 15):
    """A flight east along N = 0 with per-step noise; per axis an independent linear model."""
    rng = np.random.default_rng(seed)
    q, r = 1.0, 3.0
    truth = np.stack([np.arange(K) * 10.0, np.zeros(K)], -1) + np.cumsum(
        rng.normal(0, q, (K, 2)), 0
    )
    d = np.diff(truth, axis=0) + rng.normal(0, q, (K - 1, 2))
    z = truth + rng.normal(0, r, (K, 2))
    observed = np.ones(K, bool)
    observed[5] = False
    grid = PlanarGrid(-40.0, -40.0, 0.5, 380, 160)
    return grid, z, d, q, r, observed


def fused_position(fuse, grid, z, d, q, r, observed):
    K = len(z)
    beliefs = gaussian_belief(grid, t(z), r)[None]
    cov = t(np.tile(q**2 * np.eye(2), (1, K - 1, 1, 1)))
    observed = torch.tensor(observed)[None]
    return fuse(PositionFlights(beliefs, t(d)[None], cov, observed), grid, 0.0)


def assert_kalman_position(fuse, seed: int, smoothed: bool):
    # Stated tolerance: means 1e-8 m, variances 1e-6 relative (beliefs of 6 cells' width).
    grid, z, d, q, r, observed = inputs = linear_gaussian_position(seed)
    post = fused_position(fuse, *inputs)
    K = len(z)
    p = masses(post.log_density[0], grid.cell)
    for axis, centres in enumerate(grid.centres()):
        reference = kalman(z[:, axis], d[:, axis], np.full(K - 1, q**2), r**2, observed)[smoothed]
        marginal = p.sum(-1) if axis == 0 else p.sum(-2)
        mean, var = moments(marginal, centres.numpy())
        np.testing.assert_allclose(mean, reference[0], atol=1e-8)
        np.testing.assert_allclose(var, reference[1], rtol=1e-6)
        np.testing.assert_allclose(post.map[0, :, axis].numpy(), reference[0], atol=1e-6)
        np.testing.assert_allclose(post.mean[0, :, axis].numpy(), reference[0], atol=1e-8)
    np.testing.assert_allclose(post.escaped.numpy(), 0.0, atol=1e-14)


def synthetic_position_flights(seed: int, B: int = 3, K: int = 40, outliers: float = 0.3):
    """Flights at 10 m/s, samples every 2 s; Gaussian beliefs (30 m) with outliers on the grid."""
    rng = np.random.default_rng(seed)
    yaw = np.cumsum(rng.normal(0, 10 * DEG, (B, K)), axis=1)
    steps = 20.0 * np.stack([-np.sin(yaw), np.cos(yaw)], -1)  # yaw 0 north, +90 west
    truth = np.cumsum(steps, axis=1) - steps[:, :1]
    grid = PlanarGrid.around(truth, spacing=5.0, margin=150.0)
    east, north = (c.numpy() for c in grid.centres())
    wrong = (rng.random((B, K)) < outliers)[..., None]
    anywhere = np.stack(
        [rng.uniform(east[0], east[-1], (B, K)), rng.uniform(north[0], north[-1], (B, K))], -1
    )
    centre = np.where(wrong, anywhere, truth + rng.normal(0, 30.0, (B, K, 2)))
    beliefs = gaussian_belief(grid, t(centre), 30.0)
    noise = OdometryNoise()
    odo = simulate_odometry(yaw, truth, 2.0, noise, rng)
    d = t(odo.displacement)
    return (
        grid,
        truth,
        centre,
        PositionFlights(beliefs, d, position_transition_covariance(d, noise)),
    )


def mean_distance(a, truth) -> float:
    return float(np.linalg.norm(np.asarray(a) - truth, axis=-1).mean())


def causality_position_inputs(change: str):
    """As :func:`causality_yaw_inputs`, on the plane (a larger increment also widens the pad)."""
    grid, _, _, flights = synthetic_position_flights(seed=1, B=2, K=16)
    beliefs, d = flights.beliefs.clone(), flights.displacement.clone()
    if change == "belief":
        beliefs[0, 12] = gaussian_belief(grid, t([grid.east0 + 30.0, grid.north0 + 30.0]), 30.0)
    else:
        d[0, 11] += 40.0
    return grid, flights, replace(flights, beliefs=beliefs, displacement=d)


class TestFilterPosition:
    def test_linear_gaussian_equals_kalman(self):
        assert_kalman_position(filter_position, seed=0, smoothed=False)

    @pytest.mark.parametrize("change", CHANGES)
    def test_causal_bit_identical(self, change):
        # Each flight and step has its own FFT length: the other flight stays bit-identical too.
        grid, before, after = causality_position_inputs(change)
        fields = ("log_density", "map", "mean", "escaped")
        assert_causal(filter_position(before, grid), filter_position(after, grid), fields)

    def test_synthetic_flight_far_below_per_frame(self):
        grid, truth, centre, flights = synthetic_position_flights(seed=2)
        post = filter_position(flights, grid)
        per_frame, fused = mean_distance(centre, truth), mean_distance(post.map, truth)
        assert per_frame > 80.0
        assert fused < per_frame / 5, (per_frame, fused)
        # Only the uniform share of a robust posterior reaches the edge: |d| / width of it leaves.
        assert float(post.escaped.max()) < 0.02


class TestSmoothPosition:
    def test_linear_gaussian_equals_rts(self):
        assert_kalman_position(smooth_position, seed=0, smoothed=True)

    @pytest.mark.parametrize("change", CHANGES)
    def test_a_later_sample_changes_earlier_estimates(self, change):
        grid, before, after = causality_position_inputs(change)
        assert_reads_later(smooth_position(before, grid), smooth_position(after, grid))

    def test_synthetic_flight_below_the_filter(self):
        grid, truth, _, flights = synthetic_position_flights(seed=2)
        filtered = mean_distance(filter_position(flights, grid).map, truth)
        smoothed = mean_distance(smooth_position(flights, grid).map, truth)
        assert smoothed < filtered, (filtered, smoothed)


# -------------------------------------------------------------------------------------- odometry


def random_flights(rng: np.random.Generator, B: int, K: int):
    yaw = rng.uniform(-np.pi, np.pi, (B, K))
    position = rng.uniform(-100.0, 100.0, (B, K, 2))
    return yaw, position


class TestSimulateOdometry:
    NOISE = OdometryNoise(
        gyro_bias_sigma=0.5 * DEG,
        yaw_walk_sigma=0.3 * DEG,
        scale_sigma=0.05,
        position_step_sigma=2.0,
    )

    def test_matches_stated_figures(self):
        # 20000 flights of 3 samples; each check within 4 standard errors of its figure.
        rng = np.random.default_rng(0)
        B, dt, n = 20000, 2.0, self.NOISE
        yaw, position = random_flights(rng, B, 3)
        odo = simulate_odometry(yaw, position, dt, n, rng)
        error = wrap(odo.dyaw - np.diff(yaw, axis=1))  # (B, 2)
        var_flight = (n.gyro_bias_sigma * dt) ** 2
        se = 4 / math.sqrt(B)
        assert odo.gyro_bias.std() == pytest.approx(n.gyro_bias_sigma, rel=se * 0.75)
        assert abs(error.mean()) < se * math.sqrt(var_flight + n.yaw_walk_sigma**2)
        assert error.std() == pytest.approx(math.sqrt(var_flight + n.yaw_walk_sigma**2), rel=se)
        # The bias is shared by a flight's increments: their covariance is (sigma_b dt)^2.
        cov = np.cov(error[:, 0], error[:, 1])[0, 1]
        assert cov == pytest.approx(var_flight, abs=se * (var_flight + n.yaw_walk_sigma**2))
        walk = error - odo.gyro_bias[:, None] * dt
        assert walk.std() == pytest.approx(n.yaw_walk_sigma, rel=se)
        true_d = np.diff(position, axis=1)
        residual = odo.displacement - (1 + odo.scale_error[:, None, None]) * true_d
        assert odo.scale_error.std() == pytest.approx(n.scale_sigma, rel=se * 0.75)
        assert abs(odo.scale_error.mean()) < se * n.scale_sigma
        assert residual.std() == pytest.approx(n.position_step_sigma, rel=se)
        assert abs(residual.mean()) < se * n.position_step_sigma

    def test_seeded(self):
        yaw, position = random_flights(np.random.default_rng(1), 3, 5)
        a, b = (
            simulate_odometry(yaw, position, 0.5, self.NOISE, np.random.default_rng(7))
            for _ in range(2)
        )
        np.testing.assert_array_equal(a.dyaw, b.dyaw)
        np.testing.assert_array_equal(a.displacement, b.displacement)
        assert a.dyaw.shape == (3, 4) and a.displacement.shape == (3, 4, 2)

    def test_noiseless_is_the_truth(self):
        yaw, position = random_flights(np.random.default_rng(2), 2, 6)
        zero = OdometryNoise(0.0, 0.0, 0.0, 0.0)
        odo = simulate_odometry(yaw, position, 1.0, zero, np.random.default_rng(0))
        np.testing.assert_allclose(wrap(odo.dyaw - np.diff(yaw, axis=1)), 0.0, atol=1e-12)
        np.testing.assert_allclose(odo.displacement, np.diff(position, axis=1), atol=1e-12)

    def test_rejects_shapes(self):
        with pytest.raises(ValueError, match="position"):
            simulate_odometry(
                np.zeros((2, 3)), np.zeros((2, 3)), 1.0, self.NOISE, np.random.default_rng()
            )


class TestYawTransitionSigma:
    def test_matches_the_drift_over_the_horizon(self):
        # Over `horizon` steps the white model's variance equals the simulated drift's.
        noise, dt, horizon, B = OdometryNoise(), 2.0, 4, 20000
        rng = np.random.default_rng(5)
        yaw, position = random_flights(rng, B, horizon + 1)
        odo = simulate_odometry(yaw, position, dt, noise, rng)
        drift = wrap(odo.dyaw - np.diff(yaw, axis=1)).sum(axis=1)
        expected = horizon * yaw_transition_sigma(noise, dt, horizon) ** 2
        assert drift.var() == pytest.approx(expected, rel=4 * math.sqrt(2 / B))

    def test_no_bias_is_the_walk(self):
        noise = OdometryNoise(gyro_bias_sigma=0.0)
        assert yaw_transition_sigma(noise, 2.0) == pytest.approx(noise.yaw_walk_sigma)


class TestPositionTransitionCovariance:
    @pytest.mark.parametrize("batch", [1, 3])
    def test_along_and_across_track(self, batch):
        noise = OdometryNoise()
        d = t(np.random.default_rng(batch).normal(0, 20, (batch, 2)))
        cov = position_transition_covariance(d, noise, horizon=4.0).numpy()
        unit = d.numpy() / np.linalg.norm(d.numpy(), axis=-1, keepdims=True)
        across = np.stack([-unit[:, 1], unit[:, 0]], -1)
        along_var = np.einsum("bi,bij,bj->b", unit, cov, unit)
        across_var = np.einsum("bi,bij,bj->b", across, cov, across)
        step = noise.position_step_sigma**2
        length = np.linalg.norm(d.numpy(), axis=-1)
        np.testing.assert_allclose(along_var, step + 4.0 * (noise.scale_sigma * length) ** 2)
        np.testing.assert_allclose(across_var, step)


class TestFilterAndSmooth:
    """One forward pass for both estimates: bit-identical to the two separate calls."""

    def test_yaw(self):
        _, _, flights = synthetic_yaw_flights(5, B=3, K=12)
        f, s = filter_and_smooth_yaw(flights, YAW)
        for both, alone in ((f, filter_yaw(flights, YAW)), (s, smooth_yaw(flights, YAW))):
            for name in ("log_density", "map", "mean", "resultant"):
                assert torch.equal(getattr(both, name), getattr(alone, name))

    def test_position(self):
        grid, _, _, flights = synthetic_position_flights(6, B=2, K=8)
        f, s = filter_and_smooth_position(flights, grid)
        pairs = ((f, filter_position(flights, grid)), (s, smooth_position(flights, grid)))
        for both, alone in pairs:
            for name in ("log_density", "map", "mean", "escaped"):
                assert torch.equal(getattr(both, name), getattr(alone, name))

    def test_position_without_the_mean(self):
        grid, _, _, flights = synthetic_position_flights(6, B=2, K=8)
        full = filter_and_smooth_position(flights, grid)
        bare = filter_and_smooth_position(flights, grid, mean=False)
        for a, b in zip(full, bare, strict=True):
            assert b.mean is None
            for name in ("log_density", "map", "escaped"):
                assert torch.equal(getattr(a, name), getattr(b, name))
