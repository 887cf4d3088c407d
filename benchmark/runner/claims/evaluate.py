"""Every claim of the report, in its order, and the claims table (the claims themselves are
decided in ``paper``, ``satellite`` and ``ranking``, on the machinery of ``evidence``)."""

from __future__ import annotations

import pandas as pd

from benchmark.runner.claims.evidence import (
    COMBINE_RULE,
    MIN_FLIGHTS,
    N_BOOT,
    Claim,
    Evidence,
)
from benchmark.runner.claims.frame_errors import FrameStore
from benchmark.runner.claims.paper import (
    ablation_claim,
    constant_claim,
    kappa_claim,
    pairwise_claim,
    representation_claim,
    translation_claim,
    uncertainty_claim,
)
from benchmark.runner.claims.ranking import ranking_claims
from benchmark.runner.claims.satellite import control_claim, satellite_claims


def evaluate_claims(summaries: dict[str, pd.DataFrame], frames: FrameStore) -> list[Claim]:
    """Every claim, in the report's order (1-10 the paper's, then the satellite claims, then which
    representation wins each test split of the beyond-the-paper ``extended`` table).

    ``summaries`` (per-table mean summaries, ``benchmark.runner.report.tables.summarize``) are kept
    for the report's context; every verdict is computed from ``frames``' per-frame errors.
    """
    ev = Evidence(frames)
    angles = ["dtheta_deg", "dgamma_deg", "dpsi_deg", "dphi_deg"]
    return [
        constant_claim(ev),
        representation_claim(ev),
        pairwise_claim(ev, "For the rotation matrix, a distribution beats regression (every angle)",
                       "Tables 1-2, δθ δγ δψ δφ (deg)", ("table1", "table2"), "Pd/Re-Net",
                       "Re-Net-R", angles),
        translation_claim(ev),
        pairwise_claim(ev, "Pd/Re-Net stays more accurate than Re-Net-R at every satellite height",
                       "Fig. 5, δφ (deg)", "fig5", "Pd/Re-Net", "Re-Net-R", ["dphi_deg"],
                       sweep=True),
        pairwise_claim(ev, "Pd/Re-Net stays more accurate than Re-Net-R at every view difference",
                       "Fig. 6, δφ (deg)", "fig6", "Pd/Re-Net", "Re-Net-R", ["dphi_deg"],
                       sweep=True),
        kappa_claim(ev),
        ablation_claim(ev),
        pairwise_claim(ev, "On the flight-test analogue, Pd/Re-Net with AGTFM beats Re-Net",
                       "Table 5, δE δN δU (m), δφ (deg)", "table5", "Pd/Re-Net with AGTFM",
                       "Re-Net", ["dE_m", "dN_m", "dU_m", "dphi_deg"]),
        uncertainty_claim(ev),
        *satellite_claims(ev),
        control_claim(ev),
        *ranking_claims(ev),
    ]  # fmt: skip


def render_claims(claims: list[Claim]) -> str:
    """Markdown table (#, claim, source, paired difference [95% interval], rule, verdict,
    evidence) followed by the general verdict rule."""
    lines = [
        "| # | claim | source | paired difference [95% interval] | rule | verdict | evidence |",
        "|---|---|---|---|---|---|---|",
    ]
    for i, c in enumerate(claims, 1):
        cells = [
            str(i),
            c.claim,
            c.source,
            c.difference or "–",
            c.rule or "–",
            f"**{c.verdict}**",
            c.evidence,
        ]
        lines.append("| " + " | ".join(x.replace("|", "\\|") for x in cells) + " |")
    lines += ["", RULE_NOTE]
    return "\n".join(lines)


RULE_NOTE = (
    "Each Δ is a per-frame paired difference on the same test frames, each model's error averaged "
    "over its seeds; the interval is the 95% percentile interval of a bootstrap resampling whole "
    "flights and seeds: per model, or once for two models whose seed-s runs share one trained "
    "encoder (the heads on the shared encoder of seed s) or one model with and without a probe "
    f"({N_BOOT} replicates). ✓ supported: the interval excludes zero "
    "(or the stated threshold) on the claimed side; ✗ contradicted: it excludes it on the other "
    "side, at the Bonferroni-corrected level when a claim has several comparisons (so a 95% "
    "interval on the wrong side can still read ~); ~ not resolved at this scale (always so on a "
    "split with fewer than "
    f"{MIN_FLIGHTS} flights: a bootstrap over so few flights has no coverage). A head takes part "
    "in a comparison only when it beats the constant predictor on that split and error (interval "
    "below zero); excluded heads are listed "
    "with their difference to the constant. "
    f"Several comparisons: {COMBINE_RULE}."
)
