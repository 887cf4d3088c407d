"""Claims about the satellite image (issue 9): does each head use it, and what does the UAV image
alone give (the UAV-only control)?

*Uses the satellite image* is decided per model on the satellite-swap probe: the paired per-frame
difference of the yaw error (and of the geodesic error), swapped minus true satellite image, on the
same frames, with a 95% bootstrap interval that resamples whole flights
(``benchmark.evaluation.paired``; computed per unit by the runner). A model uses it when both
intervals lie above zero and both mean rises reach ``report.MIN_RISE_DEG`` (1 deg); a model whose
yaw error does not rise is reported as not using it. With several seeds the bounds are averaged
over seeds.
"""

from __future__ import annotations

import pandas as pd

from benchmark.runner.claims import (
    INCONCLUSIVE,
    NOT_RUN,
    Claim,
    _trained_labels,
    _value,
    _verdict,
)
from benchmark.runner.report import ONE_FLIGHT, pick, uses_satellite

CONSTANT = "Constant (train mean)"
# (table, split) pairs where every attitude head is checked for using the satellite image.
SATELLITE_CHECKS = (
    ("table1", "standard/test"),
    ("table2", "generalized/test"),
    ("towns", "towns/test"),
    ("towns", "towns/london"),
)
CONTROL_TOLERANCE = 0.9  # the control's yaw error must stay >= 0.9x the constant predictor's


def _effect_text(swap: pd.Series, e: str, name: str) -> str:
    d, lo, hi = (float(swap[f"swap_{e}_{k}_deg"]) for k in ("diff", "boot_lo", "boot_hi"))
    return f"Δ{name} {d:+.1f} [{lo:+.1f}, {hi:+.1f}]"


def satellite_claim(summary: pd.DataFrame | None, table: str, split: str) -> Claim:
    """One claim per (table, split): every non-control head uses the satellite image there."""
    claim = (
        f"Every head uses the satellite image on `{split}`: its yaw and geodesic errors rise when "
        "the satellite image shows another place"
    )
    source = (
        f"{table}, satellite-swap probe: swapped minus true error per frame, 95% bootstrap over "
        "flights (deg)"
    )
    if summary is None or summary.empty:
        return Claim(claim, source, NOT_RUN, f"{table} not run")
    outcomes, users, notes = [], [], []
    for label in _trained_labels(summary):
        true, swap = pick(summary, label, split, "true"), pick(summary, label, split, "swap")
        verdict = uses_satellite(swap)
        if true is None or verdict is None:
            continue
        if verdict == ONE_FLIGHT:
            notes.append(f"{label}: {verdict}")
            continue
        outcomes.append("yes" if verdict == "yes" else "no")
        text = {"yes": "uses it", "no": "does not use it"}.get(verdict, f"{verdict}")
        users += [label] if verdict == "yes" else []
        notes.append(
            f"{label}: {text} (δψ {true['dpsi_deg']:.1f} → {swap['dpsi_deg']:.1f}, "
            f"{_effect_text(swap, 'dpsi', 'δψ')}; {_effect_text(swap, 'dphi', 'δφ')})"
        )
    if outcomes and not users:
        notes.append(
            "no head uses the satellite image here: these rows compare UAV-only regressors"
        )
    verdict = _verdict(outcomes) if outcomes or not notes else INCONCLUSIVE
    return Claim(claim, source, verdict, "; ".join(notes) or f"{split} not run")


def satellite_claims(s: dict[str, pd.DataFrame]) -> list[Claim]:
    return [satellite_claim(s.get(table), table, split) for table, split in SATELLITE_CHECKS]


def _control(summary: pd.DataFrame | None) -> str | None:
    if summary is None or summary.empty:
        return None
    labels = _trained_labels(summary, control=True)
    return labels[0] if labels else None


def _angles(summary: pd.DataFrame, label: str, split: str) -> dict[str, float] | None:
    out = {}
    for m in ("dtheta_deg", "dgamma_deg", "dpsi_deg"):
        v = _value(summary, label, split, m)
        if v is None:
            return None
        out[m] = v[0]
    return out


def control_claim(s: dict[str, pd.DataFrame]) -> Claim:
    """The UAV-only control reads no heading in an unseen city; on the standard split, how far it
    gets (landmarks of the training cities), against the constant predictor and Pd/Re-Net."""
    claim = (
        "The UAV-only control (same encoder and Pd/Re-Net head, satellite input blanked) learns no "
        "heading in an unseen city: on generalized/test its δψ is no more than 10% below the "
        "constant predictor's"
    )
    source = "Tables 1-2 (and towns), UAV-only control vs constant predictor, δψ (deg)"
    notes: list[str] = []
    verdict = NOT_RUN
    gen = s.get("table2")
    label = _control(gen)
    ctrl = _angles(gen, label, "generalized/test") if label else None
    const = _angles(gen, CONSTANT, "generalized/test") if label else None
    if ctrl and const:
        ratio = ctrl["dpsi_deg"] / const["dpsi_deg"]
        verdict = "supported" if ratio >= CONTROL_TOLERANCE else "contradicted"
        c, k = ctrl, const
        notes.append(
            f"generalized/test: control δψ {c['dpsi_deg']:.1f} vs constant {k['dpsi_deg']:.1f} "
            f"({ratio:.2f}x); from the horizon: δθ {c['dtheta_deg']:.1f} vs "
            f"{k['dtheta_deg']:.1f}, δγ {c['dgamma_deg']:.1f} vs {k['dgamma_deg']:.1f}"
        )
    std = s.get("table1")
    label = _control(std)
    ctrl = _angles(std, label, "standard/test") if label else None
    const = _angles(std, CONSTANT, "standard/test") if label else None
    head = _value(std, "Pd/Re-Net", "standard/test", "dpsi_deg") if label else None
    if ctrl and const:
        text = (
            f"standard/test: control δψ {ctrl['dpsi_deg']:.1f} vs constant {const['dpsi_deg']:.1f}"
        )
        if head is not None:
            gain = const["dpsi_deg"] - head[0]
            text += f" and Pd/Re-Net {head[0]:.1f}"
            if gain > 0:
                share = (const["dpsi_deg"] - ctrl["dpsi_deg"]) / gain
                text += (
                    f": the UAV image alone gives {100 * share:.0f}% of Pd/Re-Net's yaw gain over "
                    "the constant predictor (landmarks memorised in the training cities)"
                )
        notes.append(text)
        if verdict == NOT_RUN:
            verdict = INCONCLUSIVE
    towns = s.get("towns")
    label = _control(towns)
    for split in ("towns/test", "towns/london"):
        ctrl = _angles(towns, label, split) if label else None
        const = _angles(towns, CONSTANT, split) if label else None
        if ctrl and const:
            notes.append(
                f"{split}: control δψ {ctrl['dpsi_deg']:.1f} vs constant {const['dpsi_deg']:.1f} "
                f"({ctrl['dpsi_deg'] / const['dpsi_deg']:.2f}x)"
            )
    return Claim(claim, source, verdict, "; ".join(notes) or "no UAV-only control run")
