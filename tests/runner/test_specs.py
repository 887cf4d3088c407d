"""Table specs: the repository's own specs load, and malformed specs fail with file and field."""

from __future__ import annotations

from pathlib import Path

import pytest

from benchmark.models.model_config import ModelConfig
from benchmark.models.registry import list_heads
from benchmark.runner.plan.specs import SpecError, load_spec, load_specs

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
BEYOND_PAPER = {"leakage", "towns", "extended", "encoders", "sequence"}  # issues 9, 10, 21, 39


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
rows:
  - {label: A, paper_model: Pd/Re-Net, attitude: pd_re_net}
"""


class TestRepositorySpecs:
    def test_every_paper_table_and_figure_has_a_spec(self):
        assert {s.name for s in load_specs()} == PAPER_ITEMS | BEYOND_PAPER

    def test_heads_exist_in_the_registry(self):
        attitude, translation = set(list_heads("attitude")), set(list_heads("translation"))
        for spec in load_specs():
            for row in spec.rows:
                assert row.get("attitude") in attitude, (spec.name, row.get("attitude"))
                assert row.get("translation") in translation, (spec.name, row.get("translation"))

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
        kappas = [j.row.get("attitude_options")["kappa"] for j in fig7.jobs()]
        assert kappas == [1, 5, 10, 20, 50]  # YAML scalars; ModelConfig types them as floats
        assert [j.row.model_config().attitude_options for j in fig7.jobs()] == [
            {"kappa": 1.0}, {"kappa": 5.0}, {}, {"kappa": 20.0}, {"kappa": 50.0},
        ]  # fmt: skip
        fig5 = {s.name: s for s in load_specs()}["fig5"]
        assert fig5.jobs()[0].train_split == "height600/train"
        assert fig5.jobs()[0].eval_splits == ("height600/test",)


class TestControlsInSpecs:
    def test_attitude_tables_have_the_control_and_the_swap_columns(self):
        specs = {s.name: s for s in load_specs()}
        for name in ("table1", "table2", "table5", "leakage", "towns"):
            spec = specs[name]
            blank = [r for r in spec.rows if r.get("satellite_input") == "blank"]
            assert blank and all(r.get("attitude") == "pd_re_net" for r in blank), name
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
        assert spec.rows[0].get("translation") == "regression"
        assert len(spec.jobs()) == 1

    def test_a_row_is_the_plain_encoder_unless_it_names_a_variant(self, tmp_path):
        """ModelConfig's default variant is the paper's AGTFM ("a-f"); a row's is "/"."""
        (row,) = load_spec(write(tmp_path, "t1", GOOD)).rows
        assert ModelConfig().variant == "a-f" and row.get("variant") == "/"
        assert row.model_config().variant == "/"
        named = GOOD.replace("attitude: pd_re_net}", 'attitude: pd_re_net, variant: "a-f"}')
        assert load_spec(write(tmp_path, "t1", named)).rows[0].model_config().variant == "a-f"

    @pytest.mark.parametrize(
        ("old", "new", "message"),
        [
            ("# Paper Table 1: a test table.", "# a table", "first line must cite the paper"),
            ("kind: table", "kind: chart", "kind must be one of"),
            ("name: t1", "name: other", "must equal the file name"),
            ("metrics:", "metricz:", r"unknown fields \['metricz'\]"),
            (
                "attitude: pd_re_net}",
                "attitude: pd_re_net, kappa: 5}",
                r"field 'kappa' has moved: write attitude_options: \{kappa: 5\}",
            ),
            (
                "attitude: pd_re_net}",
                "attitude: pd_re_net, attitude_options: {kapa: 5}}",
                r"rows\[0\] \('A'\): attitude_options: attitude head 'pd_re_net' takes no "
                r"option 'kapa'; it takes: alpha \(default",
            ),
            (
                "attitude: pd_re_net}",
                "attitude: re_net_r, attitude_options: {kappa: 5}}",
                r"attitude head 're_net_r' takes no option 'kappa'; it takes: hidden",
            ),
            (
                "attitude: pd_re_net}",
                "attitude: pd_re_net, translation_options: {direction_weight: 0}}",
                r"translation head 'regression' takes no option 'direction_weight'",
            ),
            (
                "attitude: pd_re_net}",
                "attitude: pd_re_net, encoder_options: {norm: [1]}}",
                r"encoder_options.norm=\[1\]: expected str",
            ),
            (
                "attitude: pd_re_net}",
                "attitude: pd_re_net, attitude_options: 5}",
                r"attitude_options must be a mapping",
            ),
            (
                "attitude: pd_re_net}",
                "attitude: nope}",
                r"rows\[0\] \('A'\): unknown attitude head 'nope'",
            ),
            (
                "attitude: pd_re_net}",
                "attitude: pd_re_net, colour: red}",
                r"rows\[0\]: unknown fields",
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
            # spec files written before issue 22: ModelConfig's name, and a table's rows
            (
                "attitude: pd_re_net}",
                'attitude: pd_re_net, encoder_variant: "/"}',
                "field 'encoder_variant' is now 'variant': write variant: '/'",
            ),
            ("rows:", "variants:", "field 'variants' is now 'rows'"),
            # what a sequence row fuses (issue 39): a head's belief or the encoder's pose volume
            (
                "attitude: pd_re_net}",
                "attitude: pd_re_net, beliefs: pixels}",
                r"beliefs must be one of \('head', 'volume', 'volume_joint'\), got 'pixels'",
            ),
            (
                "attitude: pd_re_net}",
                "attitude: pd_re_net, encoder: matching, beliefs: volume}",
                "beliefs: volume is for a kind: sequence spec",
            ),
        ],
    )
    def test_errors_name_file_and_field(self, tmp_path, old, new, message):
        path = write(tmp_path, "t1", GOOD.replace(old, new))
        with pytest.raises(SpecError, match=message) as info:
            load_spec(path)
        assert str(path) in str(info.value)

    def test_a_volume_row_names_its_encoder(self, tmp_path):
        text = GOOD.replace("kind: table", "kind: sequence").replace(
            "attitude: pd_re_net}", "attitude: pd_re_net, beliefs: volume}"
        )
        with pytest.raises(SpecError, match="names the pair encoder whose pose volume it fuses"):
            load_spec(write(tmp_path, "t1", text))
        named = text.replace("beliefs: volume}", "encoder: matching, beliefs: volume}")
        assert load_spec(write(tmp_path, "t1", named)).rows[0].beliefs == "volume"

    def test_pitch_roll_is_a_volume_rows_choice(self, tmp_path):
        text = GOOD.replace("kind: table", "kind: sequence")
        volume = "attitude: pd_re_net, encoder: matching, beliefs: volume"
        best = text.replace("attitude: pd_re_net}", volume + ", pitch_roll: best_on_val}")
        spec = load_spec(write(tmp_path, "t1", best))
        assert spec.rows[0].pitch_roll == "best_on_val"
        assert spec.jobs()[0].pitch_roll == "best_on_val"
        assert load_spec(write(tmp_path, "t1", text)).rows[0].pitch_roll == "own"
        path = write(tmp_path, "t1", text.replace("attitude: pd_re_net}",
                                                  volume + ", pitch_roll: test}"))  # fmt: skip
        with pytest.raises(SpecError, match=r"pitch_roll must be one of \('own', 'best_on_val'\)"):
            load_spec(path)
        head = text.replace("attitude: pd_re_net}", "attitude: pd_re_net, pitch_roll: best_on_val}")
        with pytest.raises(SpecError, match="is for a beliefs: volume row") as info:
            load_spec(write(tmp_path, "t1", head))
        assert "t1.yaml" in str(info.value)

    def test_placeholder_outside_sweep(self, tmp_path):
        path = write(
            tmp_path,
            "t1",
            GOOD.replace("attitude: pd_re_net}", 'attitude: pd_re_net, variant: "{x}"}'),
        )
        with pytest.raises(SpecError, match="outside a sweep"):
            load_spec(path)

    def test_per_row_splits_and_beyond_the_paper(self, tmp_path):
        text = GOOD.replace("# Paper Table 1: a test table.", "# Beyond the paper: an audit.")
        text = text.replace("paper_table: 1\n", "").replace("eval_splits: [standard/test]\n", "")
        text = text.replace(
            "attitude: pd_re_net}",
            "attitude: pd_re_net, train_split: frames/train, eval_splits: [frames/test],"
            " satellite_input: blank}",
        )
        (job,) = load_spec(write(tmp_path, "t1", text)).jobs()
        assert (job.train_split, job.eval_splits) == ("frames/train", ("frames/test",))
        assert job.row.get("satellite_input") == "blank"

    def test_unknown_table_in_only(self):
        with pytest.raises(SpecError, match=r"unknown table.*groups"):
            load_specs(only=["table99"])


class TestGroups:
    """``--only paper`` / ``--only extras``: the paper's tables and figures, and the rest."""

    def test_paper_group_is_the_papers_tables_and_figures(self):
        names = [s.name for s in load_specs(only=["paper"])]
        assert names == [f"fig{i}" for i in (5, 6, 7, 9)] + [f"table{i}" for i in range(1, 7)]

    def test_groups_partition_all_specs(self):
        paper = {s.name for s in load_specs(only=["paper"])}
        extras = {s.name for s in load_specs(only=["extras"])}
        assert {"extended", "leakage", "towns"} <= extras
        assert not paper & extras
        assert paper | extras == {s.name for s in load_specs()}

    def test_names_and_groups_mix_each_spec_once_in_given_order(self):
        names = [s.name for s in load_specs(only=["towns", "extras", "table1"])]
        assert names[0] == "towns" and names[-1] == "table1"
        assert len(names) == len(set(names))


SWEEP = """# Paper Fig. 7: a test sweep.
name: f7
title: test
kind: sweep
paper_figure: 7
sweep: kappa
sweep_values: [1, 2.5, 1e-3]
eval_splits: [standard/test]
metrics: [dphi_deg]
rows:
  - {label: A, paper_model: Pd/Re-Net, attitude: pd_net_e, variant: "/",
     attitude_options: {kappa: "{x}", hidden: 64, direction_weight: 0},
     translation: re_net_t, translation_options: {scale_weight: "{x}"},
     encoder_options: {norm: batch}}
"""


class TestRowOptions:
    def test_any_head_and_encoder_option_per_row_with_sweep_values(self, tmp_path):
        spec = load_spec(write(tmp_path, "f7", SWEEP))
        configs = [j.row.model_config(width=0.25) for j in spec.jobs()]
        assert [c.attitude_options for c in configs] == [
            {"kappa": k, "hidden": 64, "direction_weight": 0.0} for k in (1.0, 2.5, 0.001)
        ]
        # scale_weight 1 is re_net_t's default: the same model as no value
        assert [c.translation_options for c in configs] == [
            {},
            {"scale_weight": 2.5},
            {"scale_weight": 0.001},
        ]
        assert {c.encoder_options["norm"] for c in configs} == {"batch"}
        assert {(c.width, c.variant, c.translation) for c in configs} == {(0.25, "/", "re_net_t")}

    def test_default_value_is_the_same_model_as_no_value(self, tmp_path):
        text = SWEEP.replace("sweep_values: [1, 2.5, 1e-3]", "sweep_values: [10, 5]")
        text = text.replace(", hidden: 64, direction_weight: 0", "")
        text = text.replace(
            'translation: re_net_t, translation_options: {scale_weight: "{x}"},', ""
        )
        text = text.replace(",\n     encoder_options: {norm: batch}}", "}")
        default, five = load_spec(write(tmp_path, "f7", text)).jobs()
        assert (
            default.row.model_config()
            == load_spec(write(tmp_path, "f7", text.replace('{kappa: "{x}"}', "{}")))
            .jobs()[0]
            .row.model_config()
        )
        assert five.row.model_config().attitude_options == {"kappa": 5.0}

    def test_option_error_names_sweep_value(self, tmp_path):
        text = SWEEP.replace("sweep_values: [1, 2.5, 1e-3]", "sweep_values: [1, wide]")
        with pytest.raises(SpecError) as err:
            load_spec(write(tmp_path, "f7", text))
        assert "f7.yaml: rows[0] ('A') (sweep value wide)" in str(err.value)
        assert "kappa='wide': expected float" in str(err.value)

    def test_placeholder_in_option_outside_sweep(self, tmp_path):
        path = write(
            tmp_path,
            "t1",
            GOOD.replace("attitude: pd_re_net}", 'attitude: pd_re_net, attitude_options: '
                         '{kappa: "{x}"}}'),
        )  # fmt: skip
        with pytest.raises(SpecError, match=r"field 'attitude_options.kappa' uses \{x\} outside"):
            load_spec(path)
