"""Table specs: the repository's own specs load, and malformed specs fail with file and field."""

from __future__ import annotations

from pathlib import Path

import pytest

from benchmark.models.registry import list_heads
from benchmark.runner.specs import SpecError, load_spec, load_specs

PAPER_ITEMS = {
    "table1",
    "table2",
    "table3",
    "table4",
    "table5",
    "table6",
    "fig5",
    "fig6",
    "fig7",
    "fig9",
}
BEYOND_PAPER = {"leakage", "towns", "extended"}  # issues 9, 10


def write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / f"{name}.yaml"
    path.write_text(text)
    return path


GOOD = """# Paper Table 1: a test table.
name: t1
title: test
kind: table
paper_table: 1
eval_splits: [standard/test]
metrics: [dphi_deg]
variants:
  - {label: A, paper_model: Pd/Re-Net, attitude: pd_re_net}
"""


class TestRepositorySpecs:
    def test_every_paper_table_and_figure_has_a_spec(self):
        assert {s.name for s in load_specs()} == PAPER_ITEMS | BEYOND_PAPER

    def test_heads_exist_in_the_registry(self):
        attitude, translation = set(list_heads("attitude")), set(list_heads("translation"))
        for spec in load_specs():
            for v in spec.variants:
                assert v.attitude in attitude, (spec.name, v.attitude)
                assert v.translation in translation, (spec.name, v.translation)

    def test_first_line_cites_the_paper(self):
        for spec in load_specs():
            first = spec.source.read_text().splitlines()[0]
            if spec.name in BEYOND_PAPER:
                assert first.startswith("# Beyond the paper:")
                continue
            number = spec.paper_table or spec.paper_figure
            assert first.startswith(f"# Paper {'Table' if spec.paper_table else 'Fig.'} {number}:")

    def test_sweeps_substitute_values(self):
        fig7 = {s.name: s for s in load_specs()}["fig7"]
        assert [j.variant.kappa for j in fig7.jobs()] == [1.0, 5.0, 10.0, 20.0, 50.0]
        fig5 = {s.name: s for s in load_specs()}["fig5"]
        assert fig5.jobs()[0].train_split == "height600/train"
        assert fig5.jobs()[0].eval_splits == ("height600/test",)


class TestControlsInSpecs:
    def test_attitude_tables_have_the_control_and_the_swap_columns(self):
        specs = {s.name: s for s in load_specs()}
        for name in ("table1", "table2", "table5", "leakage", "towns"):
            spec = specs[name]
            blank = [v for v in spec.variants if v.satellite_input == "blank"]
            assert blank and all(v.attitude == "pd_re_net" for v in blank), name
            assert {"dpsi_deg", "dphi_deg"} <= set(spec.swap_metrics), name

    def test_leakage_rows_train_on_their_own_split(self):
        leakage = {s.name: s for s in load_specs()}["leakage"]
        pairs = {(j.train_split, j.eval_splits) for j in leakage.jobs()}
        assert pairs == {("standard/train", ("standard/test",)), ("frames/train", ("frames/test",))}
        assert leakage.all_eval_splits() == ["standard/test", "frames/test"]
        assert leakage.train_split_for("frames/test") == "frames/train"


class TestLoadSpec:
    def test_good(self, tmp_path):
        spec = load_spec(write(tmp_path, "t1", GOOD))
        assert spec.variants[0].translation == "regression"
        assert len(spec.jobs()) == 1

    @pytest.mark.parametrize(
        ("old", "new", "message"),
        [
            ("# Paper Table 1: a test table.", "# a table", "first line must cite the paper"),
            ("kind: table", "kind: chart", "kind must be one of"),
            ("name: t1", "name: other", "must equal the file name"),
            ("metrics:", "metricz:", r"unknown fields \['metricz'\]"),
            (
                "attitude: pd_re_net}",
                "attitude: pd_re_net, kappa: -1}",
                "kappa must be a number > 0",
            ),
            (
                "attitude: pd_re_net}",
                "attitude: pd_re_net, colour: red}",
                r"variants\[0\]: unknown fields",
            ),
            ("eval_splits: [standard/test]", "eval_splits: []", "eval_splits must list"),
            (
                "attitude: pd_re_net}",
                "attitude: pd_re_net, satellite_input: grey}",
                "satellite_input must be one of .*'grey'",
            ),
            (
                "attitude: pd_re_net}",
                "attitude: pd_re_net, eval_splits: standard/test}",
                "eval_splits must be a non-empty list",
            ),
        ],
    )
    def test_errors_name_file_and_field(self, tmp_path, old, new, message):
        path = write(tmp_path, "t1", GOOD.replace(old, new))
        with pytest.raises(SpecError, match=message) as info:
            load_spec(path)
        assert str(path) in str(info.value)

    def test_placeholder_outside_sweep(self, tmp_path):
        path = write(
            tmp_path,
            "t1",
            GOOD.replace("attitude: pd_re_net}", 'attitude: pd_re_net, encoder_variant: "{x}"}'),
        )
        with pytest.raises(SpecError, match="outside a sweep"):
            load_spec(path)

    def test_per_variant_splits_and_beyond_the_paper(self, tmp_path):
        text = GOOD.replace("# Paper Table 1: a test table.", "# Beyond the paper: an audit.")
        text = text.replace("paper_table: 1\n", "").replace("eval_splits: [standard/test]\n", "")
        text = text.replace(
            "attitude: pd_re_net}",
            "attitude: pd_re_net, train_split: frames/train, eval_splits: [frames/test],"
            " satellite_input: blank}",
        )
        (job,) = load_spec(write(tmp_path, "t1", text)).jobs()
        assert (job.train_split, job.eval_splits) == ("frames/train", ("frames/test",))
        assert job.variant.satellite_input == "blank"

    def test_unknown_table_in_only(self):
        with pytest.raises(SpecError, match="unknown table"):
            load_specs(only=["table99"])
