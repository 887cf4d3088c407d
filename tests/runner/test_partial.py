"""``--only`` reruns: the other tables are kept live, kept and marked as from an earlier run, or
dropped (``benchmark.runner.plan.partial``); the end-to-end check is ``test_partial_rerun.py``."""

from __future__ import annotations

import json

import pandas as pd
import pytest

import benchmark.data
import benchmark.tracking
from benchmark.runner.claims.earlier import EarlierTableError, MergedFrameStore, mark_earlier_claims
from benchmark.runner.claims.evidence import NOT_RUN, Claim, safe_claim
from benchmark.runner.claims.findings import findings_markdown
from benchmark.runner.claims.report_numbers import results_frame
from benchmark.runner.execute.worker import UnitResult
from benchmark.runner.plan.partial import (
    BANNER_BEGIN,
    EARLIER,
    STALE_COLUMN,
    earlier_results,
    in_spec_order,
    mark_earlier_files,
    plan_merge,
    short_commit,
    strip_banner,
)
from benchmark.runner.plan.repro_profiles import get_repro_profile
from benchmark.runner.plan.specs import load_specs
from benchmark.runner.plan.units import plan_units

SPLITS = ["standard/train", "standard/val", "standard/test", "generalized/test"]
SPLITS += [f"height{h}/{p}" for h in (600, 800, 1000, 1200, 1400) for p in ("train", "test")]
HASH = "d" * 64
COMMIT = "1fe0c263a8db748e2d7fe88afa2f84e3b8d493de-dirty"
PROFILE = get_repro_profile("smoke")


@pytest.fixture
def earlier(tmp_path, monkeypatch):
    """An earlier reproduction of table1 and fig5 (2 seeds): its results.csv in ``out`` and its
    units' eval directories under ``workdir``; the dataset's splits and digest faked."""
    monkeypatch.setattr(benchmark.data, "list_splits", lambda root: SPLITS)
    monkeypatch.setattr(benchmark.tracking, "manifest_sha256", lambda root: HASH)
    specs = load_specs(None, ["table1", "fig5"])
    units = plan_units(specs, PROFILE, [0, 1], tmp_path / "data", SPLITS, HASH)
    results = {}
    for unit in units:
        keys = [*unit.eval_splits, *([unit.cfg.data.val_split] * bool(unit.cfg.data.val_split))]
        metrics = {
            f"{s}{m}": {"dphi_deg": 10.0 + unit.cfg.seed} for s in keys for m in ("", "/swap")
        }
        results[unit.key] = UnitResult(unit.key, True, metrics=metrics, seconds=2.0)
        (tmp_path / "runs" / "units" / unit.key / "eval").mkdir(parents=True)
    out = tmp_path / "reports"
    out.mkdir()
    frame = results_frame(units, results)
    frame.to_csv(out / "results.csv", index=False)
    for spec in specs:
        (out / f"{spec.name}.md").write_text(f"## {spec.title}\n\n| model | δφ |\n")
    (out / "fig5.png").write_bytes(b"png")
    provenance = {"git_commit": COMMIT, "dataset": {"manifest_sha256": HASH},
                  "written": "2026-12-01 21:40 UTC", "units": {u.key: {"title": u.title}
                                                              for u in units}}  # fmt: skip
    (out / "provenance.json").write_text(json.dumps(provenance))
    return specs, units, frame, out, tmp_path / "runs"


def other_dataset(monkeypatch) -> None:
    """Today's dataset is another one: none of the earlier units is planned today."""
    monkeypatch.setattr(benchmark.tracking, "manifest_sha256", lambda root: "e" * 64)


class TestEarlierResults:
    def test_keeps_the_other_table(self, earlier, tmp_path):
        specs, units, frame, out, workdir = earlier
        rows, kept_specs, kept_units = earlier_results(
            out, [specs[0]], PROFILE, tmp_path / "data", workdir
        )
        assert [s.name for s in kept_specs] == ["fig5"]
        assert set(rows["table"]) == {"fig5"}
        assert len(rows) == (frame["table"] == "fig5").sum()
        assert set(rows[STALE_COLUMN]) == {""}  # live rows: decided by the new report
        # sweep values stay strings: "600" names the model and the split height600/test
        assert set(rows["x"]) == {"600", "800", "1000", "1200", "1400"}
        fig5_units = {u.key for u in units if any(j.table == "fig5" for j in u.jobs)}
        assert {u.key for u in kept_units} == fig5_units
        assert all(j.table == "fig5" for u in kept_units for j in u.jobs)

    def test_nothing_when_every_table_reruns_or_no_file(self, earlier, tmp_path):
        specs, _, _, out, workdir = earlier
        rows, kept, units = earlier_results(out, specs, PROFILE, tmp_path / "data", workdir)
        assert rows.empty and kept == [] and units == []
        plan = plan_merge(tmp_path / "x", specs[:1], PROFILE, tmp_path, workdir)
        assert plan.rows().empty and plan.earlier == [] and plan.describe() == ""
        assert plan.markdown() == ""

    def test_other_dataset_kept_and_marked(self, earlier, tmp_path, monkeypatch):
        specs, _, frame, out, workdir = earlier
        other_dataset(monkeypatch)
        plan = plan_merge(out, [specs[0]], PROFILE, tmp_path / "data", workdir)
        assert plan.live == [] and [t.name for t in plan.earlier] == ["fig5"]
        (fig5,) = plan.kept
        assert fig5.commit == COMMIT and fig5.dataset == HASH
        assert "another dataset" in fig5.why and "dddddddddddd" in fig5.why
        rows = plan.rows()
        assert len(rows) == (frame["table"] == "fig5").sum()
        assert set(rows[STALE_COLUMN]) == {COMMIT}
        # the earlier report's digests of those units go with them
        assert set(plan.earlier_units) == set(rows["unit"].dropna())
        said = plan.describe()
        assert "fig5 (run at 1fe0c26-dirty): its units were trained on another dataset" in said
        assert "--stale drop" in said and "--only fig5,table1" in said
        md = plan.markdown()
        assert "## Partial rerun" in md and "- `fig5` at `1fe0c26-dirty`:" in md

    def test_drop_mode(self, earlier, tmp_path, monkeypatch):
        specs, _, _, out, workdir = earlier
        other_dataset(monkeypatch)
        plan = plan_merge(out, [specs[0]], PROFILE, tmp_path / "data", workdir, mode="drop")
        assert plan.rows().empty and plan.kept == [] and [t.name for t in plan.removed] == ["fig5"]
        assert "removed with their rows, files and README lines" in plan.describe()
        assert sorted(p.name for p in mark_earlier_files(out, plan)) == ["fig5.md", "fig5.png"]
        assert not (out / "fig5.md").exists() and not (out / "fig5.png").exists()
        assert "Removed, with their rows, files and findings" in plan.markdown()
        with pytest.raises(ValueError, match="stale mode 'remove'"):
            plan_merge(out, [specs[0]], PROFILE, tmp_path / "data", workdir, mode="remove")

    def test_missing_predictions_marked(self, earlier, tmp_path):
        specs, units, _, out, workdir = earlier
        fig5 = next(u for u in units if all(j.table == "fig5" for j in u.jobs))
        (workdir / "units" / fig5.key / "eval").rmdir()
        plan = plan_merge(out, [specs[0]], PROFILE, tmp_path / "data", workdir)
        assert plan.live == [] and "predictions are gone" in plan.earlier[0].why
        # without a workdir nothing is read from it: the rows are kept live
        _rows, kept, _ = earlier_results(out, [specs[0]], PROFILE, tmp_path / "data", None)
        assert [s.name for s in kept] == ["fig5"]

    def test_constant_rows_kept(self, earlier, tmp_path):
        specs, _, frame, out, workdir = earlier
        constant = frame[frame["table"] == "fig5"].head(1).assign(unit=None, label="Constant")
        pd.concat([frame, constant]).to_csv(out / "results.csv", index=False)
        rows, _, _ = earlier_results(out, [specs[0]], PROFILE, tmp_path / "data", workdir)
        assert (rows["label"] == "Constant").sum() == 1

    def test_a_file_without_rows_is_from_an_earlier_run(self, earlier, tmp_path):
        specs, _, _, out, workdir = earlier
        (out / "table2.md").write_text("## Table 2\n")
        plan = plan_merge(out, [specs[0]], PROFILE, tmp_path / "data", workdir)
        assert [s.name for s in plan.live] == ["fig5"]
        (table2,) = plan.earlier
        assert table2.name == "table2" and "no rows of it" in table2.why

    def test_marked_twice_keeps_the_first_commit(self, earlier, tmp_path, monkeypatch):
        """A table already kept from an earlier run keeps that run's commit and reason when the
        report is rerun again at another commit."""
        specs, _, _frame, out, workdir = earlier
        other_dataset(monkeypatch)
        plan = plan_merge(out, [specs[0]], PROFILE, tmp_path / "data", workdir)
        mark_earlier_files(out, plan)
        plan.rows().to_csv(out / "results.csv", index=False)
        record = {"git_commit": "f" * 40, "dataset": {"manifest_sha256": "e" * 64},
                  "earlier_tables": {"fig5": plan.kept[0].record()}}  # fmt: skip
        (out / "provenance.json").write_text(json.dumps(record))
        again = plan_merge(out, [specs[0]], PROFILE, tmp_path / "data", workdir)
        assert again.kept == plan.kept
        mark_earlier_files(out, again)
        text = (out / "fig5.md").read_text()
        assert text.count(BANNER_BEGIN) == 1 and "1fe0c26-dirty" in text
        assert strip_banner(text).startswith("## ")


MACHINE = {"cpu_model": "AMD EPYC", "cpu_flags": "avx2 fma avx512f avx512_bf16",
           "cpu_signature": "cpu family 26, model 2, stepping 1", "hostname": "vm"}  # fmt: skip


class TestMachine:
    """Issue 38: a kept table says which machine made it (the CPU kind changes trained numbers,
    DEVELOPERS.md, Machine): its banner and provenance record name the CPU model, signature and
    flags the earlier report recorded."""

    def test_the_banner_names_the_earlier_machine(self, earlier, tmp_path, monkeypatch):
        specs, _, _, out, workdir = earlier
        prov = json.loads((out / "provenance.json").read_text())
        (out / "provenance.json").write_text(json.dumps({**prov, "machine": MACHINE}))
        other_dataset(monkeypatch)
        plan = plan_merge(out, [specs[0]], PROFILE, tmp_path / "data", workdir)
        mark_earlier_files(out, plan)
        first = (out / "fig5.md").read_text().split("\n")[1]
        described = ("AMD EPYC (cpu family 26, model 2, stepping 1; CPU flags avx2 fma avx512f "
                     "avx512_bf16)")  # fmt: skip
        assert f", written 2026-12-01 21:40 UTC on {described}." in first
        assert plan.kept[0].record()["machine"] == described
        # kept again by a later report on another machine: still the machine that made it
        plan.rows().to_csv(out / "results.csv", index=False)
        record = {"git_commit": "f" * 40, "machine": {"cpu_model": "Intel Xeon"},
                  "earlier_tables": {"fig5": plan.kept[0].record()}}  # fmt: skip
        (out / "provenance.json").write_text(json.dumps(record))
        again = plan_merge(out, [specs[0]], PROFILE, tmp_path / "data", workdir)
        mark_earlier_files(out, again)
        text = (out / "fig5.md").read_text()
        assert described in text and "Intel Xeon" not in text

    def test_without_a_recorded_machine_it_says_so(self, earlier, tmp_path, monkeypatch):
        specs, _, _, out, workdir = earlier
        other_dataset(monkeypatch)
        plan = plan_merge(out, [specs[0]], PROFILE, tmp_path / "data", workdir)
        mark_earlier_files(out, plan)
        assert "(that report names no machine)." in (out / "fig5.md").read_text()


class TestClaims:
    def test_a_claim_needing_an_earlier_table_is_not_redecided(
        self, earlier, tmp_path, monkeypatch
    ):
        specs, units, _, out, workdir = earlier
        other_dataset(monkeypatch)
        plan = plan_merge(out, [specs[0]], PROFILE, tmp_path / "data", workdir)
        table1 = [u for u in units if all(j.table == "table1" for j in u.jobs)]
        store = MergedFrameStore(workdir, tmp_path / "data", table1, plan.kept,
                                 plan.earlier_specs)  # fmt: skip
        # the earlier table's models are known (the claims see what they would compare) ...
        assert store.has("fig5", "Pd/Re-Net", "height600/test", "600")
        assert store.xs("fig5", "Pd/Re-Net") == ["600", "800", "1000", "1200", "1400"]
        # ... but its per-frame values are refused, as a FileNotFoundError (safe_claim)
        with pytest.raises(EarlierTableError, match="`fig5` is from an earlier run at"):
            store.errors("fig5", "Pd/Re-Net", "height600/test", "dphi_deg", "600")

        def build():
            store.errors("fig5", "Pd/Re-Net", "height600/test", "dphi_deg", "600")

        claims = [safe_claim(build, "fig5 claim", "Fig. 5"), Claim("other", "x", NOT_RUN, "")]
        mark_earlier_claims(claims, plan)
        assert [c.verdict for c in claims] == [EARLIER, NOT_RUN]
        assert claims[0].facts["earlier"] == ("fig5", COMMIT)
        text = findings_markdown(claims, {"fig5": COMMIT})
        assert text.splitlines()[0] == (
            f"Of 2 claims checked: 1 not run, 1 {EARLIER} (on the main test splits)."
        )
        assert (
            "- **from an earlier run at `1fe0c26-dirty`, not re-decided**: `fig5` (kept as "
            "written by that run, see *Partial rerun*); claim 1 uses them and is not "
            "re-decided." in text
        )
        assert "- **not run**: claim 2." in text


class TestNote:
    def test_names_what_was_rerun(self, earlier, tmp_path):
        specs, _, _, out, workdir = earlier
        text = plan_merge(out, [specs[0]], PROFILE, tmp_path / "data", workdir).markdown()
        assert "re-ran `table1`" in text and "decided again" in text and "`fig5`" in text
        assert [s.name for s in in_spec_order([specs[0], specs[1], specs[0]])] == [
            "fig5",
            "table1",
        ]
        assert short_commit(COMMIT) == "1fe0c26-dirty" and short_commit("unknown") == "unknown"
