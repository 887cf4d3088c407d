"""``--only`` reruns keep the other tables' results (``benchmark.runner.partial``)."""

from __future__ import annotations

import pandas as pd
import pytest

import benchmark.data
import benchmark.tracking
from benchmark.runner.execute import UnitResult
from benchmark.runner.outputs import results_frame
from benchmark.runner.partial import earlier_results, in_spec_order, merge_note
from benchmark.runner.plan import plan_units
from benchmark.runner.profiles import get_repro_profile
from benchmark.runner.specs import load_specs

SPLITS = ["standard/train", "standard/val", "standard/test", "generalized/test"]
SPLITS += [f"height{h}/{p}" for h in (600, 800, 1000, 1200, 1400) for p in ("train", "test")]
HASH = "d" * 64
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
    return specs, units, frame, out, tmp_path / "runs"


class TestEarlierResults:
    def test_keeps_the_other_table(self, earlier, tmp_path):
        specs, units, frame, out, workdir = earlier
        rows, kept_specs, kept_units = earlier_results(
            out, [specs[0]], PROFILE, tmp_path / "data", workdir
        )
        assert [s.name for s in kept_specs] == ["fig5"]
        assert set(rows["table"]) == {"fig5"}
        assert len(rows) == (frame["table"] == "fig5").sum()
        # sweep values stay strings: "600" names the model and the split height600/test
        assert set(rows["x"]) == {"600", "800", "1000", "1200", "1400"}
        fig5_units = {u.key for u in units if any(j.table == "fig5" for j in u.jobs)}
        assert {u.key for u in kept_units} == fig5_units
        assert all(j.table == "fig5" for u in kept_units for j in u.jobs)

    def test_nothing_when_every_table_reruns_or_no_file(self, earlier, tmp_path):
        specs, _, _, out, workdir = earlier
        rows, kept, units = earlier_results(out, specs, PROFILE, tmp_path / "data", workdir)
        assert rows.empty and kept == [] and units == []
        rows, kept, _ = earlier_results(tmp_path / "x", specs[:1], PROFILE, tmp_path, workdir)
        assert rows.empty and kept == []

    def test_other_units_dropped_with_a_note(self, earlier, tmp_path, monkeypatch, capsys):
        specs, _, _, out, workdir = earlier
        # Another dataset now: the earlier units are not those this dataset plans.
        monkeypatch.setattr(benchmark.tracking, "manifest_sha256", lambda root: "e" * 64)
        rows, kept, _ = earlier_results(out, [specs[0]], PROFILE, tmp_path / "data", workdir)
        assert rows.empty and kept == []
        assert "not keeping fig5" in capsys.readouterr().err

    def test_missing_predictions_dropped(self, earlier, tmp_path, capsys):
        specs, units, _, out, workdir = earlier
        fig5 = next(u for u in units if all(j.table == "fig5" for j in u.jobs))
        (workdir / "units" / fig5.key / "eval").rmdir()
        rows, kept, _ = earlier_results(out, [specs[0]], PROFILE, tmp_path / "data", workdir)
        assert rows.empty and "predictions missing" in capsys.readouterr().err
        # without a workdir nothing is read from it: the rows are kept
        rows, kept, _ = earlier_results(out, [specs[0]], PROFILE, tmp_path / "data", None)
        assert [s.name for s in kept] == ["fig5"]

    def test_constant_rows_kept(self, earlier, tmp_path):
        specs, _, frame, out, workdir = earlier
        constant = frame[frame["table"] == "fig5"].head(1).assign(unit=None, label="Constant")
        pd.concat([frame, constant]).to_csv(out / "results.csv", index=False)
        rows, _, _ = earlier_results(out, [specs[0]], PROFILE, tmp_path / "data", workdir)
        assert (rows["label"] == "Constant").sum() == 1


class TestNote:
    def test_names_what_was_rerun(self):
        specs = load_specs(None, ["table1", "fig7", "fig5"])
        text = merge_note(specs[:2], specs[2:])
        assert "re-ran `table1`, `fig7`" in text and "`fig5` come from an earlier" in text
        assert "decided again" in text
        assert merge_note(specs, []) == ""
        assert [s.name for s in in_spec_order([specs[0], specs[2], specs[0]])] == [
            "fig5",
            "table1",
        ]
