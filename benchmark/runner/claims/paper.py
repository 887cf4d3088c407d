"""The paper's claims 1-10 (and the benchmark's sanity bar), each decided by paired statistics on
the per-frame errors (evidence, participation and combination rules:
``benchmark.runner.claims.evidence``).
"""

from __future__ import annotations

from benchmark.evaluation.paired import percentile_interval
from benchmark.runner.claims.evidence import (
    CONFIDENCE,
    DISTRIBUTION,
    EXCLUDED,
    NAMES,
    REGRESSION,
    SPEARMAN,
    TRANSLATION,
    Claim,
    Comparison,
    Evidence,
    build_claim,
    head_family,
    margin_of,
    safe_claim,
)


def _pair_rule(a: str, b: str, metrics: str) -> str:
    return f"Δ = {metrics}({a}) − {metrics}({b}); claimed Δ < 0"


def pairwise_claim(
    ev: Evidence,
    claim: str,
    source: str,
    table: str | tuple[str, ...],
    a: str,
    b: str,
    metrics: list[str],
    splits: list[str] | None = None,
    sweep: bool = False,
) -> Claim:
    """A beats B on every (split[, sweep value], metric) planned."""

    def build() -> Claim:
        comps, excluded = [], []
        for t in (table,) if isinstance(table, str) else table:
            for x in ev.frames.xs(t, a) if sweep else [None]:
                for split in splits or ev.frames.splits(t, a, x):
                    for m in metrics:
                        where = f"{split} {NAMES.get(m, m)}"
                        comps.append(ev.compare(where, (t, a, x), (t, b, x), split, m, excluded))
        return build_claim(claim, source, _pair_rule(a, b, "err"), comps, excluded)

    return safe_claim(build, claim, source)


def constant_claim(ev: Evidence) -> Claim:
    """Not the paper's claim but the benchmark's sanity bar: every head must really learn."""
    claim = (
        "Sanity: every rotation head beats the constant (training-mean) predictor "
        "(the UAV-only control excluded)"
    )
    source = "Table 1 setting, δφ (deg) on standard/test"

    def build() -> Claim:
        comps = []
        for label in ev.frames.labels("table1", "standard/test", control=False):
            c = ev.beats_constant(("table1", label, None), "standard/test", "dphi_deg")
            comps.append(
                Comparison(
                    label, c.diff, c.lo, c.hi, replicates=c.replicates, n_flights=c.n_flights,
                    margin=margin_of("dphi_deg"),
                )
            )  # fmt: skip
        rule = "Δ = δφ(head) − δφ(constant); claimed Δ < 0 for every head (no participation rule)"
        return build_claim(claim, source, rule, comps, [])

    out = safe_claim(build, claim, source)
    out.kind, out.split = "sanity", "standard/test"
    return out


# The paper's rotation-matrix head of each family (registry names): claim 2 compares each with
# every other head of its family in Tables 1-2; the family of a head comes from the registry.
MATRIX_HEADS = {DISTRIBUTION: "pd_re_net", REGRESSION: "re_net_r"}


def representation_claim(ev: Evidence) -> Claim:
    """The rotation matrix (Pd/Re-Net, Re-Net-R) beats every other head of its family (the
    registry's, :func:`benchmark.runner.claims.evidence.head_family`) in Tables 1-2, on δφ."""
    claim = (
        "The rotation matrix beats the other representations (quaternion, rotation vector, Euler)"
    )
    source = "Tables 1-2, geodesic error δφ (deg)"

    def build() -> Claim:
        comps, excluded = [], []
        for table, split in (("table1", "standard/test"), ("table2", "generalized/test")):
            labels = ev.frames.labels(table, split, control=False)
            heads = {label: ev.attitude((table, label, None)) for label in labels}
            for family, matrix in MATRIX_HEADS.items():
                best = next((label for label in labels if heads[label] == matrix), None)
                if best is None:
                    continue
                for other in labels:
                    if heads[other] == matrix or head_family(heads[other]) != family:
                        continue
                    comps.append(
                        ev.compare(
                            f"{split} vs {other}",
                            (table, best, None),
                            (table, other, None),
                            split,
                            "dphi_deg",
                            excluded,
                        )
                    )
        rule = (
            "Δ = δφ(rotation-matrix head: pd_re_net or re_net_r) − δφ(another head of the same "
            "family); claimed Δ < 0. Families from the head registry: distribution = "
            "is_probabilistic or gives_log_prob, otherwise regression"
        )
        return build_claim(claim, source, rule, comps, excluded)

    return safe_claim(build, claim, source)


def translation_claim(ev: Evidence) -> Claim:
    claim = "A distribution layer does not improve translation (regression is a fair trade-off)"
    source = "Tables 3-4, per-frame mean of δE, δN, δU (m)"

    def build() -> Claim:
        comps, excluded = [], []
        for table, split in (("table3", "standard/test"), ("table4", "generalized/test")):
            comps.append(
                ev.compare(
                    split,
                    (table, "Pd/Re-Net", None),
                    (table, "Re-Net-T", None),
                    split,
                    TRANSLATION,
                    excluded,
                )
            )
        rule = (
            "Δ = mean(δE,δN,δU)(regression, Pd/Re-Net) − same(Re-Net-T); claimed Δ < 0 "
            "(regression more accurate) or equivalent (no practical difference: the distribution "
            "layer does not improve translation); Re-Net-T clearly better contradicts"
        )
        return build_claim(claim, source, rule, comps, excluded, equivalent_supports=True)

    return safe_claim(build, claim, source)


def kappa_claim(ev: Evidence) -> Claim:
    claim, source = "κ = 10 gives the lowest attitude error", "Fig. 7, δφ (deg)"

    def build() -> Claim:
        comps, excluded = [], []
        xs = ev.frames.xs("fig7", "Pd/Re-Net")
        ten = [x for x in xs if float(x) == 10.0]
        for x10 in ten[:1]:
            for split in ev.frames.splits("fig7", "Pd/Re-Net", x10):
                for x in (x for x in xs if x != x10):
                    comps.append(
                        ev.compare(
                            f"{split} vs κ={x}",
                            ("fig7", "Pd/Re-Net", x10),
                            ("fig7", "Pd/Re-Net", x),
                            split,
                            "dphi_deg",
                            excluded,
                        )
                    )
        rule = "Δ = δφ(κ=10) − δφ(other κ); claimed Δ < 0 against every other κ"
        return build_claim(claim, source, rule, comps, excluded)

    return safe_claim(build, claim, source)


def ablation_claim(ev: Evidence) -> Claim:
    claim, source = "AGTFM (a-f) improves on the plain encoder (/)", "Fig. 9, δφ (deg)"

    def build() -> Claim:
        comps, excluded = [], []
        for split in ev.frames.splits("fig9", "Pd/Re-Net", "a-f"):
            comps.append(
                ev.compare(
                    split,
                    ("fig9", "Pd/Re-Net", "a-f"),
                    ("fig9", "Pd/Re-Net", "/"),
                    split,
                    "dphi_deg",
                    excluded,
                )
            )
        rule = "Δ = δφ(a-f) − δφ(/); claimed Δ < 0"
        return build_claim(claim, source, rule, comps, excluded)

    return safe_claim(build, claim, source)


def uncertainty_claim(ev: Evidence) -> Claim:
    from benchmark.evaluation.paired import spearman_replicates

    claim = "Pd/Re-Net's predicted uncertainty is meaningful (higher when the error is larger)"
    source = "Tables 1-2, Spearman ρ(uncertainty, δφ) per seed, averaged over seeds"

    def build() -> Claim:
        comps, excluded = [], []
        for table, split in (("table1", "standard/test"), ("table2", "generalized/test")):
            model = (table, "Pd/Re-Net", None)
            if not ev.frames.has(*model[:2], split):
                continue
            reason = ev.exclusion(model, split, "dphi_deg")
            if reason is not None:
                excluded.append(reason)
                comps.append(Comparison(split, verdict=EXCLUDED))
                continue
            unc, err = ev.values(model, split, "uncertainty"), ev.values(model, split, "dphi_deg")
            rho, reps = spearman_replicates(unc.values, err.values, err.flight, ev.n_boot // 2)
            lo, hi = percentile_interval(reps, CONFIDENCE)
            flights = len(set(err.flight.tolist()))
            comps.append(
                Comparison(split, rho, lo, hi, +1, 0.0, reps, unit="", n_flights=flights,
                           margin=margin_of(SPEARMAN))
            )  # fmt: skip
        rule = (
            "ρ = Spearman(uncertainty, δφ), 95% bootstrap over flights and seeds; claimed ρ > 0; "
            "Pd/Re-Net must beat the constant predictor on δφ"
        )
        return build_claim(claim, source, rule, comps, excluded)

    return safe_claim(build, claim, source)
