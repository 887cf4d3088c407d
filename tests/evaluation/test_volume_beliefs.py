"""A pose volume's marginals as fusion beliefs (benchmark.evaluation.volume_beliefs), against
closed forms and scipy's interpolator, float64."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.interpolate import RegularGridInterpolator

from benchmark.evaluation.fusion_grid import CircularGrid, PlanarGrid
from benchmark.evaluation.volume_beliefs import (
    VolumeMarginals,
    volume_estimates,
    volume_position_beliefs,
    volume_yaw_beliefs,
)

F64 = torch.float64
K, CELL, SEARCH = 36, 20.8, 19
YAWS = torch.arange(K, dtype=F64) * (2 * math.pi / K)
OFFSETS = torch.arange(-SEARCH, SEARCH + 1, dtype=F64) * CELL


def marginals(n: int = 4, seed: int = 0) -> VolumeMarginals:
    """Random volumes' marginals on the matching encoder's axes (rows north descending)."""
    g = torch.Generator().manual_seed(seed)
    yaw = torch.log_softmax(3 * torch.randn(n, K, generator=g, dtype=F64), -1)
    pos = torch.randn(n, len(OFFSETS), len(OFFSETS), generator=g, dtype=F64)
    pos = torch.log_softmax(2 * pos.flatten(1), -1).view_as(pos)
    return VolumeMarginals(torch.arange(n) + 10, yaw, pos, YAWS, OFFSETS.flip(0), OFFSETS, CELL)


class TestVolumeYawBeliefs:
    def test_integrates_to_one_and_interpolates_the_bin_densities(self):
        m, grid = marginals(), CircularGrid(720)
        belief = volume_yaw_beliefs(m, grid)
        assert belief.shape == (4, 720) and belief.dtype == F64
        # periodic piecewise linear: the grid sum is the trapezoid rule, exact here
        np.testing.assert_allclose((belief.exp() * grid.cell).sum(-1).numpy(), 1.0, rtol=1e-12)
        # at a bin centre: that bin's mass over its width (0.5 deg grid: every 20th centre)
        psi = grid.centres()
        at = torch.isclose(torch.remainder(psi, 2 * math.pi / K), torch.zeros((), dtype=F64),
                           atol=1e-9)  # fmt: skip
        bins = torch.round(torch.remainder(psi[at], 2 * math.pi) / (2 * math.pi / K)).long() % K
        expected = m.yaw_log_p[:, bins] - math.log(2 * math.pi / K)
        torch.testing.assert_close(belief[:, at], expected, rtol=0, atol=1e-9)

    def test_against_numpy_interp(self):
        m, grid = marginals(2, seed=3), CircularGrid(360)
        psi = grid.centres().numpy()
        density = m.yaw_log_p.exp().numpy() / (2 * math.pi / K)
        xs = np.concatenate([YAWS.numpy(), [2 * math.pi]])
        for b in range(2):
            ref = np.interp(np.mod(psi, 2 * math.pi), xs, np.append(density[b], density[b, 0]))
            np.testing.assert_allclose(volume_yaw_beliefs(m, grid)[b].exp().numpy(), ref,
                                       rtol=1e-9)  # fmt: skip


class TestVolumePositionBeliefs:
    def test_against_scipy_bilinear(self):
        m = marginals(3, seed=1)
        grid = PlanarGrid(-1000.0, -500.0, 10.0, 201, 101)
        rows = torch.tensor([2, 0, -1])  # -1: a flight's padding, frame 0's belief
        ours = volume_position_beliefs(m, rows, grid).exp()
        east, north = grid.centres()
        points = np.stack(np.meshgrid(north.numpy(), east.numpy(), indexing="xy"), -1)
        half = SEARCH * CELL + CELL / 2  # the outer cells reach half a cell beyond their centres
        for out, row in zip(ours, (2, 0, 0), strict=True):
            density = m.position_log_p[row].exp().numpy() / CELL**2  # (north desc, east)
            interp = RegularGridInterpolator(
                (OFFSETS.numpy(), OFFSETS.numpy()), density[::-1], bounds_error=False,
                fill_value=None,
            )  # fmt: skip
            flat = points.reshape(-1, 2)
            clamped = np.clip(flat, OFFSETS[0].item(), OFFSETS[-1].item())  # constant edge strip
            inside = (np.abs(flat) <= half).all(-1)
            ref = np.where(inside, interp(clamped), 0.0).reshape(len(east), len(north))
            np.testing.assert_allclose(out.numpy(), ref, rtol=1e-9, atol=1e-300)

    def test_mass_is_kept_when_the_grid_covers_the_square(self):
        m = marginals(2, seed=2)
        # quarter cells whose edges fall on the volume's cell centres and on its square's edge
        # (+-405.6 m): the interpolant is bilinear in each, where the midpoint rule is exact
        grid = PlanarGrid(-408.2, -408.2, CELL / 4, 158, 158)
        dens = volume_position_beliefs(m, torch.tensor([0, 1]), grid).exp()
        assert (dens.sum((-2, -1)) * grid.cell).numpy() == pytest.approx([1.0, 1.0], rel=1e-9)


class TestVolumeEstimates:
    def test_the_maxima(self):
        m = marginals(5, seed=4)
        grid = CircularGrid(720)
        yaw, en = volume_estimates(m, grid)
        k = m.yaw_log_p.argmax(-1)
        wrapped = torch.where(YAWS[k] >= math.pi, YAWS[k] - 2 * math.pi, YAWS[k])
        torch.testing.assert_close(yaw, wrapped, atol=1e-12, rtol=0)
        flat = m.position_log_p.flatten(1).argmax(-1)
        q = len(OFFSETS)
        torch.testing.assert_close(en[:, 0], OFFSETS[flat % q])
        torch.testing.assert_close(en[:, 1], OFFSETS.flip(0)[flat // q])


class TestVolumeMarginals:
    def test_shapes_are_checked(self):
        m = marginals(2)
        with pytest.raises(ValueError, match=r"position_log_p must be \(N, P, Q\)"):
            VolumeMarginals(m.index, m.yaw_log_p, m.position_log_p[:, :-1], YAWS, m.north,
                            m.east, CELL)  # fmt: skip
