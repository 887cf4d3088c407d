"""Planning: shared models are trained once, keys are portable and stable."""

from __future__ import annotations

from pathlib import Path

import pytest

from benchmark.runner.plan.repro_profiles import PROFILES, QUICK_ENCODER_OPTIONS
from benchmark.runner.plan.specs import load_specs
from benchmark.runner.plan.units import job_key, plan_units, val_split_for

SPLITS = (
    ["standard/train", "standard/val", "standard/test", "generalized/test"]
    + [f"flight/pitch{p}" for p in (0, -10, -50)]
    + [f"height{h}/{part}" for h in (600, 800, 1000, 1200, 1400) for part in ("train", "test")]
    + [f"pitch{a}to{b}/test" for a, b in ((0, -10), (-10, -20), (-20, -30), (-30, -40), (-40, -50))]
    + [f"frames/{part}" for part in ("train", "val", "test")]
    + [f"towns/{part}" for part in ("train", "val", "test", "london")]
    + ["long/standard", "long/towns", "long/london"]
)


def plan(seeds=(0,), root="/data/a", only=None):
    """The units of the repository's specs on the quick profile."""
    return plan_units(
        load_specs(only=only), PROFILES["quick"], list(seeds), Path(root), SPLITS, "h"
    )


class TestPlanUnits:
    def test_the_paper_tables_train_35_models_per_seed(self):
        # quick: the shared matching encoder + on it 8 attitude heads + Re-Net-T + the Laplace
        # translation head (Tables 3-4, not in the paper) + 2 heads x 5
        # heights + 4 other kappas + the UAV-only control on standard/train (Tables 1-5 and
        # leakage share it) + Pd/Re-Net and the control on frames/train (leakage) + 3 models on
        # towns/train = 30; + Fig. 9's GoogLeNet in its 4 variants (end to end, 4 units).
        # (The extended table adds one unit per head beyond the paper; it grows with the registry.
        # The encoders table adds 3 GoogLeNet rows and 3 gravity-aided matching rows.)
        paper = [s.name for s in load_specs()
                 if s.name not in ("extended", "encoders", "sequence")]  # fmt: skip
        assert len(plan(only=paper)) == 35
        assert len(plan(seeds=(0, 1, 2), only=paper)) == 105
        assert len(plan(only=[*paper, "encoders"])) == 41
        extra = {u.key for u in plan()} - {u.key for u in plan(only=[*paper, "encoders"])}
        for unit in plan():
            if unit.key in extra:
                assert {j.table for j in unit.jobs} <= {"extended", "sequence"}

    def test_the_sequence_table_trains_nothing_of_its_own(self):
        # issue 39: its rows are the extended and encoders tables' units, which also fuse its
        # splits (and their confirmation splits), after evaluating the validation split
        others = [s.name for s in load_specs() if s.name != "sequence"]
        assert {u.key for u in plan()} == {u.key for u in plan(only=others)}
        confirm = ["confirm/standard", "confirm/towns", "confirm/generalized"]
        units = plan_units(load_specs(), PROFILES["quick"], [0], Path("/d"), SPLITS + confirm, "h")
        fused = [u for u in units if u.fuse_splits]
        sequence = load_specs(only=["sequence"])[0]
        heads = [r for r in sequence.rows if r.beliefs == "head"]
        assert len(fused) == len({r.label for r in heads})
        for unit in fused:
            assert set(sequence.eval_splits) <= set(unit.fuse_splits) <= set(unit.eval_splits)
            assert set(confirm) <= set(unit.fuse_splits)  # the claims are decided there too
            assert unit.val_split == "standard/val"
        assert not any(u.fuse_splits for u in plan(only=others))
        # the pose-volume rows: the same units as the two Pd/Re-Net rows (vision-only and
        # gravity-aided), which fuse their volume too
        volume = [u for u in units if u.volume_splits]
        assert len(volume) == 2 and all(u.fuse_splits for u in volume)
        labels = {j.label for u in volume for j in u.jobs if j.table == "sequence"}
        assert {"Pd/Re-Net", "Pd/Re-Net · matching, gravity-aided"} <= labels
        for unit in volume:
            assert unit.volume_splits == unit.fuse_splits
        # the joint rows: both volumes' units (vision-only and gravity-aided), long flights only
        joint = [u for u in units if u.joint_splits]
        assert len(joint) == 2 and all(u in volume for u in joint)
        for unit in joint:
            assert unit.joint_splits == ["long/standard", "long/towns", "long/london"]
        protocols = {u.cfg.model.encoder_options.get("protocol", "vision_only") for u in joint}
        assert protocols == {"vision_only", "gravity_aided"}

    def test_control_is_its_own_unit(self):
        units = plan()
        blank = [u for u in units if u.cfg.model.satellite_input == "blank"]
        assert {u.cfg.data.train_split for u in blank} == {
            "standard/train", "frames/train", "towns/train"
        }  # fmt: skip
        std = next(u for u in blank if u.cfg.data.train_split == "standard/train"
                   and u.cfg.model.encoder == "matching")  # fmt: skip
        assert {j.table for j in std.jobs} == {"table1", "table2", "table3", "table4", "table5",
                                               "leakage", "encoders", "sequence"}  # fmt: skip
        assert std.cfg.data.val_split == "standard/val"

    def test_pd_re_net_is_shared_across_tables(self):
        units = plan()
        shared = [
            u for u in units if any(j.table == "table1" and j.label == "Pd/Re-Net" for j in u.jobs)
        ]
        assert len(shared) == 1
        tables = {j.table for j in shared[0].jobs}
        # kappa 10 of Fig. 7 and the encoders table's vision-only matching row are the same
        # model as Table 1's (Fig. 9 names the paper's GoogLeNet: another model in quick), and
        # so is Table 5's "with AGTFM" row (GoogLeNet's variants do not apply to the matching
        # encoder: the row runs it plain)
        assert tables == {
            "table1", "table2", "table3", "table4", "table5", "fig6", "fig7", "leakage",
            "extended", "encoders", "sequence",
        }  # fmt: skip
        assert shared[0].cfg.model.attitude_options == {}  # kappa 10 is the head's default

    def test_eval_splits_are_the_union(self):
        unit = next(
            u
            for u in plan()
            if u.cfg.model.attitude == "re_net_r" and u.cfg.data.train_split == "standard/train"
            and u.cfg.model.encoder == "matching"
            and u.cfg.model.encoder_options == QUICK_ENCODER_OPTIONS  # the profile's, no protocol
        )  # fmt: skip
        assert "generalized/test" in unit.eval_splits and "pitch0to-10/test" in unit.eval_splits
        assert "flight/pitch0" in unit.eval_splits  # Re-Net of Table 5

    def test_units_are_evaluated_on_the_confirmation_of_their_test_splits(self):
        """Issue 38: each unit also evaluates confirm/* for the test splits its jobs test, with
        the same model (same key); no job lists them, so no table shows them."""
        confirm = ["confirm/standard", "confirm/towns", "confirm/generalized"]
        without = {u.key: u for u in plan()}
        units = plan_units(load_specs(), PROFILES["quick"], [0], Path("/d"), SPLITS + confirm, "h")
        mapping = dict(
            zip(("standard/test", "towns/test", "generalized/test"), confirm, strict=True)
        )
        assert {u.key for u in units} == set(without)
        for unit in units:
            tested = {s for job in unit.jobs for s in job.eval_splits}
            expected = [c for t, c in mapping.items() if t in tested]
            assert list(unit.confirm_splits) == expected
            assert unit.eval_splits == without[unit.key].eval_splits + expected
            assert not any(s in job.eval_splits for job in unit.jobs for s in confirm)
        assert any(u.confirm_splits for u in units)

    def test_every_unit_is_evaluated_on_its_validation_split(self):
        # Choices are made on validation numbers, so each run carries them beside its test ones.
        expected = {
            "standard/train": "standard/val", "frames/train": "frames/val",
            "towns/train": "towns/val",
        }  # fmt: skip
        expected["standard/train+towns/train"] = "standard/val"  # quick's shared encoders
        for unit in plan():
            val = expected.get(unit.cfg.data.train_split)
            assert unit.val_split == val
            for job in unit.jobs:
                splits = unit.job_splits(job)
                assert splits[: len(job.eval_splits)] == list(job.eval_splits)
                assert splits[len(job.eval_splits) :] == ([val] if val else [])
            assert (val in unit.eval_splits) == (val is not None)

    def test_keys_do_not_depend_on_the_data_path(self):
        assert [u.key for u in plan(root="/a")] == [u.key for u in plan(root="/elsewhere/b")]

    def test_keys_depend_on_seed_and_dataset(self):
        a = plan_units(
            load_specs(only=["table1"]), PROFILES["quick"], [0], Path("/d"), SPLITS, "h1"
        )
        b = plan_units(
            load_specs(only=["table1"]), PROFILES["quick"], [0], Path("/d"), SPLITS, "h2"
        )
        assert {u.key for u in a}.isdisjoint({u.key for u in b})
        assert len({u.key for u in plan(seeds=(0, 1))}) == 2 * len(plan())

    def test_a_head_version_bump_changes_only_that_heads_keys(self, monkeypatch):
        from benchmark.models import get_head_class

        before = {u.key: u.cfg.model.attitude for u in plan()}
        monkeypatch.setattr(get_head_class("pd_net_e"), "version", 99)
        after = {u.key for u in plan()}
        changed = {att for key, att in before.items() if key not in after}
        assert changed == {"pd_net_e"}

    def test_missing_split_is_reported(self):
        with pytest.raises(ValueError, match="no split"):
            plan_units(
                load_specs(only=["fig5"]),
                PROFILES["quick"],
                [0],
                Path("/d"),
                ["standard/train"],
                "h",
            )

    def test_job_keys_differ_per_table(self):
        unit = plan()[0]
        keys = {job_key(j, unit.key) for j in unit.jobs}
        assert len(keys) == len(unit.jobs)


class TestValSplitFor:
    def test_only_when_present(self):
        assert val_split_for("standard/train", SPLITS) == "standard/val"
        assert val_split_for("height600/train", SPLITS) is None


class TestUnitConfigs:
    def test_row_options_reach_the_unit_config(self):
        fig7 = [u for u in plan(only=["fig7"]) if not u.shared_encoder]
        kappas = sorted(u.cfg.model.attitude_options.get("kappa", 10.0) for u in fig7)
        assert kappas == [1.0, 5.0, 10.0, 20.0, 50.0]

    def test_profile_supplies_width_and_optimiser(self):
        profile = PROFILES["quick"]
        for unit in plan(only=["table1"]):
            assert unit.cfg.model.width == profile.width
            shared = profile.shared_encoder
            optim = shared.optim if unit.shared_encoder else profile.optim
            if unit.needs:  # heads on the shared encoder's frozen features
                optim = shared.heads_optim or profile.optim
            assert unit.cfg.optim == optim
            assert unit.cfg.threads == 1 and unit.cfg.model.input_size is None

    def test_unit_key_is_the_train_run_key(self):
        from benchmark.training.identity import run_key

        for unit in plan(only=["table1"]):
            assert unit.key == run_key(unit.cfg, "h")
