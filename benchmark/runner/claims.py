"""The paper's conclusions, checked one by one against our results.

Each check reads the per-table summaries (mean and 95% interval over seeds) and returns a verdict
with its evidence. A comparison "A beats B" holds when A's mean error is lower; with several seeds
it must also be clear of noise (A's interval entirely below B's) or it counts as "within noise".
A check whose tables were not run says so instead of guessing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import pandas as pd

SUPPORTED, PARTLY, CONTRADICTED = "supported", "partly supported", "contradicted"
NOT_RUN, INCONCLUSIVE = "not run", "inconclusive"


@dataclass
class Claim:
    claim: str
    source: str
    verdict: str
    evidence: str


def _value(
    summary: pd.DataFrame | None,
    label: str,
    split: str,
    metric: str,
    x: str | None = None,
    satellite: str = "true",
):
    """``(mean, lo, hi)`` or None; measured with the true satellite image unless ``satellite``
    says ``swap``."""
    if summary is None or summary.empty or metric not in summary:
        return None
    rows = summary[(summary["label"] == label) & (summary["split"] == split)]
    if "satellite" in rows:
        rows = rows[rows["satellite"] == satellite]
    if x is not None:
        rows = rows[rows["x"].astype(str) == x]
    if rows.empty or not math.isfinite(rows.iloc[0][metric]):
        return None
    r = rows.iloc[0]
    return float(r[metric]), float(r[f"{metric}_lo"]), float(r[f"{metric}_hi"])


def _beats(a, b) -> str:
    """'yes', 'no' or 'noise' for: a has the lower error."""
    if a[0] >= b[0]:
        return "no"
    if math.isfinite(a[2]) and math.isfinite(b[1]) and a[2] >= b[1]:
        return "noise"
    return "yes"


def _verdict(outcomes: list[str]) -> str:
    if not outcomes:
        return NOT_RUN
    if all(o == "yes" for o in outcomes):
        return SUPPORTED
    if any(o == "yes" for o in outcomes):
        return PARTLY
    return CONTRADICTED


def _fmt(v) -> str:
    return f"{v[0]:.2f}" if v is not None else "n/a"


def representation_claim(s: dict[str, pd.DataFrame]) -> Claim:
    families = {
        "distribution": ("Pd/Re-Net", ["Pd-Net-Rv", "Pd-Net-E", "Pd-Net-Q"]),
        "regression": ("Re-Net-R", ["Re-Net-Rv", "Re-Net-E", "Re-Net-Q"]),
    }
    outcomes, notes = [], []
    for table, split in (("table1", "standard/test"), ("table2", "generalized/test")):
        for family, (best, others) in families.items():
            a = _value(s.get(table), best, split, "dphi_deg")
            if a is None:
                continue
            for other in others:
                b = _value(s.get(table), other, split, "dphi_deg")
                if b is not None:
                    outcomes.append(_beats(a, b))
            vals = ", ".join(
                f"{o} {_fmt(_value(s.get(table), o, split, 'dphi_deg'))}" for o in others
            )
            notes.append(f"{split} {family}: {best} {_fmt(a)} vs {vals}")
    return Claim(
        "The rotation matrix beats the other representations (quaternion, rotation vector, Euler)",
        "Tables 1-2, geodesic error δφ (deg)",
        _verdict(outcomes),
        "; ".join(notes) or "tables 1-2 not run",
    )


def _pairwise_claim(
    claim: str, source: str, s: pd.DataFrame | None, a_label: str, b_label: str,
    splits: list[str], metrics: list[str], xs: list[str | None] = (None,),
) -> Claim:  # fmt: skip
    outcomes, notes = [], []
    for split in splits:
        for x in xs:
            parts = []
            for m in metrics:
                a, b = _value(s, a_label, split, m, x), _value(s, b_label, split, m, x)
                if a is None or b is None:
                    continue
                outcomes.append(_beats(a, b))
                parts.append(f"{m} {_fmt(a)} vs {_fmt(b)}")
            if parts:
                where = split + (f" @ {x}" if x is not None else "")
                notes.append(f"{where}: " + ", ".join(parts))
    evidence = f"{a_label} vs {b_label}: " + "; ".join(notes) if notes else "not run"
    return Claim(claim, source, _verdict(outcomes), evidence)


def translation_claim(s: dict[str, pd.DataFrame]) -> Claim:
    notes, outcomes, learned = [], [], []
    axes = ("dE_m", "dN_m", "dU_m")
    for table, split in (("table3", "standard/test"), ("table4", "generalized/test")):
        reg = [_value(s.get(table), "Pd/Re-Net", split, m) for m in axes]
        dist = [_value(s.get(table), "Re-Net-T", split, m) for m in axes]
        const = [_value(s.get(table), "Constant (train mean)", split, m) for m in axes]
        if any(v is None for v in reg + dist):
            continue
        mean_reg = sum(v[0] for v in reg) / 3
        mean_dist = sum(v[0] for v in dist) / 3
        # "does not help": the distribution branch is not clearly (>10%) better
        outcomes.append("yes" if mean_dist >= 0.9 * mean_reg else "no")
        note = f"{split}: mean |error| regression {mean_reg:.1f} m vs Re-Net-T {mean_dist:.1f} m"
        if all(v is not None for v in const):
            mean_const = sum(v[0] for v in const) / 3
            learned.append(min(mean_reg, mean_dist) <= 0.9 * mean_const)
            note += f", constant predictor {mean_const:.1f} m"
        notes.append(note)
    verdict = _verdict(outcomes)
    if learned and not any(learned):
        verdict = INCONCLUSIVE
        notes.append(
            "neither translation head beats the constant predictor by 10%: nothing learned"
        )
    return Claim(
        "A distribution layer does not improve translation (regression is a fair trade-off)",
        "Tables 3-4, mean of δE, δN, δU (m)",
        verdict,
        "; ".join(notes) or "tables 3-4 not run",
    )


def kappa_claim(s: dict[str, pd.DataFrame]) -> Claim:
    summary = s.get("fig7")
    notes, outcomes = [], []
    if summary is not None and "satellite" in summary:
        summary = summary[summary["satellite"] == "true"]
    if summary is not None and not summary.empty:
        for split, part in summary.groupby("split"):
            part = part[part["dphi_deg"].notna()]
            if part.empty:
                continue
            best = part.loc[part["dphi_deg"].idxmin()]
            outcomes.append("yes" if float(best["x"]) == 10.0 else "no")
            values = ", ".join(f"κ={r.x}: {r.dphi_deg:.2f}" for r in part.itertuples())
            notes.append(f"{split}: best κ = {best['x']} ({values})")
    return Claim("κ = 10 gives the lowest attitude error", "Fig. 7, δφ (deg)", _verdict(outcomes),
                 "; ".join(notes) or "fig7 not run")  # fmt: skip


def constant_claim(s: dict[str, pd.DataFrame]) -> Claim:
    """Not the paper's claim but the benchmark's sanity bar: every head must really learn."""
    summary = s.get("table1")
    outcomes, notes = [], []
    base = _value(summary, "Constant (train mean)", "standard/test", "dphi_deg")
    if summary is not None and base is not None:
        for label in _trained_labels(summary):
            v = _value(summary, label, "standard/test", "dphi_deg")
            if v is not None:
                outcomes.append("yes" if v[0] <= 0.75 * base[0] else "no")
                notes.append(f"{label} {v[0]:.1f}")
    evidence = (
        f"constant predictor δφ {_fmt(base)}; heads: " + ", ".join(notes)
        if notes
        else "table1 not run"
    )
    return Claim(
        "Sanity: every rotation head beats the constant (training-mean) predictor by >= 25% "
        "(the UAV-only control excluded)",
        "Table 1 setting, δφ (deg) on standard/test",
        _verdict(outcomes),
        evidence,
    )


def uncertainty_claim(s: dict[str, pd.DataFrame]) -> Claim:
    notes, outcomes = [], []
    for table, split in (("table1", "standard/test"), ("table2", "generalized/test")):
        summary = s.get(table)
        v = _value(summary, "Pd/Re-Net", split, "spearman_unc_err")
        if v is not None:
            outcomes.append("yes" if v[0] > 0.1 else "no")
            notes.append(f"{split}: Spearman ρ(uncertainty, δφ) = {v[0]:.2f}")
    return Claim(
        "Pd/Re-Net's predicted uncertainty is meaningful (higher when the error is larger)",
        "Tables 1-2 models, rank correlation of the head's uncertainty with δφ (ρ > 0.1 required)",
        _verdict(outcomes),
        "; ".join(notes) or "not run",
    )


def _trained_labels(summary: pd.DataFrame, control: bool = False) -> list[str]:
    """Labels of trained models (not the constant predictor); the UAV-only controls
    (``satellite_input == "blank"``) if ``control``, else every other one."""
    if "satellite_input" in summary:
        blank = summary["satellite_input"] == "blank"
        rows = summary[blank if control else ~blank & (summary["satellite_input"] != "none")]
    else:
        rows = summary[summary["label"] != "Constant (train mean)"] if not control else summary[:0]
    return list(dict.fromkeys(rows["label"]))


def evaluate_claims(s: dict[str, pd.DataFrame]) -> list[Claim]:
    from benchmark.runner.claims_satellite import control_claim, satellite_claims

    angles = ["dtheta_deg", "dgamma_deg", "dpsi_deg", "dphi_deg"]
    fig5_xs = _xs(s.get("fig5"))
    fig6_xs = _xs(s.get("fig6"))
    flight = ["flight/pitch0", "flight/pitch-10", "flight/pitch-50"]
    return [
        constant_claim(s),
        representation_claim(s),
        _pairwise_claim("For the rotation matrix, a distribution beats regression (every angle)",
                        "Tables 1-2, δθ δγ δψ δφ", _concat(s, "table1", "table2"), "Pd/Re-Net",
                        "Re-Net-R", ["standard/test", "generalized/test"], angles),
        translation_claim(s),
        _pairwise_claim("Pd/Re-Net stays more accurate than Re-Net-R at every satellite height",
                        "Fig. 5, δφ", s.get("fig5"), "Pd/Re-Net", "Re-Net-R",
                        _splits(s.get("fig5")), ["dphi_deg"], fig5_xs),
        _pairwise_claim("Pd/Re-Net stays more accurate than Re-Net-R at every view difference",
                        "Fig. 6, δφ", s.get("fig6"), "Pd/Re-Net", "Re-Net-R",
                        _splits(s.get("fig6")), ["dphi_deg"], fig6_xs),
        kappa_claim(s),
        _ablation_claim(s),
        _pairwise_claim("On the flight-test analogue, Pd/Re-Net with AGTFM beats Re-Net",
                        "Table 5, δE δN δU δφ", s.get("table5"), "Pd/Re-Net with AGTFM", "Re-Net",
                        flight, ["dE_m", "dN_m", "dU_m", "dphi_deg"]),
        uncertainty_claim(s),
        *satellite_claims(s),
        control_claim(s),
    ]  # fmt: skip


def _ablation_claim(s: dict[str, pd.DataFrame]) -> Claim:
    summary = s.get("fig9")
    outcomes, notes = [], []
    for split in _splits(summary):
        a_f = _value(summary, "Pd/Re-Net", split, "dphi_deg", "a-f")
        plain = _value(summary, "Pd/Re-Net", split, "dphi_deg", "/")
        if a_f is None or plain is None:
            continue
        outcomes.append(_beats(a_f, plain))
        values = ", ".join(
            f"{x}: {_fmt(_value(summary, 'Pd/Re-Net', split, 'dphi_deg', x))}"
            for x in ("/", "a", "f", "a-f")
        )
        notes.append(f"{split}: {values}")
    return Claim("AGTFM (a-f) improves on the plain encoder (/)", "Fig. 9, δφ (deg)",
                 _verdict(outcomes), "; ".join(notes) or "fig9 not run")  # fmt: skip


def _xs(summary: pd.DataFrame | None) -> list[str]:
    if summary is None or summary.empty:
        return []
    return [str(x) for x in dict.fromkeys(summary["x"].astype(str))]


def _splits(summary: pd.DataFrame | None) -> list[str]:
    if summary is None or summary.empty:
        return []
    return list(dict.fromkeys(summary["split"]))


def _concat(s: dict[str, pd.DataFrame], *names: str) -> pd.DataFrame | None:
    parts = [s[n] for n in names if n in s and not s[n].empty]
    return pd.concat(parts, ignore_index=True) if parts else None


def render_claims(claims: list[Claim]) -> str:
    lines = ["| # | claim | source | verdict | evidence |", "|---|---|---|---|---|"]
    for i, c in enumerate(claims, 1):
        lines.append(f"| {i} | {c.claim} | {c.source} | **{c.verdict}** | {c.evidence} |")
    return "\n".join(lines)
