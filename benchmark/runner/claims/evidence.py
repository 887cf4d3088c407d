"""The statistics every claim is decided by (the claims: ``paper``, ``satellite``, ``ranking``;
all of them in the report's order: ``evaluate``).

Evidence. Every comparison "A beats B" is made on the per-frame error difference on the same test
frames (``benchmark.runner.claims.frame_errors.FrameStore``): ``Δ = err(A) − err(B)``, each model's
error first averaged over its training seeds. Its 95% interval is the percentile interval of a
bootstrap that resamples whole flights (frames of a flight are correlated) and the seeds
(``benchmark.evaluation.paired.pooled_bootstrap``, ``N_BOOT`` replicates, seed 0): independently
for each model, unless the two models share each seed's trained run (``FrameErrors.trained_from``:
heads on the same frozen encoder of seed s, or one model under a probe), in which case one draw of
seeds serves both, as one draw of flights does. Drawing shared seeds independently would count
what the shared encoder of a seed does to both models twice, as if it were a difference between
them.

Verdict of one comparison: **equivalent** when it has an equivalence margin ``m``
(``EQUIVALENCE_MARGINS``, by error; issue 38) and the 90% interval of Δ lies inside ``(−m, +m)``
(two one-sided tests at 5%: no difference as large as the margin, whatever the sign); otherwise
**supported** when the 95% interval excludes zero in the claimed direction, **contradicted** when
it excludes zero in the other direction, **not resolved at this scale** otherwise. Equivalence is
checked first: a difference that is clear but smaller than the margin is no practical win. The
margins were fixed by issue 38 before any data it judges were drawn and are never changed after
a result is seen; comparisons against a stated threshold other than zero (the swap probe's 1°
rise, the control's 0.9x the constant) and the participation check have none.

Participation. A head takes part in a comparison on a split only when it beats the constant
(training-mean) predictor there on the compared error: the interval of ``err(head) − err(constant)``
lies below zero. Otherwise the comparison is *excluded* and the evidence says which head and why
(a head at the constant's level has learned nothing to compare).

Head families. A claim that compares representations within a family ("distribution" or
"regression") reads the family from the head registry (:func:`head_family`: the class attributes
``is_probabilistic`` and ``gives_log_prob``), never from a table's display labels, so a head added
to a table takes part without any change here.

Claims with several comparisons (every angle, every height, ...) combine them by ``COMBINE_RULE``:
supported when every participating comparison is supported (an intersection-union test: valid at
95% without correction); contradicted when at least one is contradicted at the Bonferroni level
``1 − 0.05/k`` over the k participating comparisons (one clear counterexample, corrected for having
looked k times); **contradicted (no practical difference)** when none is contradicted but one is
equivalent (a superiority claim with a tie inside the margin); not resolved otherwise, and when no
comparison takes part. A claim that states *no* difference (``equivalent_supports``: "a
distribution layer does not improve translation") counts an equivalent comparison as support.
The equivalence test of each comparison is the 90% interval the issue fixed, not corrected for k.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from benchmark.evaluation.paired import percentile_interval, pooled_replicates
from benchmark.runner.claims.frame_errors import FrameErrors, FrameStore

SUPPORTED, CONTRADICTED = "supported", "contradicted"
UNRESOLVED, NOT_RUN, EXCLUDED = "not resolved at this scale", "not run", "excluded"
EQUIVALENT = "equivalent"  # one comparison: the 90% interval inside (−margin, +margin)
NO_DIFFERENCE = "contradicted (no practical difference)"  # a claim: its comparisons say a tie
N_BOOT = 4000
CONFIDENCE = 0.95
EQUIVALENCE_CONFIDENCE = 0.90  # two one-sided tests at 5% each
SPEARMAN = "spearman_rho"  # the uncertainty claim's statistic (no error column of its own)
# Fewer flights than this on a split: no verdict. A percentile bootstrap over G clusters has far
# below nominal coverage for small G (one flight: every replicate is the same, a zero-width
# interval), so such a comparison is "not resolved at this scale" whatever its interval.
MIN_FLIGHTS = 5
COMBINE_RULE = (
    "supported when every participating comparison's 95% interval is on the claimed side of the "
    "threshold; contradicted when one comparison's Bonferroni-corrected interval (level "
    "1 − 0.05/k, k participating comparisons) is on the other side; contradicted (no practical "
    "difference) when none is but one is equivalent (≈: its 90% interval inside ±the margin); "
    "otherwise not resolved"
)
SYMBOL = {SUPPORTED: "✓", CONTRADICTED: "✗", EQUIVALENT: "≈", UNRESOLVED: "~"}
TRANSLATION = "dT_m"  # pseudo-metric: per-frame mean of |dE|, |dN|, |dU| (m)
# Equivalence margins of issue 38, fixed before the data they judge and never tuned after a
# result: a difference smaller than these is no practical difference. Keys: error columns of
# the predictions (degrees, metres), TRANSLATION and SPEARMAN.
EQUIVALENCE_MARGINS: dict[str, float] = {
    "dphi_deg": 2.0,
    "dpsi_deg": 2.0,
    "dtheta_deg": 1.0,
    "dgamma_deg": 1.0,
    "dE_m": 5.0,
    "dN_m": 5.0,
    "dU_m": 5.0,
    "horizontal_m": 5.0,
    TRANSLATION: 5.0,  # the per-frame mean of |δE|, |δN|, |δU|
    SPEARMAN: 0.05,
}
NAMES = {"dtheta_deg": "δθ", "dgamma_deg": "δγ", "dpsi_deg": "δψ", "dphi_deg": "δφ",
         "dE_m": "δE", "dN_m": "δN", "dU_m": "δU", TRANSLATION: "mean(δE, δN, δU)"}  # fmt: skip
Model = tuple[str, str, str | None]  # (table, label, x)


@dataclass
class Comparison:
    """One paired comparison: ``diff`` = mean per-frame difference in the metric's unit, its 95%
    interval ``[lo, hi]`` and ``replicates (N_BOOT,)``; ``claimed`` = -1 (the difference should be
    below ``threshold``) or +1 (above). ``verdict`` is set by :func:`combine`."""

    where: str
    diff: float = math.nan
    lo: float = math.nan
    hi: float = math.nan
    claimed: int = -1
    threshold: float = 0.0
    replicates: np.ndarray | None = None
    verdict: str = UNRESOLVED
    note: str = ""
    unit: str = "°"
    n_flights: int | None = None  # flights of the split (None: not from a flight bootstrap)
    margin: float | None = None  # equivalence margin (EQUIVALENCE_MARGINS); None: no such test

    @property
    def too_few_flights(self) -> bool:
        return self.n_flights is not None and self.n_flights < MIN_FLIGHTS

    def text(self) -> str:
        """``where: Δ [lo, hi]unit symbol``; an equivalent comparison adds its 90% interval and
        margin, the numbers its verdict rests on."""
        sym = SYMBOL.get(self.verdict, "")
        few = f" ({self.n_flights} flight(s))" if self.too_few_flights else ""
        interval = f"[{self.lo:+.2f}, {self.hi:+.2f}]"
        if self.verdict == EQUIVALENT and self.replicates is not None and self.margin is not None:
            lo, hi = percentile_interval(self.replicates, EQUIVALENCE_CONFIDENCE)
            few += f" (90% [{lo:+.2f}, {hi:+.2f}] inside ±{self.margin:g}{self.unit.strip()})"
        return f"{self.where}: {self.diff:+.2f} {interval}{self.unit}{few} {sym}"


@dataclass
class Claim:
    """One checked claim. ``difference`` lists the participating comparisons
    (``where: Δ [lo, hi] unit symbol``), ``rule`` says what Δ is and when the claim holds;
    ``comparisons`` and ``excluded`` are the structured evidence
    (``benchmark.runner.claims.findings`` writes its sentences from them)."""

    claim: str
    source: str
    verdict: str
    evidence: str
    difference: str = ""
    rule: str = ""
    comparisons: list[Comparison] = field(default_factory=list)
    excluded: list[str] = field(default_factory=list)
    kind: str = "paper"  # "sanity", "paper", "satellite", "control" or "ranking" (``split``)
    split: str = ""
    facts: dict[str, object] = field(default_factory=dict)  # structured numbers for the prose
    # The verdict of the same claim on the confirmation draw (``confirm/*``, issue 38): set by
    # ``benchmark.runner.claims.all_claims.evaluate_claims``; None before that or without a draw.
    confirmation: Claim | None = None


DISTRIBUTION, REGRESSION = "distribution", "regression"


def head_family(attitude: str) -> str:
    """``"distribution"`` for an attitude head that predicts a density of the rotation (the
    registry class has ``is_probabilistic``, the grid-distribution contract, or ``gives_log_prob``,
    a density that is not a grid distribution: Bingham, matrix Fisher), else ``"regression"``.
    Raises ``ValueError`` naming the known heads for an unknown name."""
    from benchmark.models import get_head_class

    cls = get_head_class(attitude)
    return DISTRIBUTION if cls.is_probabilistic or cls.gives_log_prob else REGRESSION


def unit_of(metric: str) -> str:
    return " m" if metric.endswith("_m") else "°"


def margin_of(metric: str) -> float:
    """The equivalence margin of ``metric`` (``EQUIVALENCE_MARGINS``); KeyError naming the known
    metrics for one without a margin, so a new comparison cannot silently skip the test."""
    try:
        return EQUIVALENCE_MARGINS[metric]
    except KeyError:
        raise KeyError(
            f"no equivalence margin for {metric!r}; margins exist for {sorted(EQUIVALENCE_MARGINS)}"
        ) from None


class Evidence:
    """Per-frame values and participation checks over one :class:`FrameStore`, cached."""

    def __init__(self, frames: FrameStore, n_boot: int = N_BOOT):
        self.frames, self.n_boot = frames, n_boot
        self._beats: dict[tuple, Comparison] = {}

    def values(self, model: Model, split: str, metric: str, satellite: str = "true") -> FrameErrors:
        table, label, x = model
        if metric != TRANSLATION:
            return self.frames.errors(table, label, split, metric, x, satellite)
        parts = [self.frames.errors(table, label, split, m, x, satellite) for m in _AXES]
        return FrameErrors(sum(p.values for p in parts) / 3, *_meta(parts[0]))

    def attitude(self, model: Model) -> str:
        """Registry name of the model's attitude head (from its spec row)."""
        return self.frames.row(*model).get("attitude")

    def family(self, model: Model) -> str:
        """:func:`head_family` of the model's attitude head."""
        return head_family(self.attitude(model))

    def constant(self, model: Model, split: str, metric: str) -> FrameErrors:
        train = self.frames.train_split(*model)
        if metric != TRANSLATION:
            return self.frames.constant(split, metric, train)
        parts = [self.frames.constant(split, m, train) for m in _AXES]
        return FrameErrors(sum(p.values for p in parts) / 3, *_meta(parts[0]))

    def paired(
        self,
        where: str,
        a: FrameErrors,
        b: FrameErrors,
        claimed: int = -1,
        threshold: float = 0.0,
        unit: str = "°",
        margin: float | None = None,
    ) -> Comparison:
        """Δ = a − b per frame (seed means), flights and seeds resampled (the seeds together when
        ``a`` and ``b`` share each seed's run, :func:`shares_seed_runs`); ``margin``: its
        equivalence margin (None: no equivalence test)."""
        if not np.array_equal(a.index, b.index):
            raise ValueError(f"{where}: the two models were evaluated on different frames")
        diff, reps = pooled_replicates(
            b.values, a.values, a.flight, self.n_boot, seed=0, paired_seeds=shares_seed_runs(a, b)
        )
        lo, hi = percentile_interval(reps, CONFIDENCE)
        flights = len(np.unique(a.flight))
        return Comparison(
            where, diff, lo, hi, claimed, threshold, reps, unit=unit, n_flights=flights,
            margin=margin,
        )  # fmt: skip

    def beats_constant(self, model: Model, split: str, metric: str) -> Comparison:
        """err(head) − err(constant) on ``split``; ``verdict`` SUPPORTED when the head is better."""
        key = (model, split, metric)
        if key not in self._beats:
            c = self.paired(
                f"{model[1]} − constant",
                self.values(model, split, metric),
                self.constant(model, split, metric),
                unit=unit_of(metric),
            )
            c.verdict = SUPPORTED if c.hi < 0 and not c.too_few_flights else UNRESOLVED
            self._beats[key] = c
        return self._beats[key]

    def exclusion(self, model: Model, split: str, metric: str) -> str | None:
        """None when the head takes part, else why not: its difference to the constant is not
        clearly below zero, or the split has fewer than ``MIN_FLIGHTS`` flights."""
        c = self.beats_constant(model, split, metric)
        if c.verdict == SUPPORTED:
            return None
        x = f" [{model[2]}]" if model[2] is not None else ""
        return (
            f"{model[1]}{x} on {split} ({NAMES.get(metric, metric)} − constant "
            f"{c.diff:+.2f} [{c.lo:+.2f}, {c.hi:+.2f}]{c.unit}"
            + (f"; {c.n_flights} flight(s))" if c.too_few_flights else ")")
        )

    def compare(
        self, where: str, a: Model, b: Model, split: str, metric: str, excluded: list[str]
    ) -> Comparison | None:
        """A (claimed better) against B on ``split``: None if either was not planned there; an
        EXCLUDED comparison (reason appended to ``excluded``) if either does not beat the
        constant predictor."""
        if not (self.frames.has(*a[:2], split, a[2]) and self.frames.has(*b[:2], split, b[2])):
            return None
        reasons = [r for m in (a, b) if (r := self.exclusion(m, split, metric)) is not None]
        if reasons:
            excluded += [r for r in reasons if r not in excluded]
            return Comparison(where, verdict=EXCLUDED)
        va, vb = self.values(a, split, metric), self.values(b, split, metric)
        return self.paired(where, va, vb, unit=unit_of(metric), margin=margin_of(metric))


_AXES = ("dE_m", "dN_m", "dU_m")


def shares_seed_runs(a: FrameErrors, b: FrameErrors) -> bool:
    """Whether seed s of ``a`` and seed s of ``b`` rest on the same trained run for every s (the
    same seeds, and the same non-empty ``trained_from``)."""
    return bool(a.trained_from) and a.seeds == b.seeds and a.trained_from == b.trained_from


def _meta(f: FrameErrors) -> tuple:
    return f.index, f.flight, f.seeds, f.trained_from


def is_equivalent(c: Comparison) -> bool:
    """Whether ``c``'s 90% interval (``EQUIVALENCE_CONFIDENCE``) lies inside ``(−margin,
    +margin)``: both one-sided tests at 5% reject a difference of the margin or more. False
    without a margin, replicates, or with too few flights."""
    if c.margin is None or c.replicates is None or c.too_few_flights:
        return False
    lo, hi = percentile_interval(c.replicates, EQUIVALENCE_CONFIDENCE)
    return -c.margin < lo and hi < c.margin


def decide(c: Comparison, confidence: float = CONFIDENCE) -> str:
    """Verdict of one comparison: :data:`EQUIVALENT` when :func:`is_equivalent`, else from its
    interval at ``confidence``."""
    if c.replicates is None:
        return c.verdict
    if c.too_few_flights:
        return UNRESOLVED
    if is_equivalent(c):
        return EQUIVALENT
    lo, hi = percentile_interval(c.replicates, confidence)
    below, above = hi < c.threshold, lo > c.threshold
    if (below and c.claimed < 0) or (above and c.claimed > 0):
        return SUPPORTED
    if (above and c.claimed < 0) or (below and c.claimed > 0):
        return CONTRADICTED
    return UNRESOLVED


def combine(comparisons: list[Comparison], equivalent_supports: bool = False) -> str:
    """Set each participating comparison's verdict and combine them by ``COMBINE_RULE``;
    ``equivalent_supports``: the claim states no difference, so an equivalent comparison
    supports it."""
    active = [c for c in comparisons if c.verdict != EXCLUDED and c.replicates is not None]
    if not comparisons:
        return NOT_RUN
    if not active:
        return UNRESOLVED
    corrected = 1 - (1 - CONFIDENCE) / len(active)
    for c in active:
        # Equivalent at 90% (the two one-sided tests); supported at 95% (each of an
        # all-must-hold conjunction); contradicted only at the corrected level (any one of k).
        verdict = decide(c)
        if verdict in (EQUIVALENT, SUPPORTED):
            c.verdict = verdict
        else:
            c.verdict = CONTRADICTED if decide(c, corrected) == CONTRADICTED else UNRESOLVED
    verdicts = {c.verdict for c in active}
    if CONTRADICTED in verdicts:
        return CONTRADICTED
    if EQUIVALENT in verdicts and not equivalent_supports:
        return NO_DIFFERENCE
    return SUPPORTED if verdicts <= {SUPPORTED, EQUIVALENT} else UNRESOLVED


def build_claim(
    claim: str,
    source: str,
    rule: str,
    comparisons: list[Comparison | None],
    excluded: list[str],
    notes: list[str] | None = None,
    equivalent_supports: bool = False,
) -> Claim:
    """Combine comparisons (None = not planned) into a :class:`Claim` with its evidence text
    (``equivalent_supports``: see :func:`combine`)."""
    done = [c for c in comparisons if c is not None]
    verdict = combine(done, equivalent_supports)
    active = [c for c in done if c.verdict != EXCLUDED]
    evidence = list(notes or [])
    if active:
        counts = {v: sum(c.verdict == v for c in active) for v in SYMBOL}
        evidence.insert(
            0,
            f"{len(active)} comparison(s): "
            + ", ".join(f"{n} {v}" for v, n in counts.items() if n),
        )
    elif done:
        evidence.insert(
            0,
            "no comparison takes part: every one has a head that does not beat "
            "the constant predictor",
        )
    if excluded:
        evidence.append(
            "excluded (not better than the constant predictor, or too few flights): "
            + "; ".join(excluded)
        )
    return Claim(
        claim,
        source,
        verdict,
        "; ".join(evidence) or "not run",
        "<br>".join(c.text() for c in active),
        rule,
        done,
        list(excluded),
    )


def safe_claim(build: Callable[[], Claim], claim: str, source: str) -> Claim:
    """Build a claim; a missing predictions file makes it "not run" naming the file."""
    try:
        return build()
    except FileNotFoundError as err:
        return Claim(claim, source, NOT_RUN, str(err))
