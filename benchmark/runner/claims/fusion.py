"""The claims of the flight fusion (issue 39), decided on the ``sequence`` table's per-frame files
(``FrameStore.sequence_errors``) with the statistics of every claim (``evidence``).

1. Fusion beats each head's own per-frame estimate: δφ of the causal filter (what a UAV has
   online) minus the per-frame δφ, per head, on standard/test, towns/test and generalized/test.
   A head is compared with itself, so no participation check: a head at the constant's level
   that fusion lifts is a gain too.
2. Fused, the distribution head beats the regression head of the same representation: causal
   filter δφ on the long flights (where fusion has most to work with), for each representation
   that has both (``REPRESENTATION_PAIRS``); each head must beat the constant predictor per frame
   on the split (the participation rule of every claim).
3. Where a head is uncertain, fusion gains most: per head with a predicted uncertainty,
   Spearman ρ(per-frame uncertainty, per-frame gain of the smoother, frame δφ − smoothed δφ) > 0
   on long/standard. Regression heads predict no uncertainty, so they cannot take part: their
   fused density's width is one calibrated constant for every frame.
"""

from __future__ import annotations

from benchmark.evaluation.paired import percentile_interval, spearman_replicates
from benchmark.runner.claims.evidence import (
    CONFIDENCE,
    EXCLUDED,
    SPEARMAN,
    Claim,
    Comparison,
    Evidence,
    build_claim,
    margin_of,
    safe_claim,
)
from benchmark.runner.claims.frame_errors import FrameErrors

TABLE = "sequence"
GAIN_SPLITS = ("standard/test", "towns/test", "generalized/test")
LONG_SPLITS = ("long/standard", "long/towns", "long/london")
# (distribution head, regression head) of one representation, as labelled in sequence.yaml
REPRESENTATION_PAIRS = (
    ("Pd/Re-Net", "Re-Net-R"),  # rotation matrix
    ("Pd-Net-Q", "Re-Net-Q"),  # quaternion
    ("Pd-Net-E", "Re-Net-E"),  # Euler angles
    ("Pd-Net-Rv", "Re-Net-Rv"),  # rotation vector
    ("Matrix Fisher", "Re-Net-SVD"),  # SVD-orthogonalised matrix (Mohlin et al.'s pairing)
)


def _fused(ev: Evidence, label: str, split: str, metric: str, mode: str) -> FrameErrors:
    return ev.frames.sequence_errors(TABLE, label, split, metric, mode)


def fusion_gain_claim(ev: Evidence) -> Claim:
    claim = "Fused along the flight (causal filter), every head beats its own per-frame estimate"
    source = "Sequence table, δφ (deg), causal filter − per frame"

    def build() -> Claim:
        comps: list[Comparison | None] = []
        for label in ev.frames.labels(TABLE, control=False):
            for split in GAIN_SPLITS:
                if not ev.frames.has_sequence(TABLE, label, split):
                    continue
                fused = _fused(ev, label, split, "dphi_deg", "filter")
                frame = _fused(ev, label, split, "dphi_deg", "frame")
                comps.append(ev.paired(f"{label}, {split}", fused, frame,
                                       margin=margin_of("dphi_deg")))  # fmt: skip
        rule = (
            "Δ = δφ(causal filter) − δφ(per frame) of the same head on the same frames, seeds "
            "paired; claimed Δ < 0 for every head (the UAV-only control excluded) on every split"
        )
        return build_claim(claim, source, rule, comps, [])

    return safe_claim(build, claim, source)


def fused_family_claim(ev: Evidence) -> Claim:
    claim = "Fused, the distribution head beats the regression head of the same representation"
    source = "Sequence table, long flights, δφ (deg) of the causal filter"

    def build() -> Claim:
        comps: list[Comparison | None] = []
        excluded: list[str] = []
        for dist, reg in REPRESENTATION_PAIRS:
            for split in LONG_SPLITS:
                if not (ev.frames.has_sequence(TABLE, dist, split)
                        and ev.frames.has_sequence(TABLE, reg, split)):  # fmt: skip
                    continue
                reasons = [r for m in (dist, reg)
                           if (r := ev.exclusion((TABLE, m, None), split, "dphi_deg"))]  # fmt: skip
                if reasons:
                    excluded += [r for r in reasons if r not in excluded]
                    comps.append(Comparison(f"{dist} vs {reg}, {split}", verdict=EXCLUDED))
                    continue
                a = _fused(ev, dist, split, "dphi_deg", "filter")
                b = _fused(ev, reg, split, "dphi_deg", "filter")
                comps.append(ev.paired(f"{dist} − {reg}, {split}", a, b,
                                       margin=margin_of("dphi_deg")))  # fmt: skip
        rule = (
            "Δ = fused δφ(distribution head) − fused δφ(regression head of its representation) "
            "on the same frames; claimed Δ < 0 for every pair on every long split; both heads "
            "must beat the constant predictor per frame there"
        )
        return build_claim(claim, source, rule, comps, excluded)

    return safe_claim(build, claim, source)


def uncertainty_gain_claim(ev: Evidence) -> Claim:
    claim = "Where a head is uncertain, fusion gains most (its uncertainty predicts the gain)"
    source = "Sequence table, long/standard: Spearman ρ(uncertainty, δφ per frame − δφ smoothed)"

    def build() -> Claim:
        comps: list[Comparison | None] = []
        without: list[str] = []
        split = "long/standard"
        for label in ev.frames.labels(TABLE, split, control=False):
            if not ev.frames.has_sequence(TABLE, label, split):
                continue
            try:
                unc = ev.values((TABLE, label, None), split, "uncertainty")
            except ValueError:  # a regression head: no uncertainty column
                without.append(label)
                continue
            frame = _fused(ev, label, split, "dphi_deg", "frame")
            smooth = _fused(ev, label, split, "dphi_deg", "smooth")
            gain = frame.values - smooth.values
            rho, reps = spearman_replicates(unc.values, gain, frame.flight, ev.n_boot // 2)
            lo, hi = percentile_interval(reps, CONFIDENCE)
            comps.append(
                Comparison(label, rho, lo, hi, +1, 0.0, reps, unit="",
                           n_flights=len(set(frame.flight.tolist())), margin=margin_of(SPEARMAN))
            )  # fmt: skip
        rule = (
            "ρ = Spearman(uncertainty, δφ per frame − δφ smoothed), 95% bootstrap over flights "
            "and seeds; claimed ρ > 0 for every head that predicts an uncertainty"
        )
        notes = (
            [f"no uncertainty to rank by, so not compared: {', '.join(without)}"] if without else []
        )
        return build_claim(claim, source, rule, comps, [], notes)

    return safe_claim(build, claim, source)


def fusion_claims(ev: Evidence) -> list[Claim]:
    """The three fusion claims; none when no sequence table was planned."""
    if not ev.frames.labels(TABLE):
        return []
    claims = [fusion_gain_claim(ev), fused_family_claim(ev), uncertainty_gain_claim(ev)]
    for c in claims:
        c.kind = "fusion"
    return claims
