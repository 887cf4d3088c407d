"""Which representation wins the ``extended`` table: synthetic reproductions (real CSV formats,
3 seeds, 10-12 flights per split, ``test_frames.Repro``) with a clear winner, a tie, no head
above the constant predictor, a single one, and too few flights."""

from __future__ import annotations

import re

import numpy as np
import pandas as pd
import pytest
from test_frames import SPLITS, Repro

from benchmark.runner.claims.all_claims import evaluate_claims, render_claims
from benchmark.runner.claims.evidence import NO_DIFFERENCE, NOT_RUN, SUPPORTED, UNRESOLVED, Evidence
from benchmark.runner.claims.findings import findings_markdown
from benchmark.runner.claims.ranking import (
    ranking_claim,
    ranking_claims,
    ranking_markdown,
    ranking_sentence,
)

STD, GEN = "standard/test", "generalized/test"


def extended(repro: Repro, errors: dict[str, object], split: str = STD) -> Evidence:
    for label, err in errors.items():
        repro.add("extended", label, {split: err})
    return Evidence(repro.store())


class TestRankingClaim:
    def test_clear_winner(self, tmp_path):
        repro = Repro(tmp_path)
        ev = extended(repro, {"A": 15.0, "B": 5.0, "C": 30.0})
        c = ranking_claim(ev, "extended", STD)
        assert c.verdict == SUPPORTED and c.kind == "ranking" and c.split == STD
        assert (c.facts["winner"], c.facts["runner_up"]) == ("B", "A")
        assert c.facts["participants"] == ["B", "A", "C"]
        (comp,) = c.comparisons
        assert comp.where == f"{STD} B vs A" and comp.hi < 0
        # means: every seed's CSV averaged, against pandas on the files themselves
        for label in "ABC":
            units = repro.workdir / "units"
            files = sorted(units.glob(f"extended-{label}-None-*/eval/standard__test.csv"))
            ref = np.mean([pd.read_csv(f)["dphi_deg"].mean() for f in files])
            assert len(files) == 3 and c.facts["means"][label] == pytest.approx(ref, rel=1e-12)
        text = ranking_sentence(16, c)
        assert text.startswith(
            f"On `{STD}` (table extended), B has the lowest mean δφ, "
            f"{c.facts['means']['B']:.2f}°, against {c.facts['means']['A']:.2f}° for the "
            f"runner-up A: Δ {comp.diff:+.2f} [{comp.lo:+.2f}, {comp.hi:+.2f}]°"
        )
        assert "beyond the seed and flight spread (3 of 3 heads beat the constant" in text
        assert text.endswith("claim 16).")

    def test_tie_is_equivalent(self, tmp_path):
        """A tie inside the 2° margin: no representation wins (issue 38)."""
        c = ranking_claim(extended(Repro(tmp_path), {"A": 10.0, "B": 10.0}), "extended", STD)
        assert c.verdict == NO_DIFFERENCE and c.comparisons[0].lo < 0 < c.comparisons[0].hi
        assert re.search(
            r"equivalent: the 90% interval \[[-+]\d\.\d\d, [-+]\d\.\d\d\]° lies inside the ±2° "
            r"margin, so no representation wins \(no practical difference\)",
            ranking_sentence(3, c),
        )

    def test_noisy_tie_is_within_the_spread(self, tmp_path):
        c = ranking_claim(extended(Repro(tmp_path), {"A": 60.0, "B": 60.0}), "extended", STD)
        assert c.verdict == UNRESOLVED and c.comparisons[0].lo < -2 and c.comparisons[0].hi > 2
        assert "within the seed and flight spread but not inside the equivalence margin" in (
            ranking_sentence(3, c)
        )

    def test_no_head_beats_the_constant(self, tmp_path):
        c = ranking_claim(
            extended(Repro(tmp_path), {"A": "constant", "B": "constant"}), "extended", STD
        )
        assert c.verdict == UNRESOLVED and c.facts["winner"] is None
        assert len(c.excluded) == 2 and c.excluded[0].startswith(f"A on {STD} (δφ − constant")
        text = ranking_sentence(4, c)
        assert text.startswith(
            f"On `{STD}` no head of table extended beats the constant predictor on δφ, so no "
            "representation wins (lowest mean δφ: "
        )
        assert f"constant {c.facts['constant']:.2f}°; claim 4)." in text

    def test_a_single_head_beats_the_constant(self, tmp_path):
        c = ranking_claim(extended(Repro(tmp_path), {"A": "constant", "B": 5.0}), "extended", STD)
        assert c.verdict == UNRESOLVED and c.facts["winner"] == "B"
        assert c.evidence.startswith("B is the only head that beats the constant predictor")
        assert "it is the only head that beats the constant predictor: no runner-up" in (
            ranking_sentence(5, c)
        )

    def test_too_few_flights_no_verdict(self, tmp_path):
        """Four flights: the winner may beat the constant at 95%, but a flight bootstrap over
        four flights has no coverage, so nothing takes part and nothing is decided."""
        repro = Repro(tmp_path, splits={**SPLITS, STD: (4, 5)})
        c = ranking_claim(extended(repro, {"A": 5.0, "B": 30.0}), "extended", STD)
        assert c.verdict == UNRESOLVED and c.facts["winner"] is None
        assert all(e.endswith("; 4 flight(s))") for e in c.excluded)
        assert c.facts["n_flights"] == 4
        assert ranking_sentence(6, c).startswith(
            f"On `{STD}` no head of table extended is ranked: its 4 flight(s) are too few for a "
            "flight bootstrap (at least 5), so no verdict (lowest mean δφ: A "
        )

    def test_not_planned(self, tmp_path):
        repro = Repro(tmp_path)
        repro.add("table1", "A", {STD: 5.0})
        ev = Evidence(repro.store())
        assert ranking_claims(ev) == []
        c = ranking_claim(ev, "extended", STD)
        assert c.verdict == NOT_RUN and ranking_sentence(1, c) is None


class TestInReport:
    def test_claims_findings_and_table_section_agree(self, tmp_path):
        repro = Repro(tmp_path)
        for label, std, gen in (("A", 5.0, 9.0), ("B", 15.0, 9.0), ("C", "constant", 30.0)):
            repro.add("extended", label, {STD: std, GEN: gen})
        repro.add("extended", "Control", {STD: 1.0, GEN: 1.0}, blank=True)  # never ranked
        claims = evaluate_claims({}, repro.store())
        ranked = [c for c in claims if c.kind == "ranking"]
        assert len(claims) == 17 and [c.split for c in ranked] == [STD, GEN]
        assert [c.verdict for c in ranked] == [SUPPORTED, NO_DIFFERENCE]  # A and B tie on GEN
        assert all("Control" not in c.facts["means"] for c in ranked)
        findings, table = findings_markdown(claims), render_claims(claims)
        sentences = [ranking_sentence(i, c) for i, c in enumerate(claims, 1) if c in ranked]
        assert all(f"- {s}" in findings for s in sentences)
        assert "claim 16 (The representation" not in findings  # a sentence, not a verdict bullet
        section = ranking_markdown(claims, "extended")
        assert section.startswith("\n## Which representation wins\n")
        assert all(f"- {s}" in section for s in sentences)
        assert ranking_markdown(claims, "table1") == ""
        numbers = re.findall(r"[+-]?\d+\.\d\d", "".join(sentences))
        assert numbers and all(n in table for n in numbers)
