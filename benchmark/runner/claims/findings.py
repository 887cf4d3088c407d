"""The findings paragraph of a reproduction, written only from the claim verdicts and their numbers.

Prose written by hand drifts from the numbers it summarises (issue 10); this text is generated
from the :class:`~benchmark.runner.claims.evidence.Claim` objects the claims table is rendered from,
so it says nothing the table does not: verdict counts, which claims hold and which do not (with the
differences and intervals exactly as the table prints them), which heads use the satellite image
on which split, which representation wins each test split of the ``extended`` table
(``benchmark.runner.claims.ranking``), and which heads were left out for not beating the constant
predictor. After a partial rerun that kept tables from an earlier run, one line per earlier run
names those tables and the claims that use them: *from an earlier run at <commit>, not
re-decided* (``benchmark.runner.plan.partial``).
"""

from __future__ import annotations

from collections.abc import Mapping

from benchmark.runner.claims.evidence import (
    CONTRADICTED,
    EQUIVALENT,
    EXCLUDED,
    NO_DIFFERENCE,
    NOT_RUN,
    SUPPORTED,
    UNRESOLVED,
    Claim,
    Comparison,
)
from benchmark.runner.claims.ranking import ranking_sentence
from benchmark.runner.plan.partial import EARLIER, short_commit

ORDER = (SUPPORTED, CONTRADICTED, NO_DIFFERENCE, UNRESOLVED, NOT_RUN, EARLIER)
SENTENCE_KINDS = ("satellite", "ranking")  # claims summarised by a sentence of their own


def _range(comps: list[Comparison]) -> str:
    """``Δ -3.10`` or ``Δ from -14.89 to -7.93°`` over the comparisons (same digits as the
    table)."""
    diffs = sorted(c.diff for c in comps)
    unit = comps[0].unit
    if len(diffs) == 1:
        return f"Δ {diffs[0]:+.2f}{unit}"
    return f"Δ from {diffs[0]:+.2f} to {diffs[-1]:+.2f}{unit}"


def _why_none(c: Claim) -> str:
    """Why no comparison of ``c`` takes part, from its exclusion notes."""
    few = [e for e in c.excluded if e.endswith("flight(s))")]
    if few and len(few) == len(c.excluded):
        return "too few flights for a flight bootstrap"
    if few:
        return "heads do not beat the constant predictor, or too few flights"
    return "a head does not beat the constant predictor"


def _claim_summary(number: int, c: Claim) -> str:
    """``claim 3 (text: why)``: why it holds or not, from its comparisons."""
    active = [x for x in c.comparisons if x.verdict != EXCLUDED]
    if c.verdict == SUPPORTED:
        why = f"{len(active)} of {len(active)} comparisons supported, {_range(active)}"
    elif c.verdict == CONTRADICTED:
        bad = [x for x in active if x.verdict == CONTRADICTED]
        why = "contradicted by " + "; ".join(x.text() for x in bad)
    elif c.verdict == NO_DIFFERENCE:
        ties = [x for x in active if x.verdict == EQUIVALENT]
        why = "no practical difference: " + "; ".join(x.text() for x in ties)
    elif c.verdict == UNRESOLVED and not active:
        why = f"no comparison takes part ({_why_none(c)})"
    elif c.verdict == UNRESOLVED:
        n_sup = sum(x.verdict == SUPPORTED for x in active)
        why = f"{n_sup} of {len(active)} comparisons supported, {_range(active)}"
    else:
        return f"claim {number}"
    return f"claim {number} ({c.claim}: {why})"


def _heads(c: Claim) -> dict[str, str]:
    """Per head of a satellite claim: ``uses``, ``does not use``, ``not resolved`` or
    ``excluded`` (from its δψ and δφ comparisons, named ``"<head> δψ"``)."""
    by_head: dict[str, list[Comparison]] = {}
    for x in c.comparisons:
        by_head.setdefault(x.where.rsplit(" ", 1)[0], []).append(x)
    out = {}
    for head, comps in by_head.items():
        verdicts = {x.verdict for x in comps}
        if verdicts == {EXCLUDED}:
            out[head] = "excluded"
        elif CONTRADICTED in verdicts:
            out[head] = "does not use"
        elif verdicts == {SUPPORTED}:
            out[head] = "uses"
        else:
            out[head] = "not resolved"
    return out


def satellite_sentence(number: int, c: Claim) -> str | None:
    """One sentence per satellite claim that was run."""
    if c.kind != "satellite" or c.verdict == NOT_RUN:
        return None
    heads = _heads(c)
    tested = {h: s for h, s in heads.items() if s != "excluded"}
    split = f"`{c.split}`"
    if not tested:
        return (
            f"On {split} no head is tested for using the satellite image: {_why_none(c)} "
            f"(claim {number})."
        )
    numbers = "; ".join(x.text() for x in c.comparisons if x.verdict != EXCLUDED)
    if set(tested.values()) == {"does not use"}:
        return f"No head uses the satellite image on {split} (claim {number}: {numbers})."
    if set(tested.values()) == {"uses"}:
        return f"Every tested head uses the satellite image on {split} (claim {number}: {numbers})."
    parts = []
    for status in ("uses", "does not use", "not resolved"):
        names = [h for h, s in tested.items() if s == status]
        if names:
            verb = {"uses": "use(s) it", "does not use": "do(es) not use it"}.get(
                status, "is/are not resolved"
            )
            parts.append(f"{', '.join(names)} {verb}")
    return f"On {split}: " + "; ".join(parts) + f" (claim {number}: {numbers})."


def _exclusions(claims: list[Claim], at_most: int = 8) -> list[str]:
    """``"<head> on <split> (<errors>)"`` per excluded head and split, from the claims' exclusion
    notes (``"<head> on <split> (<error> − constant Δ [lo, hi]...)"``); more than ``at_most``
    are counted per head instead (``"<head>: <n> split(s)"``, sweep values dropped)."""
    errors: dict[str, dict[str, None]] = {}
    for c in claims:
        for note in c.excluded:
            head, _, rest = note.partition(" (")
            errors.setdefault(head, {})[rest.split(" − ", 1)[0]] = None
    if len(errors) <= at_most:
        return [f"{head} ({', '.join(e for e in errors[head] if e)})" for head in sorted(errors)]
    per_label: dict[str, int] = {}
    for head in errors:
        label = head.rsplit(" on ", 1)[0].split(" [", 1)[0]
        per_label[label] = per_label.get(label, 0) + 1
    return [f"{label}: {n} split(s)" for label, n in sorted(per_label.items())]


def earlier_lines(claims: list[Claim], earlier: Mapping[str, str]) -> list[str]:
    """One bullet per earlier run (``earlier``: kept table -> git commit of the run that wrote
    it): its tables and the claims (numbered as in the claims table) that use them, which are
    not re-decided."""
    by_commit: dict[str, list[str]] = {}
    for table, commit in sorted(earlier.items()):
        by_commit.setdefault(commit, []).append(table)
    lines = []
    for commit, tables in by_commit.items():
        numbers = [
            str(i)
            for i, c in enumerate(claims, 1)
            if c.verdict == EARLIER and c.facts.get("earlier", ("", ""))[1] == commit
        ]
        if len(numbers) == 1:
            uses = f"claim {numbers[0]} uses them and is not re-decided"
        elif numbers:
            uses = f"claims {', '.join(numbers)} use them and are not re-decided"
        else:
            uses = "no claim uses them"
        names = ", ".join(f"`{t}`" for t in tables)
        lines.append(
            f"- **from an earlier run at `{short_commit(commit)}`, not re-decided**: {names} "
            f"(kept as written by that run, see *Partial rerun*); {uses}."
        )
    return lines


def confirmation_lines(claims: list[Claim]) -> list[str]:
    """What the confirmation draw says of the verdicts (``[]`` when no claim was decided on it):
    which claims are settled (the same verdict on the main and the confirmation splits), which
    disagree (each with both verdicts), and which have no confirmation split."""
    numbered = [(i, c) for i, c in enumerate(claims, 1) if c.verdict != EARLIER]
    if not any(c.confirmation is not None for _, c in numbered):
        return []
    settled, differ, main_only = [], [], []
    for i, c in numbered:
        k = c.confirmation
        if k is None or k.verdict == NOT_RUN:
            main_only.append(str(i))
        elif k.verdict == c.verdict:
            settled.append(f"{i} ({c.verdict})")
        else:
            differ.append(f"claim {i} (main **{c.verdict}**, confirmation **{k.verdict}**)")
    checked = len(settled) + len(differ)
    lines = [
        f"- **Confirmation draw** (`confirm/*`, frames nobody chose anything on): {len(settled)} "
        f"of {checked} claims decided on both are settled, the same verdict on both: "
        + (", ".join(f"claim {x}" for x in settled) if settled else "none")
        + "."
    ]
    if differ:
        lines.append(
            f"- **Not settled** ({len(differ)}: the two draws disagree, so the main verdict "
            "does not stand alone): " + "; ".join(differ) + "."
        )
    if main_only:
        lines.append(
            "- Decided on the main splits only (their splits have no confirmation split): "
            + ", ".join(f"claim {x}" for x in main_only)
            + "."
        )
    return lines


def findings_markdown(claims: list[Claim], earlier: Mapping[str, str] | None = None) -> str:
    """Markdown findings (a counts sentence, then bullets) from the checked claims, numbered as
    in the claims table (1-based, in order). ``earlier`` (table -> git commit) names the tables
    kept from an earlier run; claims with the verdict ``EARLIER`` are listed with them."""
    numbered = list(enumerate(claims, 1))
    counts = {v: sum(c.verdict == v for c in claims) for v in ORDER}
    head = ", ".join(f"{n} {v}" for v, n in counts.items() if n)
    lines = [f"Of {len(claims)} claims checked: {head} (on the main test splits).", ""]
    lines += earlier_lines(claims, earlier or {})
    lines += confirmation_lines(claims)
    for verdict in ORDER[:-1]:  # EARLIER: in the lines above
        group = [
            (i, c)
            for i, c in numbered
            if c.verdict == verdict and (c.kind not in SENTENCE_KINDS or verdict == NOT_RUN)
        ]
        if not group:
            continue
        if verdict == NOT_RUN:
            lines.append(f"- **{verdict}**: " + ", ".join(f"claim {i}" for i, _ in group) + ".")
        else:
            lines.append(f"- **{verdict}**: " + "; ".join(_claim_summary(i, c) for i, c in group))
    for i, c in numbered:
        if c.verdict == EARLIER:
            continue
        sentence = satellite_sentence(i, c) or ranking_sentence(i, c)
        if sentence is not None:
            lines.append(f"- {sentence}")
    excluded = _exclusions(claims)
    if excluded:
        lines.append(
            "- Left out of the comparisons for not beating the constant predictor (or too few "
            "flights), see the claims table: " + "; ".join(excluded) + "."
        )
    return "\n".join(lines) + "\n"
