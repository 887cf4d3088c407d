"""The Laplace translation head (``baselines/translation_laplace.py``): its NLL against scipy's
Laplace density, the median property of its loss (closed form), decoding, float64 gradcheck and
the scale clamp."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy import stats

from baselines.translation_laplace import KINK_EPS, LOG_SCALE_LIMIT, TranslationLaplace
from benchmark.models import create_head


def _head(mean=(10.0, -20.0, -900.0), std=(150.0, 110.0, 10.0)) -> TranslationLaplace:
    head = create_head("laplace", kind="translation", in_features=4).double()
    head.set_statistics(torch.tensor(mean), torch.tensor(std))
    return head


class TestNll:
    def test_is_scipys_laplace_nll_plus_the_kink_smoothing(self):
        head = _head()
        rng = np.random.default_rng(0)
        loc = torch.from_numpy(rng.normal(0, 1, (6, 3)))
        log_scale = torch.from_numpy(rng.uniform(-2, 1, (6, 3)))
        T = torch.from_numpy(rng.normal([10, -20, -900], [150, 110, 10], (6, 3)))
        got = head.nll({"loc": loc, "log_scale": log_scale}, T).numpy()
        z = (T.numpy() - head.mean.numpy()) / head.std.numpy()
        b = np.exp(log_scale.numpy())
        x = z - loc.numpy()
        scipy_nll = -stats.laplace.logpdf(z, loc=loc.numpy(), scale=b)
        smoothing = (np.sqrt(x**2 + KINK_EPS**2) - KINK_EPS - np.abs(x)) / b  # in (-eps/b, 0]
        np.testing.assert_allclose(got, (scipy_nll + smoothing).sum(1), rtol=1e-12, atol=1e-12)

    def test_far_from_the_kink_it_is_the_laplace_nll(self):
        head = _head(mean=(0.0, 0.0, 0.0), std=(1.0, 1.0, 1.0))
        loc = torch.zeros(1, 3, dtype=torch.float64)
        log_scale = torch.zeros(1, 3, dtype=torch.float64)
        T = torch.tensor([[3.0, -5.0, 8.0]], dtype=torch.float64)
        want = -stats.laplace.logpdf([3.0, -5.0, 8.0]).sum()
        got = float(head.nll({"loc": loc, "log_scale": log_scale}, T)[0])
        assert got == pytest.approx(want, abs=3 * KINK_EPS)  # smoothing ~ -eps per axis


class TestPositionLogProb:
    def test_is_scipys_laplace_in_metres_for_east_and_north(self):
        head = _head()
        rng = np.random.default_rng(1)
        loc = torch.from_numpy(rng.normal(0, 1, (3, 3)))
        log_scale = torch.from_numpy(rng.uniform(-2, 1, (3, 3)))
        en = torch.from_numpy(rng.normal([10, -20], [300, 200], (3, 5, 2)))
        got = head.position_log_prob({"loc": loc, "log_scale": log_scale}, en).numpy()
        mu = head.mean.numpy()[:2] + head.std.numpy()[:2] * loc.numpy()[:, :2]
        b = head.std.numpy()[:2] * np.exp(log_scale.numpy()[:, :2])
        ref = stats.laplace.logpdf(en.numpy(), loc=mu[:, None], scale=b[:, None]).sum(-1)
        assert got.shape == (3, 5)
        np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12)

    def test_integrates_to_one_over_the_plane(self):
        head = _head(mean=(0.0, 0.0, 0.0), std=(100.0, 50.0, 10.0))
        raw = {"loc": torch.tensor([[0.3, -0.2, 0.0]], dtype=torch.float64),
               "log_scale": torch.tensor([[-0.5, 0.2, 0.0]], dtype=torch.float64)}  # fmt: skip
        h = 2.0
        axis = torch.arange(-3000, 3000 + h, h, dtype=torch.float64)
        e, n = torch.meshgrid(axis, axis, indexing="ij")
        en = torch.stack([e, n], -1).reshape(1, -1, 2)
        mass = float(head.position_log_prob(raw, en).exp().sum() * h * h)
        assert mass == pytest.approx(1.0, rel=1e-3)


class TestLoss:
    def test_minimiser_is_the_median_not_the_mean(self):
        """For a fixed scale, the location minimising the mean loss over a sample is the sample's
        median: on a bimodal sample (70 % near 0, 30 % at +10 standard units) least squares
        would give the mean, ~3."""
        head = _head(mean=(0.0, 0.0, 0.0), std=(1.0, 1.0, 1.0))
        rng = np.random.default_rng(1)
        values = np.concatenate([rng.normal(0, 0.5, 71), rng.normal(10, 0.5, 30)])
        T = torch.from_numpy(np.repeat(values[:, None], 3, axis=1))
        grid = np.linspace(-2, 5, 1401)
        losses = []
        for mu in grid:
            raw = {
                "loc": torch.full((len(values), 3), mu, dtype=torch.float64),
                "log_scale": torch.zeros(len(values), 3, dtype=torch.float64),
            }
            losses.append(float(head.loss(raw, T)))
        best = grid[int(np.argmin(losses))]
        assert best == pytest.approx(np.median(values), abs=0.02)
        assert abs(best - values.mean()) > 2.5


class TestDecode:
    def test_is_the_location_in_metres(self):
        head = _head()
        loc = torch.tensor([[0.5, -1.0, 2.0]], dtype=torch.float64)
        raw = {"loc": loc, "log_scale": torch.zeros(1, 3, dtype=torch.float64)}
        want = torch.tensor([[10 + 75.0, -20 - 110.0, -900 + 20.0]], dtype=torch.float64)
        torch.testing.assert_close(head.decode(raw), want)

    def test_forward_shapes_at_batch_1_and_8(self):
        head = _head()
        for b in (1, 8):
            raw = head(torch.randn(b, 4, dtype=torch.float64))
            assert raw["loc"].shape == raw["log_scale"].shape == (b, 3)
            assert head.decode(raw).shape == (b, 3)


class TestGradients:
    def test_gradcheck_float64(self):
        head = _head()
        rng = np.random.default_rng(2)
        loc = torch.from_numpy(rng.normal(0, 1, (4, 3))).requires_grad_()
        log_scale = torch.from_numpy(rng.uniform(-1, 1, (4, 3))).requires_grad_()
        T = torch.from_numpy(rng.normal([10, -20, -900], [150, 110, 10], (4, 3)))
        assert torch.autograd.gradcheck(
            lambda m, s: head.nll({"loc": m, "log_scale": s}, T), (loc, log_scale)
        )

    def test_at_the_label_the_gradient_vanishes_smoothly(self):
        head = _head(mean=(0.0, 0.0, 0.0), std=(1.0, 1.0, 1.0))
        T = torch.tensor([[1.0, 2.0, 3.0]], dtype=torch.float64)
        for offset in (0.0, 1e-9):
            loc = (T + offset).clone().requires_grad_()
            raw = {"loc": loc, "log_scale": torch.zeros(1, 3, dtype=torch.float64)}
            head.loss(raw, T).backward()
            assert loc.grad.abs().max() < 1e-6


class TestScaleClamp:
    def test_extreme_log_scales_are_clamped_and_the_location_still_learns(self):
        head = _head()
        with torch.no_grad():
            head.net[2].bias[3:] = torch.tensor([-50.0, 50.0, -50.0], dtype=torch.float64)
        features = torch.randn(5, 4, dtype=torch.float64)
        raw = head(features)
        assert raw["log_scale"].min() == -LOG_SCALE_LIMIT
        assert raw["log_scale"].max() == LOG_SCALE_LIMIT
        T = torch.full((5, 3), 400.0, dtype=torch.float64)
        loss = head.loss(raw, T)
        assert math.isfinite(loss.detach().item())
        loss.backward()
        assert head.net[2].bias.grad[:3].abs().min() > 0  # the location gets a gradient


class TestOptions:
    @pytest.mark.parametrize("hidden", [0, -3])
    def test_bad_hidden_is_refused(self, hidden):
        with pytest.raises(ValueError, match="hidden"):
            create_head("laplace", kind="translation", in_features=4, hidden=hidden)
