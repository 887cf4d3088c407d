"""Every claim decided again on the confirmation draw (issue 38): the same models read on
``confirm/*`` frames, both verdicts side by side in the claims table, and the findings counting a
claim as settled only where the two agree."""

from __future__ import annotations

import numpy as np
import pytest
from test_frames import SPLITS, Repro

from benchmark.runner.claims.all_claims import evaluate_claims, render_claims
from benchmark.runner.claims.evidence import (
    CONTRADICTED,
    NOT_RUN,
    SUPPORTED,
    Evidence,
)
from benchmark.runner.claims.findings import findings_markdown
from benchmark.runner.claims.paper import pairwise_claim
from benchmark.sim import CONFIRMS

STD, GEN = "standard/test", "generalized/test"
CONFIRM_SPLITS = {**SPLITS, "confirm/standard": (12, 5), "confirm/generalized": (10, 5)}


def add_with_confirmation(repro: Repro, table: str, label: str, main: dict, confirm: dict):
    """A model evaluated on its test splits (``main``: split -> error) and, by the same units,
    on their confirmation splits (``confirm``: test split -> error on its confirmation split)."""
    first = len(repro.units)
    repro.add(table, label, main)
    for unit in repro.units[first:]:
        for split, spec in confirm.items():
            for satellite in ("true", "swap"):
                repro.write(unit.key, CONFIRMS[split], "true", spec, unit.cfg.seed,
                            "standard/train", False, 0.0, satellite)  # fmt: skip


@pytest.fixture
def repro(tmp_path):
    return Repro(tmp_path, splits=CONFIRM_SPLITS)


class TestConfirmationStore:
    def test_reads_the_confirmation_frames_of_the_same_units(self, repro):
        add_with_confirmation(repro, "table1", "A", {STD: 5.0, GEN: 5.0}, {STD: 40.0})
        store = repro.store()
        confirm = store.confirmation(CONFIRMS)
        main = store.errors("table1", "A", STD, "dphi_deg")
        again = confirm.errors("table1", "A", STD, "dphi_deg")
        assert again.values.shape[1] == main.values.shape[1]  # same size, other frames
        assert again.values.mean() > 4 * main.values.mean()
        assert main.seeds == again.seeds and main.trained_from == again.trained_from
        flights = set(repro.labels["confirm/standard"]["flight"])
        assert set(again.flight) == flights

    def test_a_split_without_confirmation_files_is_not_evaluated(self, repro):
        add_with_confirmation(repro, "table1", "A", {STD: 5.0, GEN: 5.0}, {STD: 5.0})
        confirm = repro.store().confirmation(CONFIRMS)
        assert confirm.splits("table1", "A") == [STD]
        assert confirm.has("table1", "A", STD) and not confirm.has("table1", "A", GEN)
        assert confirm.labels("table1", GEN) == []
        with pytest.raises(KeyError, match="not evaluated on 'generalized/test'"):
            confirm.errors("table1", "A", GEN, "dphi_deg")

    def test_constant_predictor_on_the_confirmation_labels(self, repro):
        add_with_confirmation(repro, "table1", "A", {STD: 5.0}, {STD: 5.0})
        store = repro.store()
        confirm = store.confirmation(CONFIRMS)
        a = store.constant(STD, "dphi_deg", "standard/train")
        b = confirm.constant(STD, "dphi_deg", "standard/train")
        assert set(b.flight) == set(repro.labels["confirm/standard"]["flight"])
        assert not np.array_equal(a.values, b.values)
        # the main store's cache is not served to the confirmation store, nor the other way
        assert np.array_equal(store.constant(STD, "dphi_deg", "standard/train").values, a.values)


class TestClaimsOnBothDraws:
    def _claims(self, repro, confirm_error):
        add_with_confirmation(repro, "table1", "Pd/Re-Net", {STD: 5.0}, {STD: confirm_error})
        add_with_confirmation(repro, "table1", "Re-Net-R", {STD: 20.0}, {STD: 20.0})
        return evaluate_claims({}, repro.store(), CONFIRMS)

    def test_same_verdict_is_settled(self, repro):
        claims = self._claims(repro, 5.0)
        number, c = next(
            (i, c) for i, c in enumerate(claims, 1) if c.claim.startswith("For the rotation")
        )
        assert c.confirmation is not None and c.confirmation.verdict == c.verdict
        assert [x.where.split()[0] for x in c.confirmation.comparisons] == [STD] * 4
        settled = next(x for x in findings_markdown(claims).splitlines() if "Confirmation" in x)
        assert f"claim {number} ({c.verdict})" in settled

    def test_disagreement_is_listed_with_both_verdicts(self, repro):
        claims = self._claims(repro, 40.0)  # the distribution head loses on the new frames
        number, c = next(
            (i, c) for i, c in enumerate(claims, 1) if c.claim.startswith("For the rotation")
        )
        assert c.verdict != c.confirmation.verdict
        assert c.confirmation.verdict == CONTRADICTED
        text = findings_markdown(claims)
        assert f"claim {number} (main **{c.verdict}**, confirmation **{CONTRADICTED}**)" in text

    def test_claims_without_confirmation_splits_read_not_run_there(self, repro):
        claims = self._claims(repro, 5.0)
        fig5 = next(c for c in claims if "satellite height" in c.claim)
        assert fig5.confirmation.verdict == NOT_RUN
        table = render_claims(claims)
        assert "confirmation draw (`confirm/*`)" in table.splitlines()[0]
        assert "– (no confirmation split for its test splits)" in table

    def test_confirmation_column_prints_the_verdict_and_differences(self, repro):
        claims = self._claims(repro, 5.0)
        c = next(c for c in claims if c.claim.startswith("For the rotation matrix"))
        row = next(line for line in render_claims(claims).splitlines() if c.claim in line)
        cells = [x.strip() for x in row.split(" | ")]
        assert cells[5] == f"**{c.verdict}**"
        assert cells[6] == f"**{c.confirmation.verdict}**<br>{c.confirmation.difference}"
        assert c.confirmation.difference.startswith("standard/test δ")


class TestRankingPair:
    def test_confirmation_tests_the_pair_ranked_on_the_main_split(self, repro):
        """The main winner A and runner-up B are compared on the new frames, even where the
        new frames rank another head first."""
        add_with_confirmation(repro, "extended", "A", {STD: 5.0}, {STD: 12.0})
        add_with_confirmation(repro, "extended", "B", {STD: 12.0}, {STD: 5.0})
        add_with_confirmation(repro, "extended", "C", {STD: 30.0}, {STD: 3.0})
        claims = evaluate_claims({}, repro.store(), CONFIRMS)
        rank = next(c for c in claims if c.kind == "ranking")
        assert (rank.facts["winner"], rank.facts["runner_up"]) == ("A", "B")
        assert rank.verdict == SUPPORTED
        again = rank.confirmation
        assert (again.facts["winner"], again.facts["runner_up"]) == ("A", "B")
        assert again.verdict == CONTRADICTED


def test_pairwise_claim_reads_only_confirmation_frames(repro):
    """The claim code is unchanged: a pairwise claim on the confirmation store compares the
    models on confirm/standard."""
    add_with_confirmation(repro, "table1", "A", {STD: 20.0}, {STD: 5.0})
    add_with_confirmation(repro, "table1", "B", {STD: 5.0}, {STD: 20.0})
    ev = Evidence(repro.store().confirmation(CONFIRMS))
    c = pairwise_claim(ev, "A beats B", "t", "table1", "A", "B", ["dphi_deg"])
    assert c.verdict == SUPPORTED
