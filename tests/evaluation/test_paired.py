"""The paired flight bootstrap and the satellite-swap effect, against independent references."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from benchmark.evaluation.paired import paired_bootstrap, swap_effect


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
