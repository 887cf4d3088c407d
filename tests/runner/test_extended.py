"""The ``extended`` table: every attitude head of ``baselines/`` has a row, the paper's heads are
the very units Tables 1-2 train, and the rendered table shows every metric ("–" where a head
gives no density or uncertainty)."""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd
import pytest

from benchmark.models import get_head_class, list_heads
from benchmark.runner.plan.repro_profiles import PROFILES
from benchmark.runner.plan.specs import load_specs
from benchmark.runner.plan.units import plan_units
from benchmark.runner.report.tables import extra_metrics_table, markdown_table

SPLITS = ["standard/train", "standard/val", "standard/test", "generalized/test", "towns/train"]
PAPER_METRICS = ["dtheta_deg", "dgamma_deg", "dpsi_deg", "dphi_deg"]
EXTRA = ["median_dphi_deg", "acc5", "acc10", "acc30", "loglik", "spearman_unc_err"]


def spec(name: str = "extended"):
    return load_specs(only=[name])[0]


def repository_heads() -> list[str]:
    """Attitude heads defined in this repository's ``baselines/`` (a head installed by another
    package through the entry point is that package's business)."""
    return [
        name
        for name in list_heads("attitude")
        if get_head_class(name).__module__.startswith("baselines.")
    ]


class TestEveryHeadHasARow:
    def test_every_registered_attitude_head(self):
        rows = {r.get("attitude") for r in spec().rows}
        missing = [name for name in repository_heads() if name not in rows]
        lines = "\n".join(
            f'  - {{label: {get_head_class(n).paper_name}, paper_model: "", attitude: {n}, '
            'variant: "/"}'
            for n in missing
        )
        assert not missing, (
            f"attitude head(s) {missing} have no row in reports/configs/extended.yaml, the table "
            f"of every representation; add one line per head under 'rows:', e.g.\n{lines}"
        )

    def test_rows_name_registered_heads_once_each(self):
        names = [r.get("attitude") for r in spec().rows]
        assert set(names) <= set(list_heads("attitude"))
        assert len(names) == len(set(names)) and len(names) >= 13

    def test_paper_heads_are_table_one_and_two_units(self):
        """Trained like Tables 1-2 (standard/train, encoder "/", default options): planning them
        together adds only the heads beyond the paper, and each of those one unit."""
        profile = PROFILES["quick"]

        def plan(names):
            return plan_units(load_specs(only=names), profile, [0], Path("/d"), SPLITS, "h")

        both = plan(["table1", "table2", "extended"])
        paper = plan(["table1", "table2"])
        extra = [r for r in spec().rows if not r.paper_model]
        assert len(both) == len(paper) + len(extra)
        for unit in both:
            tables = {j.table for j in unit.jobs}
            if "extended" in tables and any(j.paper_model for j in unit.jobs):
                assert {"table1", "table2"} <= tables, unit.key
            # every row on standard/train; quick's shared encoder on standard/train + towns/train
            expected = profile.shared_encoder.train_split if unit.shared_encoder else None
            assert unit.cfg.data.train_split == (expected or "standard/train")

    def test_columns_and_note(self):
        s = spec()
        assert list(s.metrics) == PAPER_METRICS + EXTRA
        assert list(s.eval_splits) == ["standard/test", "generalized/test"]
        note = " ".join(s.note.split())
        assert "Re-Net-R, the paper's regressed matrix, is Levinson et al.'s \"SVD-Inf\"" in note


def summary_rows(labels_heads: dict[str, str]) -> pd.DataFrame:
    """A summary as ``report.summarize`` gives it: loglik / spearman only for density heads."""
    rows = []
    for i, (label, head) in enumerate(labels_heads.items()):
        cls = get_head_class(head)
        density = cls.is_probabilistic or cls.gives_log_prob
        for split in ("standard/test", "generalized/test"):
            row = {"table": "extended", "label": label, "paper_model": "", "x": None,
                   "split": split, "satellite": "true", "satellite_input": "image",
                   "train_split": "standard/train", "role": "test", "n_seeds": 3,
                   "interval": "seed t"}  # fmt: skip
            for j, m in enumerate(PAPER_METRICS + EXTRA):
                value = 10.0 * i + j + 0.25 if (density or m in PAPER_METRICS + EXTRA[:4]) else None
                value = math.nan if value is None else value
                row |= {m: value, f"{m}_lo": value - 0.5, f"{m}_hi": value + 0.5}
            rows.append(row)
    return pd.DataFrame(rows)


class TestRendered:
    def test_every_column_and_dash_without_density(self):
        rows = {"Pd/Re-Net": "pd_re_net", "Re-Net-R": "re_net_r"}
        text = markdown_table(spec(), summary_rows(rows), pd.DataFrame())
        header = next(line for line in text.splitlines() if line.startswith("| split | model"))
        for label in ("median δφ (°)", "acc@5°", "acc@10°", "acc@30°", "log-lik", "ρ(unc, err)"):
            assert f"| {label} |" in header
        pd_row = next(
            line for line in text.splitlines() if "| `standard/test` | Pd/Re-Net |" in line
        )
        re_row = next(
            line for line in text.splitlines() if "| `standard/test` | Re-Net-R |" in line
        )
        # Pd/Re-Net (i = 0): loglik is column 8 of the metrics -> 8.25; Re-Net-R: "–"
        assert "| 8.25 ± 0.50 | 9.25 ± 0.50 |" in pd_row
        assert re_row.endswith("| – | – | not run | not run |")
        assert "| 14.25 ± 0.50 | 15.25 ± 0.50 | 16.25 ± 0.50 | 17.25 ± 0.50 |" in re_row

    @pytest.mark.parametrize(("name", "expected"), [("extended", False), ("table1", True)])
    def test_further_metrics_only_where_not_columns(self, name, expected):
        summary = summary_rows({"Pd/Re-Net": "pd_re_net"})
        text = extra_metrics_table(spec(name), summary, ["median_dphi_deg", "acc10", "loglik"])
        assert bool(text) is expected
        if expected:
            assert "| `standard/test` | Pd/Re-Net | 4.250 ± 0.500 | 6.250 ± 0.500 |" in text
