"""The reproduction's heading-cue audit: extra dataset seeds, pooling and the README sentence."""

from __future__ import annotations

import json

import pytest

from benchmark.runner.claims.data_audit import heading_cue_report, heading_cue_summary


@pytest.fixture(scope="module")
def audit(smoke_dataset):
    return heading_cue_report(smoke_dataset, n_extra=1, quiet=True)


class TestHeadingCueReport:
    def test_extra_dataset_is_the_next_seed_with_standard_splits_only(self, smoke_dataset, audit):
        extra = smoke_dataset.parent / f"{smoke_dataset.name}-cue-s1"
        config = json.loads((extra / "config.json").read_text())
        assert config["seed"] == 1 and config["profile"]["name"] == "smoke-standard"
        splits = set(json.loads((extra / "manifest.json").read_text())["splits"])
        # generalized/{train,val} name the standard ones (the paper trains both on them)
        assert {"standard/train", "standard/val", "standard/test"} <= splits
        assert not {s for s in splits if not s.startswith(("standard/", "generalized/"))}
        assert "generalized/test" not in splits

    def test_pooled_rows_sum_the_datasets(self, smoke_dataset, audit):
        _, rows = audit
        for split in ("standard/val", "standard/test"):
            per = [r for r in rows if r["split"] == split and r["dataset"] != "pooled"]
            pooled = next(r for r in rows if r["split"] == split and r["dataset"] == "pooled")
            assert [r["dataset"] for r in per] == [
                smoke_dataset.name,
                f"{smoke_dataset.name}-cue-s1",
            ]
            assert pooled["n"] == sum(r["n"] for r in per)
            assert pooled["flights"] == sum(r["flights"] for r in per)
            # the pooled ratio is the ratio of summed errors: between the two datasets' ratios
            ratios = [r["ratio"] for r in per]
            assert min(ratios) - 1e-12 <= pooled["ratio"] <= max(ratios) + 1e-12
        # the other families are audited on the reproduction's dataset only
        assert {r["dataset"] for r in rows if r["train"] == "towns/train"} == {smoke_dataset.name}

    def test_markdown_has_a_row_per_audited_split(self, audit):
        md, rows = audit
        assert md.count("| pooled |") == 2 and len(rows) == md.count("\n| ") - 1

    def test_rerun_reuses_the_rendered_dataset(self, smoke_dataset, audit):
        manifest = smoke_dataset.parent / f"{smoke_dataset.name}-cue-s1" / "manifest.json"
        before = manifest.stat().st_mtime_ns
        _, rows = heading_cue_report(smoke_dataset, n_extra=1, quiet=True)
        assert manifest.stat().st_mtime_ns == before and rows == audit[1]


class TestHeadingCueSummary:
    @staticmethod
    def _row(dataset, split, ratio, lo, hi):
        return {"train": "standard/train", "split": split, "dataset": dataset, "n": 10,
                "flights": 4, "probe_deg": 80.0, "constant_deg": 90.0, "ratio": ratio,
                "ratio_lo": lo, "ratio_hi": hi}  # fmt: skip

    def test_verdict_reads_the_pooled_row(self):
        rows = [
            self._row("quick-s0", "standard/test", 0.79, 0.69, 0.93),
            self._row("quick-s0-cue-s1", "standard/test", 0.98, 0.86, 1.15),
            self._row("pooled", "standard/test", 0.92, 0.87, 0.99),
        ]
        text = heading_cue_summary(rows)
        assert "0.92x [0.87, 0.99]" in text and "no global heading cue" in text
        assert "pooled over 2 datasets" in text

    @pytest.mark.parametrize(
        ("lo", "hi", "verdict"),
        [(0.86, 1.1, "no global heading cue"), (0.5, 0.84, "a heading cue remains"),
         (0.8, 0.9, "not resolved")],
    )  # fmt: skip
    def test_no_interval_no_verdict(self, lo, hi, verdict):
        text = heading_cue_summary([self._row("ds", "standard/test", (lo + hi) / 2, lo, hi)])
        assert verdict in text
