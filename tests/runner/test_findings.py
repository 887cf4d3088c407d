"""The findings text is generated from the claims: its verdicts and numbers are the table's."""

from __future__ import annotations

import re

import numpy as np
from test_claims import add_head
from test_frames import Repro

from benchmark.runner.claims.all_claims import evaluate_claims, render_claims
from benchmark.runner.claims.evidence import (
    CONTRADICTED,
    EXCLUDED,
    NOT_RUN,
    SUPPORTED,
    UNRESOLVED,
    Claim,
    Comparison,
)
from benchmark.runner.claims.findings import findings_markdown, satellite_sentence

STD, GEN = "standard/test", "generalized/test"


def comp(where, diff, verdict, unit="°"):
    return Comparison(where, diff, diff - 1, diff + 1, verdict=verdict, unit=unit,
                      replicates=np.array([diff]))  # fmt: skip


def sat_claim(comps, verdict, excluded=()):
    return Claim("uses it", "swap", verdict, "", comparisons=comps, excluded=list(excluded),
                 kind="satellite", split=STD)  # fmt: skip


class TestSatelliteSentence:
    def test_no_head_uses_it(self):
        c = sat_claim([comp("Pd/Re-Net δψ", 0.1, CONTRADICTED), comp("Pd/Re-Net δφ", 0.2,
                       CONTRADICTED)], CONTRADICTED)  # fmt: skip
        assert satellite_sentence(11, c) == (
            "No head uses the satellite image on `standard/test` (claim 11: Pd/Re-Net δψ: "
            "+0.10 [-0.90, +1.10]° ✗; Pd/Re-Net δφ: +0.20 [-0.80, +1.20]° ✗)."
        )

    def test_mixed_heads_and_exclusions(self):
        c = sat_claim(
            [comp("A δψ", 9.0, SUPPORTED), comp("A δφ", 9.0, SUPPORTED),
             comp("B δψ", 0.0, CONTRADICTED), comp("B δφ", 3.0, SUPPORTED),
             comp("C δψ", 0.5, UNRESOLVED), comp("C δφ", 2.0, SUPPORTED),
             Comparison("D δψ", verdict=EXCLUDED), Comparison("D δφ", verdict=EXCLUDED)],
            CONTRADICTED,
        )  # fmt: skip
        text = satellite_sentence(12, c)
        assert text.startswith("On `standard/test`: A use(s) it; B do(es) not use it; C is/are ")
        assert "D" not in text.split("(claim")[0]

    def test_nobody_tested(self):
        c = sat_claim(
            [Comparison("D δψ", verdict=EXCLUDED)], UNRESOLVED, ["D on standard/test (x)"]
        )
        assert satellite_sentence(13, c) == (
            "On `standard/test` no head is tested for using the satellite image: a head does not "
            "beat the constant predictor (claim 13)."
        )
        c.excluded = ["D on standard/test (δψ − constant -9.00 [-9.10, -8.90]°; 1 flight(s))"]
        assert "too few flights for a flight bootstrap (claim 13)" in satellite_sentence(13, c)
        assert satellite_sentence(13, Claim("x", "y", NOT_RUN, "", kind="satellite")) is None


class TestFindings:
    def test_counts_and_groups(self):
        claims = [
            Claim("A beats B", "t", SUPPORTED, "", comparisons=[comp("s", -3.0, SUPPORTED),
                  comp("g", -5.0, SUPPORTED)]),
            Claim("C beats D", "t", CONTRADICTED, "", comparisons=[comp("s", 4.0, CONTRADICTED)]),
            Claim("E beats F", "t", UNRESOLVED, "", comparisons=[Comparison("s", verdict=EXCLUDED)],
                  excluded=["F on standard/test (δφ − constant +0.01 [-0.05, +0.06]°)"]),
            Claim("G", "t", NOT_RUN, "not run"),
        ]  # fmt: skip
        text = findings_markdown(claims)
        lines = text.splitlines()
        assert lines[0] == (
            "Of 4 claims checked: 1 supported, 1 contradicted, 1 not resolved at this scale, "
            "1 not run (on the main test splits)."
        )
        assert (
            "- **supported**: claim 1 (A beats B: 2 of 2 comparisons supported, Δ from -5.00 "
            "to -3.00°)" in text
        )
        assert (
            "- **contradicted**: claim 2 (C beats D: contradicted by s: +4.00 [+3.00, +5.00]° ✗)"
            in text
        )
        assert "claim 3 (E beats F: no comparison takes part" in text
        assert "- **not run**: claim 4." in text
        assert lines[-1] == (
            "- Left out of the comparisons for not beating the constant predictor (or too few "
            "flights), see the claims table: F on standard/test (δφ)."
        )

    def test_generated_numbers_are_the_tables(self, tmp_path):
        """Every number in the findings is printed in the claims table, every verdict counted."""
        repro = Repro(tmp_path)
        add_head(repro, "table1", "Pd/Re-Net", "pd_re_net", {STD: 5.0}, swap={STD: 30.0})
        add_head(repro, "table1", "Re-Net-R", "re_net_r", {STD: 20.0})
        add_head(repro, "table1", "Pd-Net-E", "pd_net_e", {STD: "constant"})
        add_head(repro, "table2", "Pd/Re-Net", "pd_re_net", {GEN: 6.0}, uncertainty=1.0)
        add_head(repro, "table2", "Re-Net-R", "re_net_r", {GEN: 6.0})
        claims = evaluate_claims({}, repro.store())
        text, table = findings_markdown(claims), render_claims(claims)
        numbers = re.findall(r"[+-]\d+\.\d\d", text)
        assert numbers and all(n in table for n in numbers)
        for verdict in (CONTRADICTED, UNRESOLVED, NOT_RUN):
            assert f"{sum(c.verdict == verdict for c in claims)} {verdict}" in text.splitlines()[0]
        assert "On `standard/test`: Pd/Re-Net use(s) it; Re-Net-R do(es) not use it" in text
        assert "Pd-Net-E on standard/test (δφ, δψ)" in text.splitlines()[-1]
