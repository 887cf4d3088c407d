"""Heading and position fused jointly (benchmark.evaluation.fusion_joint): against the geometry of
a flight, the marginal filters it must agree with where the heading is known, and the pose
volume's own marginals."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from benchmark.evaluation.fusion import (
    CircularGrid,
    OdometryNoise,
    PlanarGrid,
    PositionFlights,
    YawFlights,
    filter_position,
    filter_yaw,
    position_transition_covariance,
)
from benchmark.evaluation.fusion_joint import (
    JointFlight,
    JointGrid,
    filter_and_smooth_joint,
    heading_kernel,
    volume_joint_belief,
)
from benchmark.evaluation.sequence import FusionSettings, fuse_split, fuse_split_joint
from benchmark.evaluation.volume_beliefs import (
    VolumeMarginals,
    volume_position_beliefs,
    volume_yaw_beliefs,
)
from tests.evaluation.test_sequence import synthetic_split

NOISE = OdometryNoise()
STEP = 15.0  # m per sample, straight ahead


def _wrap(a: torch.Tensor) -> torch.Tensor:
    return torch.atan2(torch.sin(a), torch.cos(a))


def straight_flight(K: int = 10, yaw0: float = 1.0, turn: float = 0.05):
    """A flight turning ``turn`` rad per sample, ``STEP`` m forward per sample: true ``yaw (K,)``,
    ``position (K, 2)`` (E, N) and its exact levelled steps ``(K-1, 2)``."""
    yaw = yaw0 + turn * torch.arange(K, dtype=torch.float64)
    pos = torch.zeros(K, 2, dtype=torch.float64)
    for k in range(1, K):  # body +y forward; Rz(yaw) [0, STEP] = STEP (-sin, cos)
        pos[k] = pos[k - 1] + STEP * torch.stack([-torch.sin(yaw[k - 1]), torch.cos(yaw[k - 1])])
    steps = torch.zeros(K - 1, 2, dtype=torch.float64)
    steps[:, 1] = STEP
    return yaw, pos, steps


def blob(plane: PlanarGrid, centre: torch.Tensor, sigma: float) -> torch.Tensor:
    east, north = plane.centres()
    return -0.5 * ((east[:, None] - centre[0]) ** 2 + (north[None, :] - centre[1]) ** 2) / sigma**2


class TestHeadingKernel:
    @pytest.mark.parametrize("s", [0.0, 0.1, 0.5, 1.0])
    def test_narrow_kernel_has_exactly_the_variance(self, s):
        k = heading_kernel(s * 0.05, 0.05)
        x = torch.arange(-1, 2, dtype=torch.float64)
        assert float(k.sum()) == pytest.approx(1.0, abs=1e-15)
        assert bool((k >= 0).all())
        assert float((k * x**2).sum()) == pytest.approx(s * s, rel=1e-12, abs=1e-15)

    @pytest.mark.parametrize("s", [1.01, 1.5, 2.5])
    def test_wide_kernel_is_the_sampled_gaussian(self, s):
        k = heading_kernel(s * 0.05, 0.05)
        r = (len(k) - 1) // 2
        x = torch.arange(-r, r + 1, dtype=torch.float64)
        assert float(k.sum()) == pytest.approx(1.0, abs=1e-14)
        assert float((k * x**2).sum()) == pytest.approx(s * s, rel=1e-3)  # 4 sigma tails
        assert torch.equal(k, k.flip(0))

    def test_rejects_negative_sigma(self):
        with pytest.raises(ValueError, match="sigma >= 0"):
            heading_kernel(-0.1, 0.05)


class TestHeadingBlur:
    """The heading axis's circular blur against a dense circulant matrix (scipy), in linear
    space, for kernels narrower and wider than the grid's wrap."""

    @pytest.mark.parametrize("s", [0.5, 1.5, 4.0])
    def test_against_scipy_circulant(self, s):
        from scipy.linalg import circulant

        from benchmark.evaluation.fusion_joint import _heading_blur

        n = 12
        kernel = heading_kernel(s * 0.05, 0.05)
        r = (len(kernel) - 1) // 2
        column = np.zeros(n)
        for offset in range(-r, r + 1):  # the kernel wrapped onto the n headings
            column[offset % n] += float(kernel[offset + r])
        g = torch.Generator().manual_seed(int(10 * s))
        log_f = 3.0 * torch.randn(n, 4, 5, dtype=torch.float64, generator=g)
        ours = _heading_blur(log_f, kernel).exp().numpy()
        expected = np.einsum("ij,jen->ien", circulant(column), log_f.exp().numpy())
        np.testing.assert_allclose(ours, expected, rtol=1e-12)


class TestFilterAndSmoothJoint:
    def test_position_evidence_resolves_a_heading_ambiguity(self):
        """Every frame sees the right place but cannot tell its heading from the opposite one.
        The heading marginals alone stay split 50/50; the odometry steps, turned by each heading,
        carry the position forward along the flight only for the true heading."""
        K = 10
        yaw, pos, steps = straight_flight(K)
        plane = PlanarGrid.around(pos, 10.0, 200.0)
        grid = JointGrid(CircularGrid(180), plane)

        def belief(k: int, psi: torch.Tensor) -> torch.Tensor:
            heading = torch.logaddexp(50 * (torch.cos(psi - yaw[k]) - 1),
                                      50 * (torch.cos(psi - yaw[k] - math.pi) - 1))  # fmt: skip
            return heading[:, None, None] + blob(plane, pos[k], 10.0)[None]

        flight = JointFlight(belief, torch.diff(yaw), steps, torch.full((K - 1,), 0.005))
        filtered, smoothed = filter_and_smooth_joint(flight, grid, NOISE)
        err_f = _wrap(filtered.heading.map - yaw).abs()
        err_s = _wrap(smoothed.heading.map - yaw).abs()
        assert float(err_f[2:].max()) < math.radians(1.0)  # two samples decide it
        assert float(err_s.max()) < math.radians(1.0)  # and the smoother tells sample 0
        # the marginal heading filter cannot: both modes keep half the mass
        ygrid = CircularGrid(720)
        psi = ygrid.centres()
        heading = torch.stack([belief(k, psi).logsumexp((1, 2)) for k in range(K)])[None]
        marginal = filter_yaw(YawFlights(heading, torch.diff(yaw)[None], 0.005), ygrid)
        p = torch.exp(marginal.log_density[0, -1]) * ygrid.cell
        near_wrong = _wrap(psi - yaw[-1] - math.pi).abs() < math.radians(10)
        assert float(p[near_wrong].sum()) == pytest.approx(0.5, abs=0.05)

    def test_known_heading_gives_the_marginal_position_filter(self):
        """A heading belief far sharper than a bin at the truth: the joint filter's position is
        the position filter's with the true heading's steps (same noise, same grid)."""
        K = 8
        yaw, pos, steps = straight_flight(K)
        rng = np.random.default_rng(3)
        seen = pos + torch.as_tensor(rng.normal(0, 20.0, (K, 2)))
        plane = PlanarGrid.around(pos, 10.0, 150.0)
        grid = JointGrid(CircularGrid(360), plane)

        def belief(k: int, psi: torch.Tensor) -> torch.Tensor:
            return (4e4 * (torch.cos(psi - yaw[k]) - 1))[:, None, None] + blob(
                plane, seen[k], 25.0
            )[None]

        flight = JointFlight(belief, torch.diff(yaw), steps, torch.zeros(K - 1))
        filtered, _ = filter_and_smooth_joint(flight, grid, NOISE, outlier_weight=0.0)
        d = pos[1:] - pos[:-1]
        cov = position_transition_covariance(d, NOISE)
        beliefs = torch.stack([blob(plane, seen[k], 25.0) for k in range(K)])[None]
        reference = filter_position(PositionFlights(beliefs, d[None], cov[None]), plane, 0.0)
        gap = torch.linalg.vector_norm(filtered.position.map - reference.map[0], dim=-1)
        assert float(gap.max()) < 0.5  # m, on 10 m cells

    def test_filter_never_reads_a_later_sample(self):
        K = 8
        yaw, pos, steps = straight_flight(K)
        plane = PlanarGrid.around(pos, 20.0, 150.0)
        grid = JointGrid(CircularGrid(60), plane)

        def make(late: float):
            def belief(k: int, psi: torch.Tensor) -> torch.Tensor:
                target = yaw[k] + (late if k >= 5 else 0.0)
                return (8 * (torch.cos(psi - target) - 1))[:, None, None] + blob(
                    plane, pos[k], 30.0
                )[None]

            dyaw = torch.diff(yaw).clone()
            dyaw[5:] += late
            return JointFlight(belief, dyaw, steps, torch.full((K - 1,), 0.01))

        a, _ = filter_and_smooth_joint(make(0.0), grid, NOISE)
        b, _ = filter_and_smooth_joint(make(2.0), grid, NOISE)
        assert torch.equal(a.heading.map[:5], b.heading.map[:5])
        assert torch.equal(a.position.map[:5], b.position.map[:5])
        assert not torch.equal(a.heading.map[5:], b.heading.map[5:])

    def test_filter_only_is_the_filter_of_the_full_run(self):
        K = 6
        yaw, pos, steps = straight_flight(K)
        plane = PlanarGrid.around(pos, 20.0, 150.0)
        grid = JointGrid(CircularGrid(60), plane)

        def belief(k: int, psi: torch.Tensor) -> torch.Tensor:
            return (8 * (torch.cos(psi - yaw[k]) - 1))[:, None, None] + blob(plane, pos[k], 30.0)[
                None
            ]

        flight = JointFlight(belief, torch.diff(yaw), steps, torch.full((K - 1,), 0.01))
        full, smoothed = filter_and_smooth_joint(flight, grid, NOISE)
        alone, none = filter_and_smooth_joint(flight, grid, NOISE, smooth=False)
        assert none is None and smoothed is not None
        assert torch.equal(full.heading.map, alone.heading.map)
        assert torch.equal(full.position.map, alone.position.map)

    def test_belief_of_the_wrong_shape_is_named(self):
        yaw, _, steps = straight_flight(3)
        grid = JointGrid(CircularGrid(12), PlanarGrid(0.0, 0.0, 10.0, 5, 4))
        flight = JointFlight(lambda k, psi: torch.zeros(12, 4, 5), torch.diff(yaw), steps,
                             torch.zeros(2))  # fmt: skip
        with pytest.raises(ValueError, match=r"belief\(0\) returned \(12, 4, 5\)"):
            filter_and_smooth_joint(flight, grid, NOISE)

    def test_odometry_shapes_are_checked(self):
        with pytest.raises(ValueError, match="dyaw"):
            JointFlight(lambda k, psi: psi, torch.zeros(3), torch.zeros(2, 2), torch.zeros(3))


class TestVolumeJointBelief:
    def test_marginals_are_the_volume_marginals(self):
        """On a heading grid aligned with the volume's bins (a multiple of them), the joint
        belief summed over headings is the position marginal of ``volume_position_beliefs`` and
        summed over the plane (inside the searched square) the yaw marginal of
        ``volume_yaw_beliefs``: the same interpolation, done jointly."""
        g = torch.Generator().manual_seed(0)
        n_yaw, P, Q, cell = 12, 7, 9, 20.0
        log_volume = torch.randn(1, n_yaw, P, Q, generator=g, dtype=torch.float64)
        # float32 values, as the pipeline stores the volume (the marginals are float64 of them)
        log_volume = (log_volume - log_volume.logsumexp((1, 2, 3), keepdim=True)).float().double()
        yaw = -math.pi + 2 * math.pi * torch.arange(n_yaw, dtype=torch.float64) / n_yaw
        north = cell * (torch.arange(P, dtype=torch.float64) - 3).flip(0)  # descending rows
        east = cell * (torch.arange(Q, dtype=torch.float64) - 4)
        marginals = VolumeMarginals(
            torch.zeros(1, dtype=torch.long), log_volume.logsumexp((2, 3)),
            log_volume.logsumexp(1), yaw, north, east, cell,
        )  # fmt: skip
        # covers the square and beyond; its cells tile the volume's cells (edges at +-90 m E,
        # +-70 m N), so the midpoint sum of the bilinear interpolant is its integral, exactly
        plane = PlanarGrid(-127.5, -107.5, 5.0, 52, 44)
        heading = CircularGrid(4 * n_yaw)
        psi = heading.centres()
        joint = volume_joint_belief(log_volume, yaw, north, east, cell, plane)
        b = joint(0, psi).exp()  # (n_heading, n_east, n_north) per rad m^2
        position = volume_position_beliefs(marginals, torch.zeros(1, dtype=torch.long), plane)
        inside = position[0] > -700  # beyond the square both are "log tiny"
        torch.testing.assert_close(
            (b.sum(0) * heading.cell)[inside], position[0].exp()[inside], rtol=1e-9, atol=0
        )
        assert 0 < int(inside.sum()) < inside.numel()
        yaw_density = volume_yaw_beliefs(marginals, heading)[0].exp()  # per rad
        # the plane integral of the bilinear interpolant is the mass inside the square
        torch.testing.assert_close(b.sum((1, 2)) * plane.cell, yaw_density, rtol=1e-9, atol=0)


class TestFuseSplitJoint:
    def test_recovers_the_heading_through_wrong_matches(self):
        """Synthetic flights (30 % wrong frames, odometry with the stated noise): the joint
        fusion of the product of each frame's heading and position beliefs finds the heading;
        its table has fuse_split's columns and frame rows."""
        frames = synthetic_split(n_flights=3, samples=24)
        settings = FusionSettings(joint_heading_bins=90, joint_spacing_m=25.0)
        heading_hat = torch.as_tensor(frames.yaw_hat)
        pos_hat = torch.as_tensor(frames.position_hat)

        def joint_belief(rows: np.ndarray, plane: PlanarGrid):
            def belief(k: int, psi: torch.Tensor) -> torch.Tensor:
                r = int(rows[k])
                heading = 60 * (torch.cos(psi - heading_hat[r]) - 1)
                return heading[:, None, None] + blob(plane, pos_hat[r], 20.0)[None]

            return belief

        table = fuse_split_joint(frames, joint_belief, NOISE, settings)
        marginal = fuse_split(frames, NOISE, settings)
        assert list(table.columns) == list(marginal.columns)
        by = {m: part for m, part in table.groupby("mode")}
        ref = {m: part for m, part in marginal.groupby("mode")}
        np.testing.assert_array_equal(by["frame"]["dpsi_deg"], ref["frame"]["dpsi_deg"])
        assert by["smooth"]["dpsi_deg"].median() < 3.0
        assert by["filter"]["dpsi_deg"].mean() < by["frame"]["dpsi_deg"].mean() / 2
        assert by["smooth"]["horizontal_m"].median() < 15.0
        # the filter alone: the same filtered rows, no smoothed ones
        alone = fuse_split_joint(frames, joint_belief, NOISE, settings, smooth=False)
        assert set(alone["mode"]) == {"frame", "filter"}
        np.testing.assert_array_equal(
            alone[alone["mode"] == "filter"]["yaw_hat_deg"], by["filter"]["yaw_hat_deg"]
        )
