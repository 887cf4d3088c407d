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
    fit_volume_temperature,
    temper_log_volume,
    true_cells,
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


def _small_axes() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """A small volume's axes: 8 yaw bins, 5 x 5 cells of 10 m, north descending."""
    yaw = torch.arange(8, dtype=F64) * (2 * math.pi / 8)
    off = torch.arange(-2, 3, dtype=F64) * 10.0
    return yaw, off.flip(0), off


class TestTemperLogVolume:
    def test_against_scipy_log_softmax(self):
        from scipy.special import log_softmax

        lv = torch.log_softmax(torch.randn(3, 8, 5, 5, dtype=F64).flatten(1), 1).view(3, 8, 5, 5)
        for tau in (0.5, 1.7, 6.0):
            ref = log_softmax(lv.flatten(1).numpy() / tau, axis=1).reshape(3, 8, 5, 5)
            np.testing.assert_allclose(temper_log_volume(lv, tau).numpy(), ref, atol=1e-12)

    def test_one_is_the_volume_itself(self):
        lv = torch.randn(2, 8, 5, 5, dtype=F64)
        assert temper_log_volume(lv, 1.0) is lv

    def test_empty_cells_stay_empty_at_any_temperature(self):
        lv = torch.zeros(1, 8, 5, 5, dtype=F64)
        lv[0, 1:] = -1.0e4  # the encoder's excluded cells: mass exp(-1e4) = 0
        lv = lv - torch.logsumexp(lv.flatten(1), 1).view(1, 1, 1, 1)
        out = temper_log_volume(lv, 16.0)
        assert float(out[0, 1:].exp().sum()) == 0.0
        np.testing.assert_allclose(float(out.exp().sum()), 1.0, rtol=1e-12)
        # the first bin's 25 cells were equal and stay so: 1/25 each
        np.testing.assert_allclose(out[0, 0].exp().numpy(), 1 / 25, rtol=1e-12)

    def test_order_of_cells_kept(self):
        lv = torch.randn(2, 8, 5, 5, dtype=F64)
        for tau in (0.3, 4.0):
            out = temper_log_volume(lv, tau)
            assert torch.equal(lv.flatten(1).argsort(1), out.flatten(1).argsort(1))


class TestTrueCells:
    def test_against_a_brute_force_search(self):
        axes = _small_axes()
        g = torch.Generator().manual_seed(4)
        n = 200
        yaw = (torch.rand(n, generator=g, dtype=F64) * 4 - 2) * math.pi  # beyond one turn
        east = (torch.rand(n, generator=g, dtype=F64) - 0.5) * 60
        north = (torch.rand(n, generator=g, dtype=F64) - 0.5) * 60
        cells, inside = true_cells(axes, yaw, east, north, 10.0)
        for i in range(n):
            gaps = [abs(math.remainder(float(yaw[i]) - float(a), 2 * math.pi)) for a in axes[0]]
            k = int(np.argmin(gaps))
            p = int(np.argmin([abs(float(north[i]) - float(a)) for a in axes[1]]))
            q = int(np.argmin([abs(float(east[i]) - float(a)) for a in axes[2]]))
            assert int(cells[i]) == (k * 5 + p) * 5 + q
            assert bool(inside[i]) == (abs(float(east[i])) <= 25 and abs(float(north[i])) <= 25)

    def test_yaw_near_a_full_turn_is_bin_zero(self):
        axes = _small_axes()
        zero = torch.zeros(1, dtype=F64)
        cells, inside = true_cells(axes, torch.tensor([2 * math.pi - 0.01]), zero, zero, 10.0)
        assert int(cells[0]) == 12 and bool(inside[0])  # bin 0, row 2, column 2


def assert_is_the_scans_minimum(fitted, nll) -> None:
    """``fitted`` (a VolumeCalibration) is the minimum of ``nll(tau)`` over 2001 log-spaced
    temperatures in the fit's bounds, and its ``nll_raw`` is ``nll(1)``."""
    taus = np.exp(np.linspace(np.log(0.25), np.log(16), 2001))
    scan = np.array([nll(t) for t in taus])
    assert fitted.nll <= scan.min() + 1e-7
    assert fitted.temperature == pytest.approx(taus[scan.argmin()], rel=0.01)
    assert fitted.nll_raw == pytest.approx(nll(1.0), rel=1e-12)


class TestFitVolumeTemperature:
    @staticmethod
    def overconfident(n: int, tau: float, seed: int) -> tuple[torch.Tensor, ...]:
        """``n`` frames whose true cells are drawn from ``softmax(s)`` while the volume says
        ``log_softmax(s / tau)``: a volume overconfident by ``tau`` (its best temperature)."""
        axes = _small_axes()
        g = torch.Generator().manual_seed(seed)
        s = 2.0 * torch.randn(n, 200, generator=g, dtype=F64)
        draw = torch.multinomial(torch.softmax(s, 1), 1, generator=g).flatten()
        k, p, q = draw // 25, (draw // 5) % 5, draw % 5
        lv = torch.log_softmax(s / tau, 1).view(n, 8, 5, 5)
        return lv, axes, axes[0][k], axes[2][q], axes[1][p]

    def test_recovers_a_known_overconfidence(self):
        lv, axes, yaw, east, north = self.overconfident(3000, 0.5, seed=1)
        fitted = fit_volume_temperature(lv, axes, 10.0, yaw, east, north)
        assert fitted.temperature == pytest.approx(2.0, rel=0.06)  # log_softmax(s / 0.5) * 0.5
        assert fitted.n_frames == fitted.n_total == 3000
        assert fitted.nll < fitted.nll_raw and fitted.nll_uniform == pytest.approx(math.log(200))
        assert fitted.yaw_nll_uniform == pytest.approx(math.log(8))
        assert fitted.position_nll_uniform == pytest.approx(math.log(25))

    def test_a_calibrated_volume_keeps_temperature_one(self):
        lv, axes, yaw, east, north = self.overconfident(3000, 1.0, seed=2)
        fitted = fit_volume_temperature(lv, axes, 10.0, yaw, east, north)
        assert fitted.temperature == pytest.approx(1.0, rel=0.06)

    def test_the_minimum_of_a_brute_force_scan(self):
        from scipy.special import log_softmax

        lv, axes, yaw, east, north = self.overconfident(300, 0.7, seed=3)
        fitted = fit_volume_temperature(lv, axes, 10.0, yaw, east, north)
        cells, _ = true_cells(axes, yaw, east, north, 10.0)
        flat, idx = lv.flatten(1).numpy(), cells.numpy()

        def nll(tau: float) -> float:
            return float(-log_softmax(flat / tau, axis=1)[np.arange(len(idx)), idx].mean())

        assert_is_the_scans_minimum(fitted, nll)

    def test_each_marginal_gets_its_own_temperature(self):
        # a volume whose yaw and position are independent: p(k, cell) = p_yaw(k) p_pos(cell).
        # The truth is drawn from (yaw logits a, position logits b); the volume says (2 a, b / 2):
        # its yaw marginal is overconfident by 2, its position marginal underconfident by 2.
        # Tempering the whole volume cannot fix both; each marginal's own temperature does.
        axes = _small_axes()
        g = torch.Generator().manual_seed(6)
        n = 4000
        a = 1.5 * torch.randn(n, 8, generator=g, dtype=F64)
        b = 1.5 * torch.randn(n, 25, generator=g, dtype=F64)
        k = torch.multinomial(torch.softmax(a, 1), 1, generator=g).flatten()
        c = torch.multinomial(torch.softmax(b, 1), 1, generator=g).flatten()
        lv = torch.log_softmax(2 * a, 1)[:, :, None] + torch.log_softmax(b / 2, 1)[:, None, :]
        fitted = fit_volume_temperature(
            lv.view(n, 8, 5, 5), axes, 10.0, axes[0][k], axes[2][c % 5], axes[1][c // 5]
        )
        assert fitted.yaw_temperature == pytest.approx(2.0, rel=0.08)
        assert fitted.position_temperature == pytest.approx(0.5, rel=0.08)
        assert fitted.yaw_nll < fitted.yaw_nll_raw and fitted.position_nll < fitted.position_nll_raw

    def test_marginal_nlls_against_scipy(self):
        from scipy.special import log_softmax, logsumexp

        lv, axes, yaw, east, north = self.overconfident(300, 0.7, seed=9)
        fitted = fit_volume_temperature(lv, axes, 10.0, yaw, east, north)
        cells, _ = true_cells(axes, yaw, east, north, 10.0)
        flat = lv.numpy().reshape(300, 8, 25)
        idx = np.arange(300)
        yaw_p = logsumexp(flat, axis=2)
        pos_p = logsumexp(flat, axis=1)
        k, c = cells.numpy() // 25, cells.numpy() % 25
        assert fitted.yaw_nll_raw == pytest.approx(-yaw_p[idx, k].mean(), rel=1e-12)
        assert fitted.position_nll_raw == pytest.approx(-pos_p[idx, c].mean(), rel=1e-12)
        tau = fitted.yaw_temperature
        expected = -log_softmax(yaw_p / tau, axis=1)[idx, k].mean()
        assert fitted.yaw_nll == pytest.approx(expected, rel=1e-10)

    @staticmethod
    def with_gross_errors(n: int, tau: float, share: float, seed: int) -> tuple[torch.Tensor, ...]:
        """As :meth:`overconfident`, but a ``share`` of the frames' true cells drawn uniformly
        (wrong matches): the truth follows ``(1 - share) softmax(s) + share / M``, the fusion's
        robust likelihood with outlier weight ``share`` around a volume overconfident by ``tau``."""
        axes = _small_axes()
        g = torch.Generator().manual_seed(seed)
        s = 2.0 * torch.randn(n, 200, generator=g, dtype=F64)
        draw = torch.multinomial(torch.softmax(s, 1), 1, generator=g).flatten()
        wrong = torch.rand(n, generator=g, dtype=F64) < share
        draw = torch.where(wrong, torch.randint(0, 200, (n,), generator=g), draw)
        k, p, q = draw // 25, (draw // 5) % 5, draw % 5
        lv = torch.log_softmax(s / tau, 1).view(n, 8, 5, 5)
        return lv, axes, axes[0][k], axes[2][q], axes[1][p]

    def test_the_outlier_share_keeps_wrong_matches_from_softening_the_volume(self):
        lv, axes, yaw, east, north = self.with_gross_errors(4000, 0.5, 0.3, seed=11)
        robust = fit_volume_temperature(lv, axes, 10.0, yaw, east, north, outlier_weight=0.3)
        plain = fit_volume_temperature(lv, axes, 10.0, yaw, east, north)
        assert robust.temperature == pytest.approx(2.0, rel=0.08)
        assert plain.temperature > 1.2 * robust.temperature  # the wrong matches pull it up
        assert robust.outlier_weight == 0.3 and plain.outlier_weight == 0.0

    def test_the_mixture_fit_is_the_minimum_of_a_brute_force_scan(self):
        from scipy.special import log_softmax, logsumexp

        lv, axes, yaw, east, north = self.with_gross_errors(300, 0.7, 0.4, seed=12)
        w = 0.4
        fitted = fit_volume_temperature(lv, axes, 10.0, yaw, east, north, outlier_weight=w)
        cells, _ = true_cells(axes, yaw, east, north, 10.0)
        flat, idx = lv.flatten(1).numpy(), cells.numpy()

        def nll(tau: float) -> float:
            at = log_softmax(flat / tau, axis=1)[np.arange(len(idx)), idx]
            both = np.stack([np.log1p(-w) + at, np.full_like(at, np.log(w / 200))])
            return float(-logsumexp(both, axis=0).mean())

        assert_is_the_scans_minimum(fitted, nll)

    def test_a_bad_outlier_weight_is_refused(self):
        lv, axes, yaw, east, north = self.overconfident(5, 0.5, seed=5)
        for w in (-0.1, 1.0, 1.5):
            with pytest.raises(ValueError, match="outlier_weight"):
                fit_volume_temperature(lv, axes, 10.0, yaw, east, north, outlier_weight=w)

    def test_frames_outside_the_square_are_left_out(self):
        lv, axes, yaw, east, north = self.overconfident(50, 0.5, seed=4)
        far = east.clone()
        far[:10] = 500.0  # beyond the +-25 m square
        fitted = fit_volume_temperature(lv, axes, 10.0, yaw, far, north)
        alone = fit_volume_temperature(lv[10:], axes, 10.0, yaw[10:], east[10:], north[10:])
        assert (fitted.n_frames, fitted.n_total) == (40, 50)
        assert fitted.temperature == pytest.approx(alone.temperature, rel=1e-9)
        assert fitted.yaw_temperature == pytest.approx(alone.yaw_temperature, rel=1e-9)

    def test_bad_input_is_named(self):
        lv, axes, yaw, east, north = self.overconfident(5, 0.5, seed=5)
        with pytest.raises(ValueError, match="N = len"):
            fit_volume_temperature(lv[:4], axes, 10.0, yaw, east, north)
        with pytest.raises(ValueError, match="no frame"):
            fit_volume_temperature(lv, axes, 10.0, yaw, east + 1000.0, north)


class TestVolumeEstimatesOfACalibratedVolume:
    def test_the_estimates_are_the_untempered_marginals_maxima(self):
        import dataclasses

        raw, grid = marginals(3, seed=7), CircularGrid(720)
        flat = marginals(3, seed=8)  # other marginals, standing for the tempered ones
        both = dataclasses.replace(
            flat, raw_yaw_log_p=raw.yaw_log_p, raw_position_log_p=raw.position_log_p
        )
        yaw, en = volume_estimates(both, grid)
        yaw_raw, en_raw = volume_estimates(raw, grid)
        assert torch.equal(yaw, yaw_raw) and torch.equal(en, en_raw)

    def test_raw_marginals_of_another_shape_are_refused(self):
        import dataclasses

        m = marginals(3)
        with pytest.raises(ValueError, match="raw_yaw_log_p must be"):
            dataclasses.replace(m, raw_yaw_log_p=m.yaw_log_p[:2])


class TestVolumeMarginalsTemperatures:
    """volume_marginals tempers the whole volume and each marginal by its own temperature."""

    def test_refuses_a_bad_temperature(self):
        from benchmark.evaluation.volume_beliefs import volume_marginals

        with pytest.raises(ValueError, match="yaw_temperature must be"):
            volume_marginals(torch.nn.Identity(), [], yaw_temperature=0.0)
