"""The reproduction's heading-cue audit: extra dataset seeds, pooling and the README sentence."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from benchmark.errors import InputError
from benchmark.runner.claims.data_audit import heading_cue_audit_markdown, heading_cue_summary
from benchmark.runner.execute.audit import (
    check_cue_datasets,
    cue_dataset_plan,
    cue_dataset_roots,
    heading_cue_rows,
)


@pytest.fixture(scope="module")
def audit(smoke_dataset):
    rows = heading_cue_rows(smoke_dataset, n_extra=1, quiet=True)
    return heading_cue_audit_markdown(rows, n_extra=1), rows


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
        rows = heading_cue_rows(smoke_dataset, n_extra=1, quiet=True)
        assert manifest.stat().st_mtime_ns == before and rows == audit[1]


@pytest.fixture
def data(tmp_path, smoke_dataset) -> Path:
    """A private copy of the smoke dataset, ``tmp_path/ds``: its audit datasets go beside it."""
    return Path(shutil.copytree(smoke_dataset, tmp_path / "ds"))


def stale_copy(data: Path, k: int) -> Path:
    """The ``k``-th audit dataset's place holds its config as another simulator wrote it."""
    from benchmark.data.writer import dataset_config

    root, profile, seed = cue_dataset_plan(data, k)[k - 1]
    config = {**dataset_config(profile, seed), "generator_source": "0123456789ab"}
    root.mkdir(parents=True)
    (root / "config.json").write_text(json.dumps(config))
    return root


class TestCueDatasetsBeforeAnyWork:
    """A reproduction refuses, before training, an audit dataset it could not render over."""

    def test_plan_names_the_next_seeds_beside_the_dataset(self, smoke_dataset):
        plan = cue_dataset_plan(smoke_dataset, 2)
        assert [(root.name, seed) for root, _, seed in plan] == [
            (f"{smoke_dataset.name}-cue-s1", 1),
            (f"{smoke_dataset.name}-cue-s2", 2),
        ]
        assert all(root.parent == smoke_dataset.parent for root, _, _ in plan)
        assert {profile.name for _, profile, _ in plan} == {"smoke-standard"}

    def test_absent_or_this_codes_datasets_pass_and_nothing_is_written(self, tmp_path, data):
        check_cue_datasets(data, 2)
        assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]

    def test_an_earlier_simulators_dataset_is_one_usage_error_naming_it(self, tmp_path, data):
        stale = stale_copy(data, 2)
        before = (stale / "config.json").read_bytes()
        with pytest.raises(InputError) as raised:
            check_cue_datasets(data, 2)
        message = str(raised.value)
        assert message.startswith(f"{stale} holds a heading-cue audit dataset of another")
        assert "(generator_source: existing '0123456789ab' != requested '" in message
        assert "move it away or delete it" in message and "\n" not in message
        assert (stale / "config.json").read_bytes() == before  # untouched
        assert not (tmp_path / "ds-cue-s1").exists()  # nothing rendered on the way

    def test_the_report_stage_says_the_same(self, data):
        """Should one appear after the check, rendering the audit gives the same InputError,
        not the writer's ConfigMismatchError with a traceback."""
        stale_copy(data, 1)
        with pytest.raises(InputError, match="move it away or delete it"):
            cue_dataset_roots(data, 1, quiet=True)

    def test_no_pooled_datasets_nothing_to_check(self, data):
        stale_copy(data, 1)
        check_cue_datasets(data, 0)  # the audit pools no dataset then


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
        assert "0.92x [0.87, 0.99]" in text and "pooled over 2 datasets" in text
        # The interval excludes 1: a weak cue, not "no cue" (issue 38, the committed sentence).
        assert "no global heading cue" not in text
        assert "a weak global heading cue" in text and "weaker than the 0.85 threshold" in text

    @pytest.mark.parametrize(
        ("lo", "hi", "verdict"),
        [
            (0.86, 1.1, "no global heading cue detected (the interval includes 1)"),
            (1.02, 1.2, "no global heading cue (the interval lies above 1"),
            (0.898, 0.992, "a weak global heading cue"),
            (0.5, 0.84, "a global heading cue stronger than the 0.85 threshold"),
            (0.8, 0.9, "whose strength against the 0.85 threshold is not resolved"),
            (0.8, 1.05, "not resolved at this scale (the interval contains both 1 and"),
        ],
    )
    def test_words_follow_the_interval(self, lo, hi, verdict):
        """Each sentence from its interval against 1 and the threshold; "no ... cue" only where
        the interval does not exclude 1 from below."""
        text = heading_cue_summary([self._row("ds", "standard/test", (lo + hi) / 2, lo, hi)])
        assert verdict in text
        says_none = "no global heading cue" in text
        assert says_none == (lo >= 0.85 and hi >= 1.0)
