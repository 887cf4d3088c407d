"""The equivalence rule of issue 38: a fourth outcome for "A beats B", against a closed form (a
normal Δ of known mean and spread: two one-sided tests at 5%), and on a constructed tie, a
constructed win and a constructed too-small sample; the margins kept in one place and printed in
the claims table's note.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import norm
from test_frames import SPLITS, Repro

from benchmark.runner.claims.all_claims import margins_note, render_claims
from benchmark.runner.claims.evidence import (
    EQUIVALENCE_MARGINS,
    EQUIVALENT,
    NO_DIFFERENCE,
    SUPPORTED,
    TRANSLATION,
    UNRESOLVED,
    Comparison,
    Evidence,
    FrameErrors,
    combine,
    is_equivalent,
    margin_of,
)
from benchmark.runner.claims.paper import pairwise_claim, translation_claim

STD = "standard/test"


def normal_differences(mu: float, sigma: float, n: int, seed: int = 0) -> np.ndarray:
    """``(n,)`` values with sample mean exactly ``mu`` and (population) sd exactly ``sigma``."""
    x = np.random.default_rng(seed).standard_normal(n)
    return mu + sigma * (x - x.mean()) / x.std()


def paired_on(delta: np.ndarray, margin: float) -> Comparison:
    """Δ per frame against zero, one frame per flight (independent frames), one seed."""
    n = len(delta)
    index, flight = np.arange(n), np.arange(n)
    a = FrameErrors(delta[None, :], index, flight, (0,))
    b = FrameErrors(np.zeros((1, n)), index, flight, (0,))
    return Evidence(frames=None).paired("x", a, b, margin=margin)  # type: ignore[arg-type]


class TestMargins:
    def test_the_issue_margins(self):
        """Fixed by the issue before any data: δφ δψ 2°, δθ δγ 1°, positions 5 m, ρ 0.05."""
        expected = {"dphi_deg": 2.0, "dpsi_deg": 2.0, "dtheta_deg": 1.0, "dgamma_deg": 1.0,
                    "dE_m": 5.0, "dN_m": 5.0, "dU_m": 5.0, "horizontal_m": 5.0,
                    TRANSLATION: 5.0, "spearman_rho": 0.05}  # fmt: skip
        assert expected == EQUIVALENCE_MARGINS

    def test_unknown_metric_has_no_silent_margin(self):
        with pytest.raises(KeyError, match="no equivalence margin for 'loss'"):
            margin_of("loss")

    def test_note_prints_every_margin_from_the_one_table(self):
        note = margins_note()
        assert "δφ, δψ: 2°" in note and "δθ, δγ: 1°" in note
        assert "δE, δN, δU, horizontal, mean(δE, δN, δU): 5 m" in note
        assert "Spearman ρ: 0.05" in note
        assert margins_note() in render_claims([])


class TestClosedForm:
    """A normal Δ with N independent frames: the bootstrap of its mean is normal with standard
    error σ/√N, so the two one-sided tests at 5% decide "equivalent" exactly when
    |μ| + z₀.₉₅ σ/√N < m (scipy's normal quantile)."""

    N, SIGMA, MARGIN = 2000, 20.0, 2.0

    @property
    def se(self) -> float:
        return self.SIGMA / math.sqrt(self.N)

    def test_ninety_percent_interval_is_the_normal_one(self):
        c = paired_on(normal_differences(0.3, self.SIGMA, self.N), self.MARGIN)
        from benchmark.evaluation.paired import percentile_interval

        lo, hi = percentile_interval(c.replicates, 0.90)
        z = norm.ppf(0.95)
        # Monte Carlo error of a 5% quantile over 4000 replicates: about 0.03 standard errors.
        assert lo == pytest.approx(0.3 - z * self.se, abs=0.12 * self.se)
        assert hi == pytest.approx(0.3 + z * self.se, abs=0.12 * self.se)

    @pytest.mark.parametrize("offset", [-2.0, -0.5, 0.5, 2.0])  # distance to the boundary, in SE
    @pytest.mark.parametrize("sign", [-1.0, 1.0])
    def test_decision_matches_two_one_sided_tests(self, offset, sign):
        z = norm.ppf(0.95)
        mu = sign * (self.MARGIN - z * self.se + offset * self.se)
        c = paired_on(normal_differences(mu, self.SIGMA, self.N), self.MARGIN)
        closed_form = abs(mu) + z * self.se < self.MARGIN
        assert closed_form == (offset < 0)
        assert is_equivalent(c) == closed_form

    def test_a_clear_difference_inside_the_margin_is_equivalent_not_a_win(self):
        """Δ −1 ± 0.45 (95%): below zero, yet inside ±2: no practical win."""
        c = paired_on(normal_differences(-1.0, self.SIGMA, self.N), self.MARGIN)
        assert c.hi < 0
        assert combine([c]) == NO_DIFFERENCE and c.verdict == EQUIVALENT

    def test_a_claim_of_no_difference_counts_equivalence_as_support(self):
        c = paired_on(normal_differences(0.2, self.SIGMA, self.N), self.MARGIN)
        assert combine([c], equivalent_supports=True) == SUPPORTED


def two_models(repro: Repro, a, b, metrics=("dphi_deg",)):
    repro.add("table1", "A", {STD: a})
    repro.add("table1", "B", {STD: b})
    return pairwise_claim(Evidence(repro.store()), "A beats B", "t", "table1", "A", "B",
                          list(metrics))  # fmt: skip


class TestConstructed:
    def test_tie(self, tmp_path):
        c = two_models(Repro(tmp_path), 10.0, 10.0)
        assert c.verdict == NO_DIFFERENCE
        assert c.comparisons[0].verdict == EQUIVALENT and "≈" in c.difference

    def test_win(self, tmp_path):
        c = two_models(Repro(tmp_path), 5.0, 20.0)
        assert c.verdict == SUPPORTED and c.comparisons[0].verdict == SUPPORTED

    def test_too_small_sample_stays_not_resolved(self, tmp_path):
        """Five flights of one frame, large errors: the interval is wider than the margin in
        both directions, so neither a win, a loss nor a tie."""
        repro = Repro(tmp_path, splits={**SPLITS, STD: (5, 1)})
        c = two_models(repro, 30.0, 30.0)
        assert c.verdict == UNRESOLVED
        comp = c.comparisons[0]
        assert comp.verdict == UNRESOLVED and comp.lo < -2.0 and comp.hi > 2.0

    def test_translation_tie_supports_no_improvement(self, tmp_path):
        """Claim 4 states no difference: a tie within 5 m supports it."""
        repro = Repro(tmp_path)
        repro.add("table3", "Pd/Re-Net", {STD: 8.0})
        repro.add("table3", "Re-Net-T", {STD: 8.0})
        c = translation_claim(Evidence(repro.store()))
        assert c.comparisons[0].verdict == EQUIVALENT
        assert c.verdict == SUPPORTED
