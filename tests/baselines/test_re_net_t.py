"""Re-Net-T (version 3): direction and length of the standardised translation ``u``, against numpy.

``u = (T - mean) / std`` per axis; the direction ``u / |u|`` is a lattice vMF, the scale the
standardised ``|u|``. Labels like the dataset's: ``dU`` ~ -900 +- 100 m, ``dE``, ``dN`` within
+-150 m (|T| ~ 930 m), so the direction of ``T`` itself has no range but that of ``u`` does.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy import stats

from benchmark.geometry import fibonacci_sphere
from benchmark.models import create_head

F = 16
# Four labels like the dataset's (metres): the overfit set of the issue.
LABELS = torch.tensor(
    [
        [120.0, -80.0, -1010.0],
        [-150.0, 140.0, -820.0],
        [40.0, 150.0, -905.0],
        [-90.0, -130.0, -960.0],
    ]
)


def dataset_like(n: int, seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    T = torch.empty(n, 3, dtype=torch.float64)
    T[:, :2] = (torch.rand(n, 2, generator=g, dtype=torch.float64) * 2 - 1) * 150
    T[:, 2] = -900 + 100 * torch.randn(n, generator=g, dtype=torch.float64)
    return T


def head(n_points: int = 4096, **kwargs):
    torch.manual_seed(0)
    return create_head("re_net_t", in_features=F, n_points=n_points, **kwargs).double()


def fitted(seed: int, n: int = 200, **kwargs):
    h = head(**kwargs)
    h.fit_statistics(dataset_like(n, seed=seed))
    return h


def np_standardised(h, T: torch.Tensor) -> np.ndarray:
    """numpy reference of ``u = (T - mean) / std``."""
    return (T.numpy() - h.mean.numpy()) / h.std.numpy()


def np_softmax(x: np.ndarray) -> np.ndarray:
    e = np.exp(x - x.max(-1, keepdims=True))
    return e / e.sum(-1, keepdims=True)


def np_decode(h, logits: np.ndarray, s: np.ndarray) -> np.ndarray:
    """numpy reference of the decoding: ``mean + std * max(m + s sd, 0) * normalise(E d)``."""
    grid = fibonacci_sphere(logits.shape[-1]).double().numpy()
    resultant = np_softmax(logits) @ grid
    direction = resultant / np.linalg.norm(resultant, axis=-1, keepdims=True)
    length = np.maximum(h.scale_mean.item() + s * h.scale_std.item(), 0.0)
    return h.mean.numpy() + h.std.numpy() * length[:, None] * direction


class TestStatistics:
    def test_fit_statistics_sets_axis_and_scale_statistics(self):
        h = head()
        T = dataset_like(500, seed=0)
        h.fit_statistics(T)
        np.testing.assert_allclose(h.mean.numpy(), T.numpy().mean(0), rtol=1e-12)
        np.testing.assert_allclose(h.std.numpy(), T.numpy().std(0), rtol=1e-12)
        r = np.linalg.norm(np_standardised(h, T), axis=-1)
        assert h.scale_mean.item() == pytest.approx(r.mean(), rel=1e-12)
        assert h.scale_std.item() == pytest.approx(r.std(), rel=1e-12)  # population std

    def test_convention_training_scales_standardise_to_zero_mean_unit_std(self):
        h = fitted(seed=1, n=500)
        s = h.target_distribution(dataset_like(500, seed=1))["scale"]
        assert s.mean().item() == pytest.approx(0.0, abs=1e-9)
        assert s.std(unbiased=False).item() == pytest.approx(1.0, abs=1e-9)

    def test_standardised_directions_have_range_where_those_of_T_have_none(self):
        # The reason for version 3: the directions of T stay within ~20 deg of straight down, the
        # directions of u cover the sphere (mean resultant length near 0 versus near 1).
        h = fitted(seed=2, n=500)
        T = dataset_like(500, seed=2).numpy()
        u = np_standardised(h, torch.from_numpy(T))
        d_T = T / np.linalg.norm(T, axis=-1, keepdims=True)
        d_u = u / np.linalg.norm(u, axis=-1, keepdims=True)
        assert np.linalg.norm(d_T.mean(0)) > 0.95
        assert np.linalg.norm(d_u.mean(0)) < 0.1

    def test_set_statistics_fallback_is_the_chi3_moments(self):
        h = fitted(seed=3)
        h.set_statistics(torch.tensor([10.0, -20.0, -900.0]), torch.tensor([150.0, 150.0, 100.0]))
        assert h.scale_mean.item() == pytest.approx(stats.chi(3).mean(), rel=1e-6)
        assert h.scale_std.item() == pytest.approx(stats.chi(3).std(), rel=1e-6)
        assert head().scale_mean.item() == pytest.approx(stats.chi(3).mean(), rel=1e-6)

    def test_scale_statistics_are_saved_in_the_state_dict(self):
        h = fitted(seed=4, n=50)
        other = head()
        other.load_state_dict(h.state_dict())
        assert other.scale_mean.item() == h.scale_mean.item()
        assert other.scale_std.item() == h.scale_std.item()

    def test_version_2_state_dict_is_refused(self):
        # Version 2 kept |T| statistics under other names: loading one must fail, not mislead.
        state = fitted(seed=5, n=50).state_dict()
        state["length_mean"] = state.pop("scale_mean")
        state["length_std"] = state.pop("scale_std")
        with pytest.raises(RuntimeError, match="scale_mean"):
            head().load_state_dict(state)

    def test_bad_labels_name_the_shape(self):
        with pytest.raises(ValueError, match=r"shape \(M >= 2, 3\)"):
            head().fit_statistics(torch.zeros(5, 2))


class TestTarget:
    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_target_is_the_vmf_of_the_standardised_direction(self, batch):
        h = fitted(seed=6, n_points=256)
        T = dataset_like(batch, seed=6 + batch)
        u = np_standardised(h, T)
        r = np.linalg.norm(u, axis=-1)
        grid = fibonacci_sphere(256).double().numpy()
        expected = np_softmax(10.0 * (u / r[:, None]) @ grid.T)
        target = h.target_distribution(T)
        np.testing.assert_allclose(target["direction"].numpy(), expected, rtol=1e-10, atol=1e-15)
        s = (r - h.scale_mean.item()) / h.scale_std.item()
        np.testing.assert_allclose(target["scale"].numpy(), s, rtol=1e-10, atol=1e-12)

    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_target_decodes_to_the_label(self, batch):
        h = fitted(seed=7)
        T = dataset_like(batch, seed=7 + batch)
        T_hat = h.decode_distribution(h.target_distribution(T))
        # The expectation of a kappa-10 lattice vMF points along mu to ~1e-4 rad, times
        # std * |u| (~150 m * 3 at most): < 0.1 m.
        assert (T_hat - T).norm(dim=-1).max() < 0.1


class TestDegenerateScale:
    """``|u| -> 0``: the direction is undefined; target falls back to e_z, decoding -> mean."""

    def test_label_at_the_mean_decodes_to_the_mean(self):
        h = fitted(seed=8)
        T = h.mean[None].clone()
        target = h.target_distribution(T)
        grid = fibonacci_sphere(4096).double().numpy()
        np.testing.assert_allclose(  # the e_z fallback
            target["direction"][0].numpy(), np_softmax(10.0 * grid[:, 2]), rtol=1e-10
        )
        assert target["scale"].item() == pytest.approx(-h.scale_mean.item() / h.scale_std.item())
        torch.testing.assert_close(h.decode_distribution(target), T, rtol=0, atol=1e-9)

    @pytest.mark.parametrize("eps", [1e-9, 1e-6, 1e-3])
    def test_labels_near_the_mean_from_all_sides_decode_close(self, eps):
        # The label direction jumps as u crosses 0, the decoded translation moves by <= 2|std||u|.
        h = fitted(seed=9)
        v = torch.tensor(stats.uniform_direction(3).rvs(16, random_state=0))
        T = h.mean + eps * h.std * v
        T_hat = h.decode_distribution(h.target_distribution(T))
        bound = 2 * eps * h.std.norm().item() + 1e-9
        assert (T_hat - T).norm(dim=-1).max().item() < bound

    def test_zero_length_decodes_to_the_mean_whatever_the_direction(self):
        h = fitted(seed=10)
        g = torch.Generator().manual_seed(0)
        logits = 5 * torch.randn(4, 4096, generator=g, dtype=torch.float64)
        s = torch.full((4,), -h.scale_mean.item() / h.scale_std.item(), dtype=torch.float64)
        torch.testing.assert_close(h.decode({"logits": logits, "scale": s}), h.mean.expand(4, 3))

    def test_negative_length_clamps_to_the_mean(self):
        h = fitted(seed=11)
        raw = {"logits": torch.zeros(2, 4096, dtype=torch.float64)}
        raw["scale"] = torch.full((2,), -1e3, dtype=torch.float64)
        assert torch.equal(h.decode(raw), h.mean.expand(2, 3))

    def test_loss_and_gradient_are_finite_at_the_mean(self):
        h = fitted(seed=12, n_points=64)
        logits = torch.randn(2, 64, dtype=torch.float64, requires_grad=True)
        s = torch.zeros(2, dtype=torch.float64, requires_grad=True)
        loss = h.loss({"logits": logits, "scale": s}, h.mean.expand(2, 3).clone())
        loss.backward()
        assert torch.isfinite(loss) and torch.isfinite(logits.grad).all()
        assert torch.isfinite(s.grad).all()


class TestDecode:
    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_decode_matches_numpy(self, batch):
        h = fitted(seed=13, n_points=256)
        g = torch.Generator().manual_seed(batch)
        logits = 3 * torch.randn(batch, 256, generator=g, dtype=torch.float64)
        s = torch.randn(batch, generator=g, dtype=torch.float64)
        T_hat = h.decode({"logits": logits, "scale": s})
        np.testing.assert_allclose(
            T_hat.numpy(), np_decode(h, logits.numpy(), s.numpy()), rtol=1e-10, atol=1e-9
        )

    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_near_vertical_translations_perturbed(self, batch):
        # Straight below and slightly off it (the directions of T have no range there), with
        # perturbed logits: the error stays small (no boundary on the lattice).
        h = fitted(seed=14)
        g = torch.Generator().manual_seed(batch)
        T = torch.zeros(batch, 3, dtype=torch.float64)
        T[:, :2] = torch.randn(batch, 2, generator=g, dtype=torch.float64) * 2.0
        T[:, 2] = -900.0
        target = h.target_distribution(T)
        logits = torch.log(target["direction"])
        noisy = logits + 0.2 * torch.randn(logits.shape, generator=g, dtype=torch.float64)
        T_hat = h.decode({"logits": noisy, "scale": target["scale"]})
        assert (T_hat - T).norm(dim=-1).max() < 5.0

    def test_uncertainty_is_the_spherical_variance(self):
        h = fitted(seed=15, n_points=256)
        logits = torch.randn(
            5, 256, generator=torch.Generator().manual_seed(0), dtype=torch.float64
        )
        grid = fibonacci_sphere(256).double().numpy()
        expected = 1 - np.linalg.norm(np_softmax(logits.numpy()) @ grid, axis=-1)
        np.testing.assert_allclose(h.uncertainty({"logits": logits}).numpy(), expected, rtol=1e-10)

    def test_gradcheck_float64(self):
        h = fitted(seed=16, n=50, n_points=64)
        g = torch.Generator().manual_seed(0)
        logits = torch.randn(3, 64, generator=g, dtype=torch.float64, requires_grad=True)
        s = torch.randn(3, generator=g, dtype=torch.float64, requires_grad=True)
        assert torch.autograd.gradcheck(
            lambda a, b: h.decode({"logits": a, "scale": b}), (logits, s)
        )


class TestLoss:
    @pytest.mark.parametrize("batch", [1, 3, 8])
    def test_scale_term_is_squared_standardised_error(self, batch):
        h = fitted(seed=17, alpha=0.0, scale_weight=2.0)
        T = dataset_like(batch, seed=18)
        logits = torch.log(h.target_distribution(T)["direction"])
        r = np.linalg.norm(np_standardised(h, T), axis=-1)
        s_true = torch.from_numpy((r - h.scale_mean.item()) / h.scale_std.item())
        base = h.loss({"logits": logits, "scale": s_true}, T)
        shifted = h.loss({"logits": logits, "scale": s_true + 0.5}, T)
        assert (shifted - base).item() == pytest.approx(2.0 * 0.25, abs=1e-9)

    def test_gradcheck_float64(self):
        h = fitted(seed=19, n=50, n_points=64)
        T = dataset_like(3, seed=20)
        g = torch.Generator().manual_seed(1)
        logits = torch.randn(3, 64, generator=g, dtype=torch.float64, requires_grad=True)
        s = torch.randn(3, generator=g, dtype=torch.float64, requires_grad=True)
        assert torch.autograd.gradcheck(
            lambda a, b: h.loss({"logits": a, "scale": b}, T), (logits, s)
        )


def overfit(name: str, steps: int = 300) -> torch.Tensor:
    """Fixed random features -> head, Adam 1e-3, ``steps`` steps on LABELS; (4, 3) metres out."""
    torch.manual_seed(0)
    h = create_head(name, in_features=64)
    h.fit_statistics(LABELS)
    x = torch.randn(4, 64, generator=torch.Generator().manual_seed(1))
    optimizer = torch.optim.Adam(h.parameters(), lr=1e-3)
    for _ in range(steps):
        loss = h.loss(h(x), LABELS)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    with torch.no_grad():
        return h.decode(h(x))


class TestOverfitDatasetLikeLabels:
    def test_translation_is_learned_close_to_the_regression_head(self):
        # The case: |T| / rms (v1) missed by 10-26 m after 300 steps; the standardised |T|
        # (v2) fit the length but the direction of T still cost several metres. Direction and
        # length of u both have range. Measured: 0.3-1.1 m (v2: ~3 m; regression head: ~0 m).
        T_hat = overfit("re_net_t")
        errors = (T_hat - LABELS).norm(dim=-1)
        assert errors.max() < 2.0, errors
        reference = overfit("regression")
        assert (reference - LABELS).norm(dim=-1).max() < 1.0
