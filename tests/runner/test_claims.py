"""Claims decided by paired statistics: synthetic reproductions (real CSV formats, 3 seeds, 10-12
flights per split, ``test_frames.Repro``) with a clear win, a clear loss, noise, a head at the
constant predictor's level and seeds that disagree; the combination rule on hand-made replicates.
"""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest
from test_frames import SPLITS, Repro

from benchmark.evaluation.paired import pooled_bootstrap
from benchmark.runner.claims.all_claims import evaluate_claims, render_claims
from benchmark.runner.claims.evidence import (
    CONTRADICTED,
    EQUIVALENT,
    EXCLUDED,
    N_BOOT,
    NO_DIFFERENCE,
    NOT_RUN,
    SUPPORTED,
    UNRESOLVED,
    Comparison,
    Evidence,
    combine,
    head_family,
    shares_seed_runs,
)
from benchmark.runner.claims.paper import (
    constant_claim,
    kappa_claim,
    pairwise_claim,
    representation_claim,
    translation_claim,
    uncertainty_claim,
)
from benchmark.runner.claims.satellite import control_claim, satellite_claim
from benchmark.runner.plan.specs import RowSpec

STD, GEN = "standard/test", "generalized/test"


def replace_model(row: RowSpec, **fields) -> RowSpec:
    return dataclasses.replace(row, model={**row.model, **fields})


def add_head(repro: Repro, table: str, label: str, attitude: str, splits, **kwargs) -> None:
    """``repro.add`` with the row's attitude head set to ``attitude`` (Repro uses pd_re_net)."""
    first = len(repro.units)
    repro.add(table, label, splits, **kwargs)
    for unit in repro.units[first:]:
        unit.jobs = [
            dataclasses.replace(
                j, row=dataclasses.replace(j.row, model={**j.row.model, "attitude": attitude})
            )
            for j in unit.jobs
        ]


def claim_ab(repro: Repro, a, b, metrics=("dphi_deg",)):
    repro.add("table1", "A", {STD: a})
    repro.add("table1", "B", {STD: b})
    return pairwise_claim(Evidence(repro.store()), "A beats B", "t", "table1", "A", "B",
                          list(metrics))  # fmt: skip


def comparison(replicates, claimed=-1, threshold=0.0) -> Comparison:
    reps = np.asarray(replicates, dtype=float)
    return Comparison("x", reps.mean(), *np.quantile(reps, [0.025, 0.975]), claimed, threshold,
                      reps)  # fmt: skip


class TestCombine:
    def test_all_supported(self):
        comps = [comparison(np.linspace(-3, -1, 1000)) for _ in range(3)]
        assert combine(comps) == SUPPORTED
        assert all(c.verdict == SUPPORTED for c in comps)

    def test_one_clear_counterexample_contradicts(self):
        comps = [comparison(np.linspace(-3, -1, 1000)), comparison(np.linspace(1, 3, 1000))]
        assert combine(comps) == CONTRADICTED

    def test_contradiction_needs_the_bonferroni_level(self):
        """Above zero at 95% but not at 1 - 0.05/10: one of ten looks is not a counterexample."""
        marginal = np.linspace(-0.1, 10, 4000)  # 2.5% quantile +0.15, 0.25% quantile -0.075
        comps = [comparison(marginal)] + [comparison(np.linspace(-3, -1, 1000)) for _ in range(9)]
        assert combine(comps) == UNRESOLVED
        assert combine([comparison(marginal)]) == CONTRADICTED

    def test_straddling_is_unresolved_and_nothing_is_not_run(self):
        assert combine([comparison(np.linspace(-1, 1, 1000))]) == UNRESOLVED
        assert combine([Comparison("x", verdict=EXCLUDED)]) == UNRESOLVED
        assert combine([]) == NOT_RUN

    def test_threshold_and_direction(self):
        assert combine([comparison(np.linspace(1.5, 3, 100), +1, 1.0)]) == SUPPORTED
        assert combine([comparison(np.linspace(0.2, 0.8, 100), +1, 1.0)]) == CONTRADICTED
        assert combine([comparison(np.linspace(0.5, 1.5, 100), +1, 1.0)]) == UNRESOLVED


class TestPairwise:
    def test_clear_win(self, tmp_path):
        c = claim_ab(Repro(tmp_path), 5.0, 20.0)
        assert c.verdict == SUPPORTED
        (comp,) = c.comparisons
        assert comp.hi < 0 and comp.lo < comp.diff < comp.hi
        assert re.search(
            r"standard/test δφ: -1\d\.\d\d \[-\d+\.\d\d, -\d+\.\d\d\]° ✓", c.difference
        )

    def test_clear_loss(self, tmp_path):
        assert claim_ab(Repro(tmp_path), 20.0, 5.0).verdict == CONTRADICTED

    def test_tie_is_no_practical_difference(self, tmp_path):
        """Equal errors on 60 frames: the 90% interval lies inside the 2° margin (issue 38)."""
        c = claim_ab(Repro(tmp_path), 10.0, 10.0)
        assert c.verdict == NO_DIFFERENCE
        (comp,) = c.comparisons
        assert comp.verdict == EQUIVALENT and comp.lo < 0 < comp.hi
        assert re.search(r"\(90% \[[-+]\d\.\d\d, [-+]\d\.\d\d\] inside ±2°\) ≈", c.difference)

    def test_noisy_tie_is_not_resolved(self, tmp_path):
        """Equal but noisy errors: the interval is wider than the margin, so neither a win nor
        a tie is shown."""
        c = claim_ab(Repro(tmp_path), 60.0, 60.0)
        assert c.verdict == UNRESOLVED
        (comp,) = c.comparisons
        assert comp.verdict == UNRESOLVED and comp.lo < -2 and comp.hi > 2

    def test_head_at_constant_level_is_excluded(self, tmp_path):
        c = claim_ab(Repro(tmp_path), 5.0, "constant")
        assert c.verdict == UNRESOLVED
        assert c.comparisons[0].verdict == EXCLUDED
        assert len(c.excluded) == 1 and c.excluded[0].startswith(
            "B on standard/test (δφ − constant"
        )
        assert "too few flights): B on standard/test (δφ − constant" in c.evidence
        assert c.difference == ""

    def test_too_few_flights_give_no_verdict(self, tmp_path):
        """Four flights: however clear the difference, no verdict and no participation."""
        repro = Repro(tmp_path, splits={**SPLITS, STD: (4, 5)})
        c = claim_ab(repro, 5.0, 20.0)
        assert c.verdict == UNRESOLVED and c.comparisons[0].verdict == EXCLUDED
        assert c.excluded[0].endswith("; 4 flight(s))")
        ev = Evidence(repro.store())
        low = ev.paired("x", ev.values(("table1", "A", None), STD, "dphi_deg"),
                        ev.values(("table1", "B", None), STD, "dphi_deg"))  # fmt: skip
        assert low.hi < 0 and low.n_flights == 4 and combine([low]) == UNRESOLVED
        assert "(4 flight(s)) ~" in low.text()

    def test_seed_pooling(self, tmp_path):
        """One of three seeds failed (45 deg): seed 0 alone wins clearly, the pooled interval
        over seeds does not."""

        def unstable(seed, n):
            return np.full(n, 45.0 if seed == 1 else 5.0) + np.random.default_rng(seed).gamma(
                2, 1, n
            )

        repro = Repro(tmp_path)
        repro.add("table1", "A", {STD: unstable})
        repro.add("table1", "B", {STD: 20.0})
        ev = Evidence(repro.store())
        pooled = pairwise_claim(ev, "A beats B", "t", "table1", "A", "B", ["dphi_deg"])
        assert pooled.verdict == UNRESOLVED
        one = Repro(tmp_path / "one")
        one.add("table1", "A", {STD: unstable}, seeds=(0,))
        one.add("table1", "B", {STD: 20.0}, seeds=(0,))
        single = pairwise_claim(Evidence(one.store()), "A", "t", "table1", "A", "B", ["dphi_deg"])
        assert single.verdict == SUPPORTED
        assert pooled.comparisons[0].hi - pooled.comparisons[0].lo > 3 * (
            single.comparisons[0].hi - single.comparisons[0].lo
        )

    def test_heads_on_one_frozen_encoder_pair_their_seeds(self, tmp_path):
        """Two heads on each seed's shared encoder: the encoder's seed effect (here 0, +30 and
        -30 deg on every frame) is the same for both and cancels, so B's 1 deg advantage is
        clear; two end-to-end models with the same errors share nothing, and the seeds' spread
        leaves the comparison open."""
        offsets = {0: 0.0, 1: 30.0, 2: -30.0}

        def head(extra):
            def err(seed, n):
                rng = np.random.default_rng(seed)
                return 40.0 + offsets[seed] + extra + rng.normal(0, 0.2, n)

            return err

        shared = Repro(tmp_path / "shared")
        shared.add("table1", "A", {STD: head(1.0)}, encoder="enc")
        shared.add("table1", "B", {STD: head(0.0)}, encoder="enc")
        ev = Evidence(shared.store())
        a, b = (ev.values(("table1", m, None), STD, "dphi_deg") for m in "AB")
        assert shares_seed_runs(a, b)
        c = ev.paired("A − B", a, b, claimed=+1)
        ref = pooled_bootstrap(b.values, a.values, a.flight, N_BOOT, seed=0, paired_seeds=True)
        assert (c.diff, c.lo, c.hi) == pytest.approx(ref, rel=1e-12)
        assert 0.5 < c.lo < c.diff < c.hi < 1.5 and combine([c]) == SUPPORTED
        apart = Repro(tmp_path / "apart")
        apart.add("table1", "A", {STD: head(1.0)})
        apart.add("table1", "B", {STD: head(0.0)})
        ev = Evidence(apart.store())
        a, b = (ev.values(("table1", m, None), STD, "dphi_deg") for m in "AB")
        assert not shares_seed_runs(a, b)
        c = ev.paired("A − B", a, b, claimed=+1)
        assert c.lo < 0 < c.hi and combine([c]) == UNRESOLVED

    def test_every_metric_must_hold(self, tmp_path):
        c = claim_ab(Repro(tmp_path), 5.0, 20.0, metrics=("dphi_deg", "dE_m", "dN_m"))
        assert c.verdict == SUPPORTED and len(c.comparisons) == 3
        assert "m ✓" in c.difference


class TestPaperClaims:
    def test_sanity_claim_flags_a_head_at_constant_level(self, tmp_path):
        repro = Repro(tmp_path)
        repro.add("table1", "Pd/Re-Net", {STD: 5.0})
        repro.add("table1", "Pd-Net-E", {STD: "constant"})
        repro.add("table1", "UAV-only control", {STD: "constant"}, blank=True)
        c = constant_claim(Evidence(repro.store()))
        # A head at the constant's level (its difference tight around 0) is equivalent to it:
        # the sanity bar fails as "no practical difference" (issue 38's rule).
        assert c.verdict == NO_DIFFERENCE
        assert [x.where for x in c.comparisons] == ["Pd/Re-Net", "Pd-Net-E"]
        assert [x.verdict for x in c.comparisons] == [SUPPORTED, EQUIVALENT]

    def test_translation_regression_more_accurate(self, tmp_path):
        repro = Repro(tmp_path)
        repro.add("table3", "Pd/Re-Net", {STD: 5.0})
        repro.add("table3", "Re-Net-T", {STD: 25.0})
        assert translation_claim(Evidence(repro.store())).verdict == SUPPORTED

    def test_kappa_ten_best(self, tmp_path):
        repro = Repro(tmp_path)
        for x, err in (("1", 20.0), ("10", 5.0), ("50", 15.0)):
            repro.add("fig7", "Pd/Re-Net", {STD: err, GEN: err}, x=x)
        c = kappa_claim(Evidence(repro.store()))
        assert c.verdict == SUPPORTED and len(c.comparisons) == 4

    def test_uncertainty(self, tmp_path):
        repro = Repro(tmp_path)
        repro.add("table1", "Pd/Re-Net", {STD: 8.0}, uncertainty=1.0)
        repro.add("table2", "Pd/Re-Net", {GEN: 8.0}, uncertainty=-1.0)
        c = uncertainty_claim(Evidence(repro.store()))
        assert [x.verdict for x in c.comparisons] == [SUPPORTED, CONTRADICTED]
        assert c.verdict == CONTRADICTED
        assert c.comparisons[0].diff > 0.5 and c.comparisons[1].diff < -0.5

    def test_uncertainty_needs_a_head_that_beats_the_constant(self, tmp_path):
        repro = Repro(tmp_path)
        repro.add("table1", "Pd/Re-Net", {STD: "constant"})
        c = uncertainty_claim(Evidence(repro.store()))
        assert c.verdict == UNRESOLVED and "Pd/Re-Net on standard/test" in c.excluded[0]


class TestFamiliesFromTheRegistry:
    """Claim 2 reads head families from the registry, not from display labels."""

    def test_head_family_follows_the_class_attributes(self, monkeypatch):
        from benchmark.models import AttitudeHead, list_heads, register_head
        from benchmark.models import registry as registry_module

        assert head_family("pd_re_net") == "distribution"
        assert head_family("pd_net_q_sym") == "distribution"
        assert head_family("re_net_r") == "regression"
        list_heads()
        monkeypatch.setattr(registry_module, "_HEADS", dict(registry_module._HEADS))

        @register_head("test_density_only")
        class DensityOnly(AttitudeHead):  # a density that is not a grid distribution
            gives_log_prob = True

        assert not DensityOnly.is_probabilistic
        assert head_family("test_density_only") == "distribution"
        with pytest.raises(ValueError, match="pd_re_net"):
            head_family("no_such_head")

    def test_every_registered_head_has_a_family_matching_its_contract(self):
        from benchmark.models import get_head_class, list_heads

        for name in list_heads("attitude"):
            cls = get_head_class(name)
            density = cls.is_probabilistic or cls.gives_log_prob
            assert head_family(name) == ("distribution" if density else "regression"), name

    def test_representation_claim_takes_new_heads_by_family(self, tmp_path):
        """Rows with labels the claim has never heard of join the family their registry class
        declares: a worse distribution head (Pd-Net-Q Sym, label unknown to the claim) is
        compared with Pd/Re-Net, a worse regression head with Re-Net-R, and no cross-family
        comparison is made."""
        repro = Repro(tmp_path)
        add_head(repro, "table1", "Pd/Re-Net", "pd_re_net", {STD: 5.0})
        add_head(repro, "table1", "Quaternion sym.", "pd_net_q_sym", {STD: 20.0})
        add_head(repro, "table1", "Re-Net-R", "re_net_r", {STD: 6.0})
        add_head(repro, "table1", "Rotation vector", "re_net_rv", {STD: 25.0})
        add_head(repro, "table1", "Control", "pd_re_net", {STD: "constant"}, blank=True)
        c = representation_claim(Evidence(repro.store()))
        assert [x.where for x in c.comparisons] == [
            "standard/test vs Quaternion sym.",
            "standard/test vs Rotation vector",
        ]
        assert c.verdict == SUPPORTED and all(x.diff < -10 for x in c.comparisons)
        assert "registry" in c.rule

    def test_representation_claim_relabelled_heads(self, tmp_path):
        """The matrix heads are found by registry name whatever their label; a head of the
        other family is not compared."""
        repro = Repro(tmp_path)
        add_head(repro, "table2", "Matrix (dist.)", "pd_re_net", {GEN: 20.0})
        add_head(repro, "table2", "Euler (dist.)", "pd_net_e", {GEN: 5.0})
        add_head(repro, "table2", "Euler (regr.)", "re_net_e", {GEN: 5.0})
        c = representation_claim(Evidence(repro.store()))
        assert [x.where for x in c.comparisons] == ["generalized/test vs Euler (dist.)"]
        assert c.verdict == CONTRADICTED


class TestSatelliteClaims:
    def test_uses_and_does_not_use(self, tmp_path):
        repro = Repro(tmp_path)
        repro.add("table1", "Pd/Re-Net", {STD: 5.0}, swap={STD: 40.0})
        ev = Evidence(repro.store())
        assert satellite_claim(ev, "table1", STD).verdict == SUPPORTED
        repro.add("table1", "Re-Net-R", {STD: 5.0})  # same predictions with the swapped image
        c = satellite_claim(Evidence(repro.store()), "table1", STD)
        assert c.verdict == CONTRADICTED
        rise = [x for x in c.comparisons if x.where.startswith("Re-Net-R")]
        assert [(x.diff, x.lo, x.hi) for x in rise] == [(0.0, 0.0, 0.0)] * 2

    def test_control(self, tmp_path):
        repro = Repro(tmp_path)
        repro.add("table2", "UAV-only control", {GEN: "constant"}, blank=True)
        assert control_claim(Evidence(repro.store())).verdict == SUPPORTED
        learns = Repro(tmp_path / "learns")
        learns.add("table2", "UAV-only control", {GEN: 5.0}, blank=True)
        assert control_claim(Evidence(learns.store())).verdict == CONTRADICTED


class TestEvaluateAndRender:
    def test_all_claims_and_table(self, tmp_path):
        repro = Repro(tmp_path)
        repro.add("table1", "Pd/Re-Net", {STD: 5.0}, swap={STD: 30.0})
        repro.add("table1", "Re-Net-R", {STD: 20.0})
        claims = evaluate_claims({}, repro.store())
        assert len(claims) == 15  # no extended table planned: no ranking claims
        assert claims[2].verdict == SUPPORTED  # distribution beats regression (where it learns)
        assert {claims[i].verdict for i in (3, 4, 5, 6, 7, 8)} == {NOT_RUN}
        text = render_claims(claims)
        lines = text.splitlines()
        assert lines[0] == (
            "| # | claim | source | paired difference [95% interval] | rule | verdict "
            "| confirmation draw (`confirm/*`): verdict, paired difference | evidence |"
        )
        rows = [line for line in lines if re.match(r"\| \d+ \|", line)]
        assert len(rows) == 15 and all(row.count(" | ") == 7 for row in rows)
        assert "Bonferroni" in text

    def test_missing_file_named_in_the_claim(self, tmp_path):
        repro = Repro(tmp_path)
        repro.add("table1", "Pd/Re-Net", {STD: 5.0})
        repro.add("table1", "Re-Net-R", {STD: 20.0})
        path = repro.workdir / "units" / "table1-Re-Net-R-None-1" / "eval" / "standard__test.csv"
        path.unlink()
        claims = evaluate_claims({}, repro.store())
        assert claims[2].verdict == NOT_RUN and str(path) in claims[2].evidence
