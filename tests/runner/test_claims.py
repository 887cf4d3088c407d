"""Claim checks on hand-made summaries: verdicts follow the numbers, noise is not a win."""

from __future__ import annotations

import math

import pandas as pd

from benchmark.runner.claims import (
    CONTRADICTED,
    INCONCLUSIVE,
    NOT_RUN,
    PARTLY,
    SUPPORTED,
    evaluate_claims,
    kappa_claim,
    representation_claim,
    translation_claim,
)

NAN = math.nan


def summary(rows: list[tuple]) -> pd.DataFrame:
    """rows: (label, split, x, {metric: (mean, lo, hi)})"""
    out = []
    for label, split, x, metrics in rows:
        row = {"label": label, "split": split, "x": x}
        for m, (mean, lo, hi) in metrics.items():
            row |= {m: mean, f"{m}_lo": lo, f"{m}_hi": hi}
        out.append(row)
    return pd.DataFrame(out)


def table(split: str, values: dict[str, float]) -> pd.DataFrame:
    return summary([(k, split, None, {"dphi_deg": (v, NAN, NAN)}) for k, v in values.items()])


HEADS = [
    "Pd/Re-Net",
    "Pd-Net-Rv",
    "Pd-Net-E",
    "Pd-Net-Q",
    "Re-Net-R",
    "Re-Net-Rv",
    "Re-Net-E",
    "Re-Net-Q",
]


class TestRepresentationClaim:
    def test_supported_when_matrix_wins_everywhere(self):
        values = dict(zip(HEADS, [5, 9, 9, 9, 6, 9, 9, 9], strict=True))
        s = {"table1": table("standard/test", values), "table2": table("generalized/test", values)}
        assert representation_claim(s).verdict == SUPPORTED

    def test_contradicted_when_matrix_never_wins(self):
        values = dict(zip(HEADS, [9, 5, 5, 5, 9, 5, 5, 5], strict=True))
        assert (
            representation_claim({"table1": table("standard/test", values)}).verdict == CONTRADICTED
        )

    def test_partly(self):
        values = dict(zip(HEADS, [5, 9, 9, 9, 9, 5, 5, 5], strict=True))
        assert representation_claim({"table1": table("standard/test", values)}).verdict == PARTLY

    def test_not_run(self):
        assert representation_claim({}).verdict == NOT_RUN


class TestNoise:
    def test_overlapping_intervals_do_not_count_as_a_win(self):
        s = summary(
            [
                ("Pd/Re-Net", "standard/test", None, {"dphi_deg": (5.0, 3.0, 7.0)}),
                ("Re-Net-R", "standard/test", None, {"dphi_deg": (6.0, 4.0, 8.0)}),
            ]
        )
        claims = {c.source: c for c in evaluate_claims({"table1": s})}
        assert claims["Tables 1-2, δθ δγ δψ δφ"].verdict == CONTRADICTED  # a tie within noise


class TestTranslationClaim:
    def test_distribution_clearly_better_contradicts(self):
        rows = [
            (
                "Pd/Re-Net",
                "standard/test",
                None,
                {m: (10.0, NAN, NAN) for m in ("dE_m", "dN_m", "dU_m")},
            ),
            (
                "Re-Net-T",
                "standard/test",
                None,
                {m: (5.0, NAN, NAN) for m in ("dE_m", "dN_m", "dU_m")},
            ),
        ]
        assert translation_claim({"table3": summary(rows)}).verdict == CONTRADICTED

    def test_similar_errors_support(self):
        rows = [
            (
                "Pd/Re-Net",
                "standard/test",
                None,
                {m: (10.0, NAN, NAN) for m in ("dE_m", "dN_m", "dU_m")},
            ),
            (
                "Re-Net-T",
                "standard/test",
                None,
                {m: (9.5, NAN, NAN) for m in ("dE_m", "dN_m", "dU_m")},
            ),
        ]
        assert translation_claim({"table3": summary(rows)}).verdict == SUPPORTED

    def test_nothing_learned_is_inconclusive(self):
        rows = [
            (label, "standard/test", None, {m: (v, NAN, NAN) for m in ("dE_m", "dN_m", "dU_m")})
            for label, v in (
                ("Pd/Re-Net", 150.0),
                ("Re-Net-T", 152.0),
                ("Constant (train mean)", 151.0),
            )
        ]
        claim = translation_claim({"table3": summary(rows)})
        assert claim.verdict == INCONCLUSIVE and "nothing learned" in claim.evidence


class TestKappaClaim:
    def test_best_kappa(self):
        rows = [("Pd/Re-Net", "standard/test", x, {"dphi_deg": (v, NAN, NAN)}) for x, v in
                (("1", 9), ("5", 7), ("10", 5), ("20", 6), ("50", 8))]  # fmt: skip
        assert kappa_claim({"fig7": summary(rows)}).verdict == SUPPORTED
        rows[0] = ("Pd/Re-Net", "standard/test", "1", {"dphi_deg": (1.0, NAN, NAN)})
        claim = kappa_claim({"fig7": summary(rows)})
        assert claim.verdict == CONTRADICTED and "best κ = 1" in claim.evidence


class TestAllClaims:
    def test_every_claim_reports_not_run_without_results(self):
        claims = evaluate_claims({})
        assert len(claims) == 15
        assert {c.verdict for c in claims} == {NOT_RUN}


def probe_rows(label, split, true_psi, swap_psi, effect, groups=8, blank=False):
    """A model's true and swap summary rows; ``effect``: (diff, lo, hi) of yaw and geodesic."""
    kind = "blank" if blank else "image"
    base = {"label": label, "split": split, "x": None, "satellite_input": kind}
    true = {**base, "satellite": "true", "dpsi_deg": true_psi, "dpsi_deg_lo": NAN,
            "dpsi_deg_hi": NAN}  # fmt: skip
    swap = {**base, "satellite": "swap", "dpsi_deg": swap_psi, "swap_groups": groups}
    for e in ("dpsi", "dphi"):
        swap |= dict(zip([f"swap_{e}_diff_deg", f"swap_{e}_boot_lo_deg", f"swap_{e}_boot_hi_deg"],
                         effect, strict=True))  # fmt: skip
    return [true, swap]


class TestSatelliteClaims:
    def test_uses_and_does_not_use(self):
        from benchmark.runner.claims_satellite import satellite_claim

        rows = probe_rows("Pd/Re-Net", "standard/test", 20.0, 35.0, (15.0, 10.0, 19.0))
        rows += probe_rows("Re-Net-R", "standard/test", 22.0, 22.1, (0.1, -0.3, 0.5))
        rows += probe_rows("Pd-Net-Q", "standard/test", 22.0, 22.3, (0.3, 0.1, 0.5))  # < 1 deg
        rows += probe_rows("UAV-only control", "standard/test", 40.0, 40.0, (0, 0, 0), blank=True)
        claim = satellite_claim(pd.DataFrame(rows), "table1", "standard/test")
        assert claim.verdict == PARTLY
        assert "Pd/Re-Net: uses it" in claim.evidence
        assert "Re-Net-R: does not use it" in claim.evidence
        assert "Pd-Net-Q: does not use it" in claim.evidence
        assert "UAV-only control" not in claim.evidence

    def test_no_head_uses_it_is_said_plainly(self):
        from benchmark.runner.claims_satellite import satellite_claim

        rows = probe_rows("Pd/Re-Net", "towns/test", 90.0, 90.0, (0.0, -0.2, 0.2))
        claim = satellite_claim(pd.DataFrame(rows), "towns", "towns/test")
        assert claim.verdict == CONTRADICTED
        assert "no head uses the satellite image here" in claim.evidence

    def test_one_flight_is_inconclusive(self):
        from benchmark.runner.claims_satellite import satellite_claim

        rows = probe_rows("Pd/Re-Net", "standard/test", 20.0, 30.0, (10, 10, 10), groups=1)
        claim = satellite_claim(pd.DataFrame(rows), "table1", "standard/test")
        assert claim.verdict == INCONCLUSIVE and "one flight" in claim.evidence


class TestControlClaim:
    def frame(self, split, control_psi, constant_psi, head_psi=None):
        rows = []
        for label, psi, kind in (("UAV-only control", control_psi, "blank"),
                                 ("Constant (train mean)", constant_psi, "none"),
                                 ("Pd/Re-Net", head_psi, "image")):  # fmt: skip
            if psi is None:
                continue
            row = {"label": label, "split": split, "x": None, "satellite": "true",
                   "satellite_input": kind}  # fmt: skip
            for m, v in (("dpsi_deg", psi), ("dtheta_deg", 3.0), ("dgamma_deg", 2.0)):
                row |= {m: v, f"{m}_lo": NAN, f"{m}_hi": NAN}
            rows.append(row)
        return pd.DataFrame(rows)

    def test_within_ten_percent_of_the_constant(self):
        from benchmark.runner.claims_satellite import control_claim

        s = {"table2": self.frame("generalized/test", 85.0, 90.0),
             "table1": self.frame("standard/test", 50.0, 90.0, 20.0)}  # fmt: skip
        claim = control_claim(s)
        assert claim.verdict == SUPPORTED and "(0.94x)" in claim.evidence
        assert "57% of Pd/Re-Net's yaw gain" in claim.evidence  # (90 - 50) / (90 - 20)
        s["table2"] = self.frame("generalized/test", 60.0, 90.0)
        assert control_claim(s).verdict == CONTRADICTED
