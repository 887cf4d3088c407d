"""Every registered head, parametrized over the registry: a new head is tested for free."""

from __future__ import annotations

import itertools
import math

import pytest
import torch
from scipy.spatial.transform import Rotation

from benchmark.geometry import geodesic_distance
from benchmark.models import create_head, get_head_class, list_heads

ATTITUDE = list_heads("attitude")
TRANSLATION = list_heads("translation")
PROB_ATTITUDE = [n for n in ATTITUDE if get_head_class(n).is_probabilistic]
PROB_TRANSLATION = [n for n in TRANSLATION if get_head_class(n).is_probabilistic]
# What evaluation asks of a head (heads.py): log_prob and uncertainty for the full grid contract or
# for the matching flag of a density head that is not a grid distribution.
LOG_PROB_ATTITUDE = [
    n for n in ATTITUDE if get_head_class(n).is_probabilistic or get_head_class(n).gives_log_prob
]
UNCERTAINTY_ATTITUDE = [
    n for n in ATTITUDE if get_head_class(n).is_probabilistic or get_head_class(n).gives_uncertainty
]
F = 24  # feature width: heads do not care, small keeps the suite fast
DTYPES = [torch.float32, torch.float64]


def rotations(n: int, seed: int = 0, dtype=torch.float64) -> torch.Tensor:
    return torch.tensor(Rotation.random(n, random_state=seed).as_matrix(), dtype=dtype)


def make(name: str, dtype=torch.float32):
    torch.manual_seed(0)
    return create_head(name, in_features=F).to(dtype)


def features(batch: int, dtype, seed: int = 1) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.randn(batch, F, generator=g, dtype=torch.float64).to(dtype).requires_grad_()


def grads_reach(x: torch.Tensor) -> bool:
    return x.grad is not None and bool(torch.isfinite(x.grad).all()) and x.grad.abs().sum() > 0


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("batch", [1, 8])
@pytest.mark.parametrize("name", ATTITUDE)
class TestAttitudeContract:
    def test_decode_is_a_rotation(self, name, batch, dtype):
        head = make(name, dtype)
        R = head.decode(head(features(batch, dtype)))
        assert R.shape == (batch, 3, 3) and R.dtype == dtype
        eye = torch.eye(3, dtype=dtype).expand(batch, 3, 3)
        tol = 1e-5 if dtype == torch.float32 else 1e-10
        torch.testing.assert_close(R.transpose(-1, -2) @ R, eye, atol=tol, rtol=0)
        torch.testing.assert_close(
            torch.linalg.det(R), torch.ones(batch, dtype=dtype), atol=tol, rtol=0
        )

    def test_loss_is_finite_scalar_with_gradient(self, name, batch, dtype):
        head = make(name, dtype)
        x = features(batch, dtype)
        loss = head.loss(head(x), rotations(batch, dtype=dtype))
        assert loss.dim() == 0 and loss.dtype == dtype and torch.isfinite(loss)
        loss.backward()
        assert grads_reach(x)

    def test_wrong_feature_width(self, name, batch, dtype):
        head = make(name, dtype)
        with pytest.raises(ValueError, match=f"\\(B, {F}\\)"):
            head(torch.randn(batch, F + 1, dtype=dtype))


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("batch", [1, 8])
@pytest.mark.parametrize("name", TRANSLATION)
class TestTranslationContract:
    def test_decode_and_loss(self, name, batch, dtype):
        head = make(name, dtype)
        head.set_statistics(torch.tensor([10.0, -5.0, 80.0]), torch.tensor([100.0, 60.0, 10.0]))
        x = features(batch, dtype)
        raw = head(x)
        T = head.decode(raw)
        assert T.shape == (batch, 3) and T.dtype == dtype and torch.isfinite(T).all()
        loss = head.loss(raw, torch.randn(batch, 3, dtype=dtype) * 100)
        assert loss.dim() == 0 and torch.isfinite(loss)
        loss.backward()
        assert grads_reach(x)


@pytest.mark.parametrize("name", TRANSLATION)
class TestTranslationStatistics:
    def test_statistics_are_saved_buffers(self, name):
        head = make(name)
        T = torch.randn(500, 3, dtype=torch.float64) * torch.tensor([100.0, 50, 5]) + 7
        head.fit_statistics(T)
        state = head.state_dict()
        torch.testing.assert_close(state["mean"], T.mean(0).float())
        torch.testing.assert_close(state["std"], T.std(0, unbiased=False).float())

    @pytest.mark.parametrize("std", [[1.0, 0.0, 1.0], [1.0, -2.0, 1.0], [1.0, float("nan"), 1]])
    def test_bad_statistics(self, name, std):
        with pytest.raises(ValueError, match="std > 0"):
            make(name).set_statistics(torch.zeros(3), torch.tensor(std))


@pytest.mark.parametrize("name", PROB_ATTITUDE)
class TestProbabilisticAttitude:
    def test_own_target_decodes_to_the_label(self, name):
        # Lattice resolution: ~3.2 deg spacing on S^2 with 4096 points, 2.8 deg Euler bins;
        # the expectation interpolates between points, so the recovered label is much closer.
        head = make(name, torch.float64)
        R = rotations(16, seed=3)
        R_hat = head.decode_distribution(head.target_distribution(R))
        assert geodesic_distance(R_hat, R).max() < math.radians(1.0)

    def test_distribution_sums_to_one(self, name):
        head = make(name)
        dist = head.distribution(head(features(4, torch.float32)))
        tensors = dist.values() if isinstance(dist, dict) else [dist]
        probs = [t for t in tensors if t.dim() >= 2]
        assert probs
        for p in probs:
            assert (p >= 0).all()
            torch.testing.assert_close(p.sum(-1), torch.ones(p.shape[:-1]))

    def test_decode_equals_decode_distribution(self, name):
        head = make(name)
        raw = head(features(4, torch.float32))
        torch.testing.assert_close(
            head.decode(raw), head.decode_distribution(head.distribution(raw))
        )

    def test_log_prob_and_uncertainty_shapes(self, name):
        head = make(name)
        raw = head(features(5, torch.float32))
        lp = head.log_prob(raw, rotations(5, dtype=torch.float32))
        u = head.uncertainty(raw)
        assert lp.shape == (5,) and torch.isfinite(lp).all()
        assert u.shape == (5,) and ((u >= 0) & (u <= 1)).all()


@pytest.mark.parametrize("name", PROB_TRANSLATION)
class TestProbabilisticTranslation:
    def test_own_target_decodes_to_the_label(self, name):
        head = make(name, torch.float64)
        head.set_statistics(torch.tensor([0.0, 0.0, 80.0]), torch.tensor([300.0, 300.0, 20.0]))
        T = torch.randn(16, 3, dtype=torch.float64) * 200
        T_hat = head.decode_distribution(head.target_distribution(T))
        cos = torch.nn.functional.cosine_similarity(T_hat, T, dim=-1)
        assert torch.arccos(cos.clamp(-1, 1)).max() < math.radians(1.0)
        # A lattice head's decoded target is exact to ~1e-3 of its length: the expectation of a
        # discretised vMF is biased by ~1e-4 rad (Re-Net-T v3 decodes through T = mean + std * u).
        torch.testing.assert_close(T_hat.norm(dim=-1), T.norm(dim=-1), rtol=5e-3, atol=1e-6)


def repeat_raw(raw, index: int, n: int):
    """The raw output of sample ``index`` repeated ``n`` times (tensor or dict of tensors)."""
    if isinstance(raw, dict):
        return {k: repeat_raw(v, index, n) for k, v in raw.items()}
    return raw[index : index + 1].expand(n, *raw.shape[1:])


# Monte Carlo over the Haar measure: scipy's uniform rotations, the independent reference for
# "log_prob is a density w.r.t. the normalised Haar measure" (its mean of exp must be 1).
MC_SAMPLES = 5000
MC_CHUNK = 500


@pytest.mark.parametrize("name", LOG_PROB_ATTITUDE)
class TestLogProbIsHaarNormalised:
    def test_density_integrates_to_one(self, name):
        # A freshly initialised head predicts a broad density (every head's quadrature or grid
        # resolves it); E_Haar[exp(log_prob)] = 1 within 5 standard errors of the Monte Carlo
        # mean plus 2 % for the heads' own discretisation (lattice cells, quadrature grids).
        # One prediction: a head's normaliser may cost (rotations x quadrature grid) per call.
        head = make(name, torch.float64).eval()
        with torch.no_grad():
            raw = head(features(1, torch.float64))
            density = torch.cat(
                [
                    torch.exp(head.log_prob(repeat_raw(raw, 0, len(chunk)), chunk))
                    for chunk in rotations(MC_SAMPLES, seed=21).split(MC_CHUNK)
                ]
            )
        se = density.std().item() / math.sqrt(MC_SAMPLES)
        assert density.mean().item() == pytest.approx(1.0, abs=5 * se + 0.02), (
            f"{name}: mean density {density.mean().item():.4f} (standard error {se:.4f})"
        )


@pytest.mark.parametrize("name", UNCERTAINTY_ATTITUDE)
class TestUncertainty:
    def test_shape_dtype_finite(self, name):
        # (B,), the prediction's dtype, finite, for both dtypes and batches 1 and 8.
        for dtype, batch in itertools.product(DTYPES, (1, 8)):
            head = make(name, dtype)
            u = head.uncertainty(head(features(batch, dtype)))
            assert u.shape == (batch,) and u.dtype == dtype and torch.isfinite(u).all(), (
                dtype,
                batch,
            )


@pytest.mark.parametrize("name", ATTITUDE + TRANSLATION)
class TestGradcheck:
    def test_loss_gradcheck_float64(self, name):
        torch.manual_seed(0)
        head = create_head(name, in_features=3).double()
        if name in TRANSLATION:
            head.set_statistics(torch.tensor([5.0, -3.0, 80.0]), torch.tensor([50.0, 40.0, 10.0]))
            label = torch.randn(2, 3, dtype=torch.float64) * 50
        else:
            label = rotations(2, seed=4)
        x = torch.randn(2, 3, dtype=torch.float64, requires_grad=True)

        def loss(f: torch.Tensor) -> torch.Tensor:
            # A head may draw random numbers in training (IPDF turns its query grid every step):
            # the same draw on every call, so the loss is one function of the features.
            with torch.random.fork_rng():
                torch.manual_seed(0)
                return head.loss(head(f), label)

        assert torch.autograd.gradcheck(loss, (x,), eps=1e-6, atol=1e-5)
