"""The paired flight bootstrap and the satellite-swap effect, against independent references."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from benchmark.evaluation.paired import (
    median_bootstrap,
    paired_bootstrap,
    pooled_bootstrap,
    spearman_bootstrap,
    swap_effect,
)


def naive_bootstrap(a, b, groups, n_boot, seed, confidence=0.95):
    """Reference: draw the groups (same generator call), concatenate their frames, average."""
    labels = np.unique(groups)
    draws = np.random.default_rng(seed).integers(0, len(labels), size=(n_boot, len(labels)))
    means = []
    for row in draws:
        frames = np.concatenate([np.flatnonzero(groups == labels[k]) for k in row])
        means.append(np.mean(b[frames] - a[frames]))
    tail = (1 - confidence) / 2
    return np.mean(b - a), np.percentile(means, 100 * tail), np.percentile(means, 100 * (1 - tail))


def clustered(n_groups=30, seed=0, sizes=(1, 9)):
    rng = np.random.default_rng(seed)
    size = rng.integers(sizes[0], sizes[1] + 1, n_groups)
    groups = np.repeat(rng.permutation(1000)[:n_groups] * 7, size)  # arbitrary, unsorted labels
    a = rng.gamma(2.0, 10.0, groups.size)
    shift = np.repeat(rng.normal(3.0, 5.0, n_groups), size)  # one effect per group
    return a, a + shift + rng.normal(0, 1, groups.size), groups


class TestPairedBootstrap:
    @pytest.mark.parametrize("n_boot", [1, 3, 200])
    def test_matches_naive_loop(self, n_boot):
        a, b, g = clustered()
        got = paired_bootstrap(a, b, g, n_boot=n_boot, seed=4)
        np.testing.assert_allclose(got, naive_bootstrap(a, b, g, n_boot, 4), rtol=1e-12)

    def test_closed_form_for_equal_groups_with_one_effect_each(self):
        """Equal group sizes, the difference constant within each group: a replicate's mean is the
        mean of G iid draws of the G group effects, so the interval is mean +- z sd/sqrt(G) with
        the population sd of the effects (G large: normal limit)."""
        rng = np.random.default_rng(1)
        n_groups, size = 400, 5
        effects = rng.normal(2.0, 4.0, n_groups)
        groups = np.repeat(np.arange(n_groups), size)
        a = rng.uniform(0, 50, groups.size)
        b = a + np.repeat(effects, size)
        mean, lo, hi = paired_bootstrap(a, b, groups, n_boot=20000, seed=0)
        assert mean == pytest.approx(effects.mean(), rel=1e-12)
        half = stats.norm.ppf(0.975) * effects.std(ddof=0) / np.sqrt(n_groups)
        assert lo == pytest.approx(mean - half, abs=0.06 * half)
        assert hi == pytest.approx(mean + half, abs=0.06 * half)
        # Resampling frames instead would pretend 5x more data: sqrt(5) narrower.
        _, flo, fhi = paired_bootstrap(a, b, np.arange(groups.size), n_boot=4000, seed=0)
        assert (fhi - flo) < 0.6 * (hi - lo)

    def test_degenerate_cases(self):
        a = np.arange(12.0)
        assert paired_bootstrap(a, a + 2.5, np.arange(12) // 4) == pytest.approx((2.5, 2.5, 2.5))
        a, b, _ = clustered()
        mean, lo, hi = paired_bootstrap(a, b, np.zeros(a.size))  # one group: nothing to resample
        assert lo == pytest.approx(mean) and hi == pytest.approx(mean)

    def test_deterministic_and_seeded(self):
        a, b, g = clustered()
        assert paired_bootstrap(a, b, g, seed=3) == paired_bootstrap(a, b, g, seed=3)
        assert paired_bootstrap(a, b, g, seed=3) != paired_bootstrap(a, b, g, seed=4)

    @pytest.mark.parametrize(
        ("kwargs", "match"),
        [
            ({"err_b": np.zeros(3)}, "same length, got 4, 3, 4"),
            ({"err_a": np.array([0, 1, np.nan, 2])}, "finite"),
            ({"n_boot": 0}, "n_boot must be an integer >= 1, got 0"),
            ({"confidence": 1.0}, r"confidence must be in \(0, 1\), got 1.0"),
        ],
    )
    def test_bad_input_named(self, kwargs, match):
        args = {"err_a": np.zeros(4), "err_b": np.ones(4), "groups": np.arange(4), **kwargs}
        with pytest.raises(ValueError, match=match):
            paired_bootstrap(**args)

    def test_empty(self):
        with pytest.raises(ValueError, match="no frames"):
            paired_bootstrap([], [], [])


class TestSwapEffect:
    def frames(self):
        a, b, g = clustered(seed=2)
        index = np.arange(a.size)
        true = pd.DataFrame({"index": index, "flight": g, "dpsi_deg": a, "dphi_deg": a / 2})
        swap = pd.DataFrame({"index": index, "flight": g, "dpsi_deg": b, "dphi_deg": a / 2})
        return true, swap, (a, b, g)

    def test_rows_matched_on_index_and_both_errors(self):
        true, swap, (a, b, g) = self.frames()
        shuffled = swap.sample(frac=1.0, random_state=0)  # row order must not matter
        got = swap_effect(true, shuffled, n_boot=300, seed=5)
        ref = paired_bootstrap(a, b, g, n_boot=300, seed=5)
        assert (got["swap_dpsi_diff_deg"], got["swap_dpsi_boot_lo_deg"],
                got["swap_dpsi_boot_hi_deg"]) == pytest.approx(ref)  # fmt: skip
        assert got["swap_dphi_diff_deg"] == 0.0 == got["swap_dphi_boot_hi_deg"]
        assert got["swap_groups"] == len(np.unique(g))

    def test_mismatched_frames_refused(self):
        true, swap, _ = self.frames()
        with pytest.raises(ValueError, match="same unique 'index'"):
            swap_effect(true, swap.iloc[1:])
        with pytest.raises(ValueError, match=r"lacks columns \['flight'\]"):
            swap_effect(true, swap.drop(columns="flight"))


def naive_pooled(a, b, groups, n_boot, seed, confidence=0.95):
    """Reference by explicit loops: the same generator calls (flights, then a's seeds, then b's),
    then frame by frame the mean over b's drawn seeds minus the mean over a's drawn seeds."""
    labels = np.unique(groups)
    rng = np.random.default_rng(seed)
    flights = rng.integers(0, len(labels), size=(n_boot, len(labels)))
    seeds_a = rng.integers(0, a.shape[0], size=(n_boot, a.shape[0]))
    seeds_b = rng.integers(0, b.shape[0], size=(n_boot, b.shape[0]))
    means = []
    for r in range(n_boot):
        diffs = []
        for k in flights[r]:
            for n in np.flatnonzero(groups == labels[k]):
                mb = sum(b[s, n] for s in seeds_b[r]) / len(seeds_b[r])
                ma = sum(a[s, n] for s in seeds_a[r]) / len(seeds_a[r])
                diffs.append(mb - ma)
        means.append(np.mean(diffs))
    tail = (1 - confidence) / 2
    point = np.mean(b.mean(axis=0) - a.mean(axis=0))
    return point, np.percentile(means, 100 * tail), np.percentile(means, 100 * (1 - tail))


def seeded(n_seeds_a=3, n_seeds_b=2, seed=0):
    """Clustered frames plus per-seed training noise (one offset per seed and flight)."""
    a, b, g = clustered(n_groups=12, seed=seed)
    rng = np.random.default_rng(seed + 100)
    _, inv = np.unique(g, return_inverse=True)
    noise_a = rng.normal(0, 4, (n_seeds_a, inv.max() + 1))[:, inv]
    noise_b = rng.normal(0, 4, (n_seeds_b, inv.max() + 1))[:, inv]
    return a[None, :] + noise_a, b[None, :] + noise_b, g


class TestPooledBootstrap:
    @pytest.mark.parametrize(("sa", "sb"), [(1, 1), (3, 2), (1, 3)])
    def test_matches_naive_loops(self, sa, sb):
        a, b, g = seeded(sa, sb)
        got = pooled_bootstrap(a, b, g, n_boot=60, seed=7)
        np.testing.assert_allclose(got, naive_pooled(a, b, g, 60, 7), rtol=1e-12)

    def test_one_seed_equals_flight_bootstrap(self):
        a, b, g = clustered()
        assert pooled_bootstrap(a, b, g, n_boot=500, seed=2) == pytest.approx(
            paired_bootstrap(a, b, g, n_boot=500, seed=2), rel=1e-12
        )
        # (N,) and (1, N) are the same single seed
        assert pooled_bootstrap(a[None], b, g, n_boot=50) == pooled_bootstrap(a, b, g, n_boot=50)

    def test_constant_difference_gives_zero_width(self):
        """Seed-invariant errors and b = a + c: every replicate is exactly c."""
        a, _, g = clustered()
        a3 = np.repeat(a[None], 3, axis=0)
        mean, lo, hi = pooled_bootstrap(a3, a3[:2] + 1.25, g, n_boot=300)
        assert (mean, lo, hi) == pytest.approx((1.25, 1.25, 1.25), abs=1e-12)

    def test_closed_form_seed_resampling(self):
        """One flight (nothing to draw there), a's S seeds each a constant alpha_s, b = 0: a
        replicate is minus the mean of S iid draws of the alpha_s, so the interval is
        -mean(alpha) +- z sd(alpha)/sqrt(S) (normal limit, S large)."""
        rng = np.random.default_rng(3)
        n_seeds, n = 400, 6
        alpha = rng.normal(5.0, 2.0, n_seeds)
        a = np.repeat(alpha[:, None], n, axis=1)
        mean, lo, hi = pooled_bootstrap(a, np.zeros(n), np.zeros(n), n_boot=20000, seed=1)
        assert mean == pytest.approx(-alpha.mean(), rel=1e-12)
        half = stats.norm.ppf(0.975) * alpha.std(ddof=0) / np.sqrt(n_seeds)
        assert lo == pytest.approx(mean - half, abs=0.06 * half)
        assert hi == pytest.approx(mean + half, abs=0.06 * half)

    def test_seed_noise_widens_the_interval(self):
        """Averaging the seeds first and bootstrapping flights only ignores the training noise."""
        a, b, g = seeded(3, 3)
        _, lo, hi = pooled_bootstrap(a, b, g, n_boot=4000, seed=0)
        _, flo, fhi = paired_bootstrap(a.mean(0), b.mean(0), g, n_boot=4000, seed=0)
        assert hi - lo > 1.1 * (fhi - flo)

    @pytest.mark.parametrize(
        ("kwargs", "match"),
        [
            ({"err_b": np.zeros((2, 3))}, "same frames, got N = 4, 3, 4"),
            ({"err_a": np.array([0, 1, np.nan, 2])}, "err_a must be finite"),
            ({"err_a": np.zeros((0, 4))}, r"err_a must have shape \(N,\) or \(S, N\)"),
            ({"n_boot": 0}, "n_boot must be an integer >= 1, got 0"),
            ({"confidence": 0.0}, r"confidence must be in \(0, 1\), got 0.0"),
        ],
    )
    def test_bad_input_named(self, kwargs, match):
        args = {"err_a": np.zeros((2, 4)), "err_b": np.ones(4), "groups": np.arange(4), **kwargs}
        with pytest.raises(ValueError, match=match):
            pooled_bootstrap(**args)


def naive_paired_seeds(a, b, groups, n_boot, seed, confidence=0.95):
    """Reference by explicit loops for ``paired_seeds``: the flights, then one draw of seeds used
    for both models; frame by frame the mean over the drawn seeds of ``b[s] - a[s]``."""
    labels = np.unique(groups)
    rng = np.random.default_rng(seed)
    flights = rng.integers(0, len(labels), size=(n_boot, len(labels)))
    seeds = rng.integers(0, a.shape[0], size=(n_boot, a.shape[0]))
    means = []
    for r in range(n_boot):
        diffs = [
            np.mean([b[s, n] - a[s, n] for s in seeds[r]])
            for k in flights[r]
            for n in np.flatnonzero(groups == labels[k])
        ]
        means.append(np.mean(diffs))
    tail = (1 - confidence) / 2
    point = np.mean(b.mean(axis=0) - a.mean(axis=0))
    return point, np.percentile(means, 100 * tail), np.percentile(means, 100 * (1 - tail))


class TestPooledBootstrapPairedSeeds:
    """Two models whose seed-s runs share a trained part (heads on seed s's frozen encoder)."""

    def test_matches_naive_loops(self):
        a, b, g = seeded(3, 3)
        got = pooled_bootstrap(a, b, g, n_boot=60, seed=7, paired_seeds=True)
        np.testing.assert_allclose(got, naive_paired_seeds(a, b, g, 60, 7), rtol=1e-12)

    def test_shared_seed_effect_cancels(self):
        """b = a + c seed by seed, a with large per-seed offsets: paired, every replicate is
        exactly c; drawn independently, the offsets make a wide interval around c."""
        a, _, g = seeded(4, 4)
        a = a + np.array([-20.0, -5.0, 5.0, 20.0])[:, None]  # what each seed's encoder does
        paired = pooled_bootstrap(a, a + 0.75, g, n_boot=2000, seed=3, paired_seeds=True)
        assert paired == pytest.approx((0.75, 0.75, 0.75), abs=1e-12)
        _, lo, hi = pooled_bootstrap(a, a + 0.75, g, n_boot=2000, seed=3)
        assert lo < 0 < hi  # the shared offsets counted twice: no verdict at all

    def test_one_seed_is_the_flight_bootstrap(self):
        a, b, g = clustered()
        assert pooled_bootstrap(a, b, g, n_boot=300, seed=2, paired_seeds=True) == pytest.approx(
            paired_bootstrap(a, b, g, n_boot=300, seed=2), rel=1e-12
        )

    def test_closed_form_seed_resampling(self):
        """One flight, per-seed differences d_s = b_s - a_s: a replicate is the mean of S iid
        draws of the d_s, so the interval is mean(d) +- z sd(d)/sqrt(S) (normal limit)."""
        rng = np.random.default_rng(4)
        n_seeds, n = 400, 5
        shared = rng.normal(0.0, 30.0, n_seeds)[:, None]  # cancels
        d = rng.normal(2.0, 1.5, n_seeds)
        a = np.repeat(shared, n, axis=1)
        b = a + d[:, None]
        mean, lo, hi = pooled_bootstrap(a, b, np.zeros(n), n_boot=20000, seed=1, paired_seeds=True)
        assert mean == pytest.approx(d.mean(), rel=1e-12)
        half = stats.norm.ppf(0.975) * d.std(ddof=0) / np.sqrt(n_seeds)
        assert lo == pytest.approx(mean - half, abs=0.06 * half)
        assert hi == pytest.approx(mean + half, abs=0.06 * half)

    def test_different_seed_counts_refused(self):
        with pytest.raises(ValueError, match=r"paired_seeds needs the same seeds.*got 2 and 1"):
            pooled_bootstrap(np.zeros((2, 4)), np.ones(4), np.arange(4), paired_seeds=True)


def drawn_replicates(g, n_seeds, n_boot, seed):
    """``(frames, seeds)`` of each replicate with the draws of the one-model bootstraps (spearman,
    median): G flights with replacement, then ``n_seeds`` seeds; ``frames`` are the drawn flights'
    frame indices concatenated (a flight drawn twice appears twice)."""
    labels = np.unique(g)
    rng = np.random.default_rng(seed)
    flights = rng.integers(0, len(labels), size=(n_boot, len(labels)))
    seeds = rng.integers(0, n_seeds, size=(n_boot, n_seeds))
    for r in range(n_boot):
        yield np.concatenate([np.flatnonzero(g == labels[k]) for k in flights[r]]), seeds[r]


class TestSpearmanBootstrap:
    def data(self, n_seeds=2):
        rng = np.random.default_rng(4)
        g = np.repeat(np.arange(10), 6)
        x = rng.normal(size=(n_seeds, g.size))
        return x, x + rng.normal(0, 1.5, x.shape), g

    def test_point_is_mean_of_scipy_per_seed(self):
        x, y, g = self.data(3)
        rho, lo, hi = spearman_bootstrap(x, y, g, n_boot=200)
        ref = np.mean([stats.spearmanr(x[s], y[s]).statistic for s in range(3)])
        assert rho == pytest.approx(ref, rel=1e-12)
        assert lo < rho < hi

    @staticmethod
    def scipy_loop(x, y, g, n_boot, seed):
        """Each replicate = mean over drawn seeds of scipy's spearmanr on the drawn frames."""
        reps = [
            np.mean([stats.spearmanr(x[s, frames], y[s, frames]).statistic for s in seeds])
            for frames, seeds in drawn_replicates(g, x.shape[0], n_boot, seed)
        ]
        return np.percentile(reps, 2.5), np.percentile(reps, 97.5)

    def test_replicates_match_scipy_loop(self):
        x, y, g = self.data(2)
        _, lo, hi = spearman_bootstrap(x, y, g, n_boot=40, seed=9)
        assert (lo, hi) == pytest.approx(self.scipy_loop(x, y, g, 40, 9), rel=1e-10)

    def test_ties_match_scipy(self):
        """Ties in the data and duplicated flights: average ranks as scipy's rankdata."""
        x, y, g = self.data(3)
        x, y = np.round(x), np.round(y * 2) / 2
        rho, lo, hi = spearman_bootstrap(x, y, g[::-1] * 3, n_boot=30, seed=2)
        ref = np.mean([stats.spearmanr(x[s], y[s]).statistic for s in range(3)])
        assert rho == pytest.approx(ref, rel=1e-10)
        assert (lo, hi) == pytest.approx(self.scipy_loop(x, y, g[::-1] * 3, 30, 2), rel=1e-10)

    def test_constant_input_gives_nan(self):
        x, y, g = self.data(2)
        rho, lo, hi = spearman_bootstrap(np.zeros_like(x), y, g, n_boot=10)
        assert np.isnan(rho) and np.isnan(lo) and np.isnan(hi)

    def test_monotone_gives_one(self):
        x, _, g = self.data(2)
        assert spearman_bootstrap(x, np.exp(x), g, n_boot=50) == pytest.approx((1.0, 1.0, 1.0))

    def test_shapes_checked(self):
        x, y, g = self.data(2)
        with pytest.raises(ValueError, match="must agree"):
            spearman_bootstrap(x, y[:1], g)


class TestMedianBootstrap:
    @staticmethod
    def data(n_seeds=2, seed=5):
        rng = np.random.default_rng(seed)
        g = np.repeat(np.arange(9), rng.integers(1, 8, 9))  # flights of unequal length
        return rng.gamma(2.0, 10.0, size=(n_seeds, g.size)), g

    @staticmethod
    def expanded_loop(v, g, n_boot, seed):
        """The definition: each replicate = mean over the drawn seeds of ``np.median`` on the
        drawn flights' concatenated frames."""
        reps = [
            np.mean([np.median(v[s, frames]) for s in seeds])
            for frames, seeds in drawn_replicates(g, v.shape[0], n_boot, seed)
        ]
        return np.percentile(reps, 2.5), np.percentile(reps, 97.5)

    def test_point_is_mean_of_numpy_medians(self):
        v, g = self.data(3)
        point, lo, hi = median_bootstrap(v, g, n_boot=300)
        assert point == pytest.approx(np.median(v, axis=1).mean(), rel=1e-12)
        assert lo < point < hi

    @pytest.mark.parametrize("n_seeds", [1, 2, 3])
    def test_replicates_match_expanded_loop(self, n_seeds):
        v, g = self.data(n_seeds)
        _, lo, hi = median_bootstrap(v, g, n_boot=300, seed=4)  # > one block of 256
        assert (lo, hi) == pytest.approx(self.expanded_loop(v, g, 300, 4), rel=1e-12)

    def test_ties_and_unsorted_flight_labels(self):
        v, g = self.data(2)
        v = np.round(v / 10.0)  # many equal values
        _, lo, hi = median_bootstrap(v, g[::-1] * 7 + 3, n_boot=60, seed=1)
        assert (lo, hi) == pytest.approx(self.expanded_loop(v, g[::-1] * 7 + 3, 60, 1))

    def test_one_flight_one_seed_has_no_spread(self):
        v = np.arange(7.0)
        assert median_bootstrap(v, np.zeros(7), n_boot=20) == (3.0, 3.0, 3.0)

    def test_bad_input_named(self):
        v, g = self.data(2)
        with pytest.raises(ValueError, match="must hold the same frames"):
            median_bootstrap(v, g[:-1])
        with pytest.raises(ValueError, match="values must be finite"):
            median_bootstrap(np.array([1.0, np.nan]), np.zeros(2))
        with pytest.raises(ValueError, match="n_boot must be an integer >= 1"):
            median_bootstrap(v, g, n_boot=0)
