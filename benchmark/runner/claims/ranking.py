"""Which representation wins a beyond-the-paper comparison table (``extended``), per test split.

On each test split of a ranked table, the heads that beat the constant (training-mean) predictor on
the geodesic error δφ take part (the participation rule of ``benchmark.runner.claims.evidence``);
the winner and the runner-up are the two with the lowest mean δφ (mean over seeds and frames). The
claim "the winner beats the runner-up" is decided on their paired per-frame difference
``Δ = δφ(winner) − δφ(runner-up)`` with the interval of the bootstrap over flights and seeds:
equivalent (no practical difference, so the claim is contradicted) when its 90% interval lies
inside the δφ equivalence margin, supported (the win is beyond the seed and flight spread) when
the 95% interval lies below zero, not resolved otherwise, and never resolved on a split with fewer
than ``MIN_FLIGHTS`` flights (no interval, no verdict). On the confirmation draw the pair is the
one the main split ranked (``pair``): the confirmation tests that hypothesis on new frames.
Without two participating heads there is no comparison: the summary
then says which one head beats the constant, or that none does.

:func:`ranking_sentence` writes the summary from the claim's numbers only; the findings and the
table's own section print it verbatim.
"""

from __future__ import annotations

from benchmark.evaluation.paired import percentile_interval
from benchmark.runner.claims.evidence import (
    EQUIVALENCE_CONFIDENCE,
    EQUIVALENT,
    EXCLUDED,
    MIN_FLIGHTS,
    NOT_RUN,
    SUPPORTED,
    UNRESOLVED,
    Claim,
    Comparison,
    Evidence,
    build_claim,
    safe_claim,
)

RANKED_TABLES = ("extended",)  # beyond-the-paper tables whose winner the findings report
RANK_METRIC = "dphi_deg"


def ranking_claim(
    ev: Evidence, table: str, split: str, pair: tuple[str | None, str | None] | None = None
) -> Claim:
    """The head with the lowest mean δφ on ``split`` beats the runner-up (see module docstring);
    ``pair``: (winner, runner-up) ranked elsewhere (the main split, for the confirmation draw),
    compared here whatever this split's means say.

    ``facts`` hold ``table``, ``metric``, ``means`` (label -> mean δφ in deg, every trained head,
    in plan order), ``constant`` (the constant predictor's mean δφ), ``participants`` (labels that
    beat the constant predictor, best first), ``winner`` and ``runner_up`` (labels or None) and
    ``n_flights`` (flights of the split)."""
    claim = (
        f"The representation with the lowest δφ on `{split}` (table {table}) beats the runner-up "
        "beyond the seed and flight spread"
    )
    source = f"{table}, geodesic error δφ (deg), heads that beat the constant predictor"

    def build() -> Claim:
        labels = ev.frames.labels(table, split, control=False)
        if not labels:
            return Claim(claim, source, NOT_RUN, f"{table} on {split} not run")
        models = {label: (table, label, None) for label in labels}
        means = {
            label: float(ev.values(m, split, RANK_METRIC).values.mean())
            for label, m in models.items()
        }
        constant = float(ev.constant(models[labels[0]], split, RANK_METRIC).values.mean())
        excluded: list[str] = []
        participants = []
        for label, model in models.items():
            reason = ev.exclusion(model, split, RANK_METRIC)
            if reason is None:
                participants.append(label)
            else:
                excluded.append(reason)
        participants.sort(key=lambda label: means[label])
        flights = ev.beats_constant(models[labels[0]], split, RANK_METRIC).n_flights
        winner = participants[0] if participants else None
        runner_up = participants[1] if len(participants) > 1 else None
        if pair is not None:  # a head not evaluated here takes no part
            winner, runner_up = (label if label in models else None for label in pair)
        comps: list[Comparison | None] = []
        if runner_up is not None:
            comps.append(
                ev.compare(
                    f"{split} {winner} vs {runner_up}",
                    models[winner],
                    models[runner_up],
                    split,
                    RANK_METRIC,
                    excluded,
                )
            )
        elif labels:
            comps.append(Comparison(f"{split} ranking", verdict=EXCLUDED))
        rule = (
            "winner, runner-up: the two lowest mean δφ among the heads that beat the constant "
            "predictor; Δ = δφ(winner) − δφ(runner-up); claimed Δ < 0"
        )
        listed = ", ".join(f"{label} {means[label]:.2f}°" for label in labels)
        notes = [f"mean δφ: {listed}; constant predictor {constant:.2f}°"]
        out = build_claim(claim, source, rule, comps, excluded, notes)
        if len(participants) == 1:  # not "no comparison takes part" (build_claim's default)
            out.evidence = out.evidence.replace(
                out.evidence.split("; ", 1)[0],
                f"{winner} is the only head that beats the constant predictor",
                1,
            )
        out.facts = {
            "table": table, "metric": RANK_METRIC, "means": means, "constant": constant,
            "participants": participants, "winner": winner, "runner_up": runner_up,
            "n_flights": flights,
        }  # fmt: skip
        return out

    out = safe_claim(build, claim, source)
    out.kind, out.split = "ranking", split
    return out


def ranking_claims(
    ev: Evidence, pairs: dict[tuple[str, str], tuple[str | None, str | None]] | None = None
) -> list[Claim]:
    """One :func:`ranking_claim` per (ranked table, test split planned for it); ``pairs``:
    (table, split) -> (winner, runner-up) ranked on the main splits, to be tested again here."""
    out = []
    for table in RANKED_TABLES:
        splits: dict[str, None] = {}
        for label in ev.frames.labels(table, control=False):
            splits.update(dict.fromkeys(ev.frames.splits(table, label)))
        out += [
            ranking_claim(ev, table, split, None if pairs is None else pairs.get((table, split)))
            for split in splits
        ]
    return out


def ranked_pairs(claims: list[Claim]) -> dict[tuple[str, str], tuple[str | None, str | None]]:
    """(table, split) -> (winner, runner-up) of each ranking claim that ranked two heads."""
    return {
        (str(c.facts["table"]), c.split): (c.facts["winner"], c.facts["runner_up"])  # type: ignore[misc]
        for c in claims
        if c.kind == "ranking" and c.facts.get("runner_up") is not None
    }


def ranking_sentence(number: int, c: Claim) -> str | None:
    """The summary of one ranking claim (None for other claims and ranking claims not run)."""
    if c.kind != "ranking" or c.verdict == NOT_RUN or not c.facts:
        return None
    f = c.facts
    means: dict[str, float] = f["means"]  # type: ignore[assignment]
    table, split, const = f["table"], f"`{c.split}`", f["constant"]
    winner, runner = f["winner"], f["runner_up"]
    if winner is None:
        best = min(means, key=means.__getitem__)
        lowest = f"lowest mean δφ: {best} {means[best]:.2f}°, constant {const:.2f}°"
        flights = f["n_flights"]
        if isinstance(flights, int) and flights < MIN_FLIGHTS:
            return (
                f"On {split} no head of table {table} is ranked: its {flights} flight(s) are too "
                f"few for a flight bootstrap (at least {MIN_FLIGHTS}), so no verdict ({lowest}; "
                f"claim {number})."
            )
        return (
            f"On {split} no head of table {table} beats the constant predictor on δφ, so no "
            f"representation wins ({lowest}; claim {number})."
        )
    head = f"On {split} (table {table}), {winner} has the lowest mean δφ, {means[winner]:.2f}°"
    if runner is None:
        return (
            f"{head} (constant predictor {const:.2f}°), and it is the only head that beats the "
            f"constant predictor: no runner-up to compare with (claim {number})."
        )
    comp = next(x for x in c.comparisons if x.verdict != EXCLUDED)
    numbers = f"Δ {comp.diff:+.2f} [{comp.lo:+.2f}, {comp.hi:+.2f}]°"
    head += f", against {means[runner]:.2f}° for the runner-up {runner}: {numbers}"
    if comp.too_few_flights:
        verdict = f"no verdict ({comp.n_flights} flight(s), fewer than {MIN_FLIGHTS})"
    elif comp.verdict == SUPPORTED:
        verdict = "the win is beyond the seed and flight spread"
    elif comp.verdict == EQUIVALENT:
        lo, hi = percentile_interval(comp.replicates, EQUIVALENCE_CONFIDENCE)
        verdict = (
            f"equivalent: the 90% interval [{lo:+.2f}, {hi:+.2f}]° lies inside the "
            f"±{comp.margin:g}° margin, so no representation wins (no practical difference)"
        )
    elif comp.verdict == UNRESOLVED:
        verdict = (
            "within the seed and flight spread but not inside the equivalence margin, so "
            "neither a win nor a tie is shown at this scale"
        )
    else:
        verdict = f"{comp.verdict}"
    n = len(f["participants"])  # type: ignore[arg-type]
    return f"{head}; {verdict} ({n} of {len(means)} heads beat the constant; claim {number})."


def ranking_markdown(claims: list[Claim], table: str) -> str:
    """The ranked table's own summary section (``""`` when the table was not ranked): one
    sentence per test split, exactly as in the findings."""
    lines = [
        f"- {s}"
        for i, c in enumerate(claims, 1)
        if c.facts.get("table") == table and (s := ranking_sentence(i, c)) is not None
    ]
    if not lines:
        return ""
    head = (
        "Which representation wins (generated from the paired verdicts of the claims table in "
        "README.md; heads take part only where they beat the constant predictor):"
    )
    return "\n".join(["", "## Which representation wins", "", head, "", *lines]) + "\n"
