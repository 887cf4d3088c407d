"""``uavbench compare`` (issue 40 item 2): the same units of two workdirs, on the same frames.

The references are closed forms: a constant per-frame difference has every bootstrap replicate
equal to it; per-flight differences drawn from a normal law have the 95 % interval
``mean ± 1.96 sd / sqrt(G)`` of the flight means (many flights, one seed).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from benchmark.cli import main
from benchmark.errors import InputError
from benchmark.runner.claims.evidence import EQUIVALENCE_MARGINS, MIN_FLIGHTS
from benchmark.runner.compare import (
    DIFFERENT,
    EQUIVALENT,
    UNDECIDED,
    claim_verdicts,
    compare_units,
    read_units,
    variant_labels,
    variant_of,
    verdict_changes_markdown,
    verdict_of,
)

BASE = {"model.attitude": "pd_re_net", "optim.lr": 0.0003, "model.encoder": "matching"}


def frames(n_flights: int, per_flight: int, rng: np.random.Generator) -> pd.DataFrame:
    n = n_flights * per_flight
    out = pd.DataFrame({
        "index": np.arange(n), "flight": np.repeat(np.arange(n_flights), per_flight),
        "yaw_deg": rng.uniform(-180, 180, n), "pitch_deg": rng.uniform(-20, 0, n),
        "roll_deg": rng.uniform(-5, 5, n), "E_m": rng.normal(0, 50, n),
        "N_m": rng.normal(0, 50, n), "U_m": rng.normal(300, 10, n),
    })  # fmt: skip
    for col in ("dphi_deg", "dpsi_deg", "dtheta_deg", "dgamma_deg"):
        out[col] = rng.uniform(0, 40, n)
    for col in ("dE_m", "dN_m", "dU_m"):
        out[col] = rng.normal(0, 30, n)
    return out


def write_unit(root: Path, key: str, config: dict, table: pd.DataFrame,
               split: str = "standard/val") -> None:  # fmt: skip
    unit = root / "units" / key
    (unit / "eval").mkdir(parents=True)
    (unit / "config.json").write_text(json.dumps(config))
    table.to_csv(unit / "eval" / f"{split.replace('/', '__')}.csv", index=False)


def two_workdirs(tmp_path: Path, shift: dict[str, float], seeds: int = 2, n_flights: int = 30):
    """A and B with the same variant and seeds; B's errors = A's + ``shift`` per column."""
    rng = np.random.default_rng(0)
    a, b = tmp_path / "a", tmp_path / "b"
    for s in range(seeds):
        table = frames(n_flights, 4, rng)
        write_unit(a, f"a{s}", {**BASE, "seed": s, "precision": "fp32"}, table)
        shifted = table.copy()
        for col, value in shift.items():
            shifted[col] = shifted[col] + value
        write_unit(b, f"b{s}", {**BASE, "seed": s, "precision": "bf16", "pretrained.key": "x",
                                "device": "cpu", "data.root": "elsewhere"}, shifted)  # fmt: skip
    return a / "units", b / "units"


class TestVerdictOf:
    def test_inside_the_margin_is_equivalent(self) -> None:
        assert verdict_of(-1.5, 1.5, -1.2, 1.2, 2.0, MIN_FLIGHTS) == EQUIVALENT

    def test_excluding_zero_outside_the_margin_is_different(self) -> None:
        assert verdict_of(0.5, 4.0, 0.8, 3.5, 2.0, MIN_FLIGHTS) == DIFFERENT

    def test_a_small_real_difference_is_still_equivalent(self) -> None:
        # excludes 0 and lies inside the margin: no practical difference wins
        assert verdict_of(0.2, 0.9, 0.3, 0.8, 2.0, MIN_FLIGHTS) == EQUIVALENT

    def test_wide_interval_is_undecided(self) -> None:
        assert verdict_of(-5.0, 3.0, -4.0, 2.5, 2.0, MIN_FLIGHTS) == UNDECIDED

    def test_too_few_flights_is_undecided(self) -> None:
        assert verdict_of(-0.1, 0.1, -0.1, 0.1, 2.0, MIN_FLIGHTS - 1) == UNDECIDED


class TestVariantOf:
    def test_run_fields_and_frozen_encoder_do_not_make_another_variant(self) -> None:
        a = {**BASE, "seed": 0, "precision": "fp32", "device": "cpu", "data.root": "d1",
             "pretrained.key": "k1", "pretrained.checkpoint": "c1"}  # fmt: skip
        b = {**BASE, "seed": 3, "precision": "bf16", "device": "cuda", "data.root": "d2",
             "pretrained.key": "k2", "pretrained.checkpoint": "c2"}  # fmt: skip
        assert variant_of(a) == variant_of(b)

    def test_a_training_setting_makes_another_variant(self) -> None:
        assert variant_of({**BASE, "optim.lr": 0.001}) != variant_of(BASE)

    def test_labels_name_only_what_differs(self) -> None:
        v1, v2 = variant_of(BASE), variant_of({**BASE, "model.attitude": "matrix_fisher"})
        labels = variant_labels([v1, v2])
        assert labels == {v1: "attitude=pd_re_net", v2: "attitude=matrix_fisher"}


class TestCompareUnits:
    def test_a_constant_shift_is_the_difference_with_a_degenerate_interval(self, tmp_path) -> None:
        a, b = two_workdirs(tmp_path, {"dphi_deg": 0.5, "dpsi_deg": 3.0})
        diffs, left = compare_units(a, b, n_boot=500)
        got = {d.error: d for d in diffs}
        assert got["dphi_deg"].diff == pytest.approx(0.5)
        assert got["dphi_deg"].lo == pytest.approx(0.5) and got["dphi_deg"].hi == pytest.approx(0.5)
        assert got["dphi_deg"].verdict == EQUIVALENT
        assert got["dpsi_deg"].diff == pytest.approx(3.0) and got["dpsi_deg"].verdict == DIFFERENT
        assert got["dtheta_deg"].diff == pytest.approx(0.0)
        assert got["dphi_deg"].margin == EQUIVALENCE_MARGINS["dphi_deg"]
        assert not any(left.values())

    def test_translation_is_the_mean_absolute_axis_error(self, tmp_path) -> None:
        a, b = two_workdirs(tmp_path, {})
        # B's E error flips sign: |dE| is unchanged, so the translation difference is zero
        for csv in sorted(b.glob("*/eval/standard__val.csv")):
            table = pd.read_csv(csv)
            table["dE_m"] = -table["dE_m"]
            table.to_csv(csv, index=False)
        diffs, _ = compare_units(a, b, n_boot=200)
        assert {d.error: d for d in diffs}["dT_m"].diff == pytest.approx(0.0, abs=1e-12)

    def test_interval_matches_the_normal_closed_form_over_flights(self, tmp_path) -> None:
        rng = np.random.default_rng(1)
        g, per = 400, 3
        table = frames(g, per, rng)
        a, b = tmp_path / "a", tmp_path / "b"
        write_unit(a, "a0", {**BASE, "seed": 0}, table)
        flight_shift = rng.normal(1.0, 2.0, g)  # one difference per flight
        shifted = table.copy()
        shifted["dphi_deg"] = shifted["dphi_deg"] + np.repeat(flight_shift, per)
        write_unit(b, "b0", {**BASE, "seed": 0}, shifted)
        diffs, _ = compare_units(a / "units", b / "units", n_boot=4000)
        d = {x.error: x for x in diffs}["dphi_deg"]
        half = 1.96 * flight_shift.std(ddof=1) / math.sqrt(g)
        assert d.diff == pytest.approx(flight_shift.mean(), abs=1e-9)
        assert d.lo == pytest.approx(d.diff - half, abs=0.12 * half)
        assert d.hi == pytest.approx(d.diff + half, abs=0.12 * half)

    def test_other_frames_are_refused_naming_both_files(self, tmp_path) -> None:
        a, b = two_workdirs(tmp_path, {}, seeds=1)
        csv = next(b.glob("*/eval/standard__val.csv"))
        table = pd.read_csv(csv)
        table.loc[0, "yaw_deg"] += 10.0
        table.to_csv(csv, index=False)
        with pytest.raises(InputError, match="not the same frames") as err:
            compare_units(a, b, n_boot=10)
        assert str(csv) in str(err.value)

    def test_variants_without_a_partner_or_table_are_listed_not_compared(self, tmp_path) -> None:
        a, b = two_workdirs(tmp_path, {}, seeds=1)
        rng = np.random.default_rng(2)
        write_unit(a.parent, "lonely", {**BASE, "optim.lr": 0.1, "seed": 0}, frames(6, 2, rng))
        write_unit(a.parent, "nosplit", {**BASE, "optim.lr": 0.2, "seed": 0}, frames(6, 2, rng),
                   split="towns/val")  # fmt: skip
        write_unit(b.parent, "nosplit", {**BASE, "optim.lr": 0.2, "seed": 0}, frames(6, 2, rng),
                   split="towns/val")  # fmt: skip
        diffs, left = compare_units(a, b, n_boot=10)
        assert len(left["only in A"]) == 1 and len(left["no table"]) == 1
        assert {d.variant for d in diffs} == {variant_of(BASE)}

    def test_two_units_of_one_variant_and_seed_are_refused(self, tmp_path) -> None:
        rng = np.random.default_rng(3)
        for key in ("k1", "k2"):
            write_unit(tmp_path, key, {**BASE, "seed": 0}, frames(6, 2, rng))
        with pytest.raises(InputError, match="k1 and k2"):
            read_units(tmp_path / "units")

    def test_an_empty_workdir_is_refused(self, tmp_path) -> None:
        with pytest.raises(InputError, match="no such units directory"):
            read_units(tmp_path / "missing")


class TestCompareCommand:
    def test_writes_markdown_and_csv(self, tmp_path, capsys) -> None:
        a, b = two_workdirs(tmp_path, {"dphi_deg": 0.25})
        out = tmp_path / "report" / "precision.md"
        code = main(["compare", str(a.parent), str(b.parent), "--a-name", "fp32", "--b-name",
                     "bf16", "--out", str(out), "--n-boot", "200"])  # fmt: skip
        assert code == 0
        text = out.read_text()
        assert "bf16 against fp32" in text and "δφ: 1 equivalent" in text
        table = pd.read_csv(out.with_suffix(".csv"))
        assert set(table["error"]) == {"dphi_deg", "dpsi_deg", "dtheta_deg", "dgamma_deg", "dT_m"}

    def test_bad_workdir_exits_2_with_the_path(self, tmp_path, capsys) -> None:
        code = main(["compare", str(tmp_path / "nope"), str(tmp_path / "nope2")])
        assert code == 2
        assert str(tmp_path / "nope" / "units") in capsys.readouterr().err


CLAIMS = """# report

| # | claim | evidence | verdict | confirmation |
|---|---|---|---|---|
| 1 | a wins | x: -1.0 [-2, -0.5] | **supported** | **supported**<br>x |
| 2 | b ties | y | **contradicted (no practical difference)** | **not resolved at this scale** |
| 3 | c | z | **supported** | - |
"""


class TestClaimVerdicts:
    def test_reads_each_draws_verdict(self, tmp_path) -> None:
        readme = tmp_path / "README.md"
        readme.write_text(CLAIMS)
        assert claim_verdicts(readme) == {
            1: ["supported", "supported"],
            2: ["contradicted (no practical difference)", "not resolved at this scale"],
            3: ["supported"],
        }

    def test_changes_are_listed_draw_by_draw(self, tmp_path) -> None:
        a, b = tmp_path / "a.md", tmp_path / "b.md"
        a.write_text(CLAIMS)
        b.write_text(
            CLAIMS.replace("| **supported** | - |", "| **not resolved at this scale** | - |")
        )
        text = verdict_changes_markdown(a, b, a_name="fp32", b_name="bf16")
        assert "2 of 3 claims have the same verdicts" in text
        assert "| 3 | supported | not resolved at this scale |" in text

    def test_a_file_without_claims_is_refused(self, tmp_path) -> None:
        readme = tmp_path / "README.md"
        readme.write_text("# nothing here\n")
        with pytest.raises(InputError, match="no claims table"):
            claim_verdicts(readme)
