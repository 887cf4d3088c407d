"""Planning with a shared encoder (``ReproProfile.shared_encoder``): one encoder unit per seed,
trained first; every row on the profile's encoder trains its heads on it, frozen; rows that
name another encoder (Fig. 9's GoogLeNet) train end to end as before."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from test_plan import SPLITS

from benchmark.runner.plan.repro_profiles import PROFILES, SharedEncoder
from benchmark.runner.plan.specs import load_specs
from benchmark.runner.plan.units import plan_units
from benchmark.training.config import OptimConfig

SHARED = dataclasses.replace(
    PROFILES["smoke"],
    encoder="matching",
    encoder_options={"protocol": "vision_only", "grey_gradient": True},  # as quick + encoders.yaml
    shared_encoder=SharedEncoder(optim=OptimConfig(name="adam", lr=1e-3, epochs=3)),
)


def plan(profile=SHARED, seeds=(0, 1), only=("table1", "fig9")):
    return plan_units(load_specs(only=list(only)), profile, list(seeds), Path("/data/a"), SPLITS,
                      "h", workdir=Path("/work/runs"))  # fmt: skip


class TestSharedEncoderPlan:
    def test_one_encoder_per_seed_first_and_the_rows_on_it(self):
        units = plan()
        shared = [u for u in units if u.shared_encoder]
        assert [u.cfg.seed for u in shared] == [0, 1]
        assert units[: len(shared)] == shared  # trained before anything that loads them
        for enc in shared:
            assert enc.jobs == [] and enc.needs == ()
            assert enc.cfg.model.encoder == "matching" and enc.cfg.model.attitude == "pd_re_net"
            assert enc.cfg.optim.epochs == 3 and not enc.cfg.pretrained.enabled
            assert enc.eval_splits == ["standard/val"]
        by_seed = {u.cfg.seed: u.key for u in shared}
        for unit in units:
            if unit.shared_encoder:
                continue
            tables = {j.table for j in unit.jobs}
            if tables == {"fig9"}:  # the paper's encoder, named in the row: end to end
                assert unit.cfg.model.encoder == "googlenet" and unit.needs == ()
                assert not unit.cfg.pretrained.enabled
                continue
            assert unit.cfg.model.encoder == "matching"
            assert unit.needs == (by_seed[unit.cfg.seed],)
            p = unit.cfg.pretrained
            assert p.key == by_seed[unit.cfg.seed]
            assert p.checkpoint == f"/work/runs/units/{p.key}/train/checkpoint.pt"
            assert unit.cfg.optim == SHARED.optim  # the heads train with the profile's optimiser

    def test_heads_optimiser_for_the_frozen_rows_only(self):
        heads = OptimConfig(name="adam", lr=3e-4, epochs=20)
        shared = dataclasses.replace(SHARED.shared_encoder, heads_optim=heads)
        units = plan(dataclasses.replace(SHARED, shared_encoder=shared))
        for unit in units:
            if unit.shared_encoder:
                assert unit.cfg.optim == shared.optim
            elif unit.needs:
                assert unit.cfg.optim == heads
            else:  # end to end (Fig. 9's GoogLeNet): the profile's
                assert unit.cfg.optim == SHARED.optim

    def test_the_uav_only_control_sits_on_the_same_encoder(self):
        control = [u for u in plan() if u.cfg.model.satellite_input == "blank"]
        assert control and all(u.needs for u in control)

    def test_keys_do_not_depend_on_the_workdir(self):
        a = plan_units(load_specs(only=["table1"]), SHARED, [0], Path("/d"), SPLITS, "h",
                       workdir=Path("/w1"))  # fmt: skip
        b = plan_units(load_specs(only=["table1"]), SHARED, [0], Path("/d"), SPLITS, "h",
                       workdir=Path("/w2"))  # fmt: skip
        assert [u.key for u in a] == [u.key for u in b]

    def test_no_encoder_unit_when_nothing_uses_it(self):
        units = plan(only=("fig9",))
        assert not any(u.shared_encoder for u in units)

    def test_without_a_shared_encoder_nothing_changes(self):
        plain = dataclasses.replace(SHARED, shared_encoder=None)
        units = plan(plain)
        assert not any(u.needs or u.cfg.pretrained.enabled for u in units)
        assert {u.cfg.model.encoder for u in units} == {"matching", "googlenet"}


class TestProtocolInTheReport:
    def test_the_readme_names_the_protocol(self):
        from benchmark.runner.report.outputs import profile_protocol

        quick = " ".join(profile_protocol(PROFILES["quick"]).split())
        assert "matching encoder, trained once per seed end to end" in quick
        assert "`standard/train+towns/train`" in quick and "frozen features (10 epochs" in quick
        assert "GoogLeNet (Fig. 9, the encoders table) train it end to end" in quick
        paper = profile_protocol(PROFILES["paper"])
        assert paper.startswith("width 1 GoogLeNet, 30 epochs, sgd") and "end to end" in paper

    def test_each_table_names_how_its_rows_trained(self):
        from benchmark.runner.report.training import table_protocol

        units = plan(only=("table1", "fig9"))
        assert table_protocol("table1", units) == (
            "Training protocol: heads only, trained on `standard/train`, on the frozen shared "
            "matching encoder (trained once per seed end to end with its own loss on "
            "`standard/train`; the README's Profile line)."
        )
        fig9 = table_protocol("fig9", units)
        assert "end to end on `standard/train` (googlenet) by the heads' loss only" in fig9
        mixed = table_protocol("encoders", plan(only=("encoders",)))
        assert "GoogLeNet a-f (AGTFM)" in mixed and "; heads only, trained on" in mixed
        assert table_protocol("towns", units) == ""  # not planned

    def test_the_training_splits_are_the_units(self):
        """Issue 38: encoders.md said "Every row trains on standard/train" while quick's matching
        encoder trains on standard/train + towns/train; the sentence now comes from the units'
        own training splits, and follows them."""
        from benchmark.runner.plan.specs import default_spec_dir, load_spec
        from benchmark.runner.report.training import table_protocol

        assert "standard/train" not in load_spec(default_spec_dir() / "encoders.yaml").note
        units = plan(PROFILES["quick"], seeds=(0,), only=("encoders",))
        text = table_protocol("encoders", units)
        goog, matching = text.removeprefix("Training protocol: ").split("; heads only")
        assert goog.startswith("end to end on `standard/train` (googlenet)")
        assert "Pd/Re-Net · GoogLeNet /" in goog and "matching, vision-only" not in goog
        assert matching.startswith(
            ", trained on `standard/train`, on the frozen shared matching encoder (trained once "
            "per seed end to end with its own loss on `standard/train+towns/train`;"
        )
        assert "Pd/Re-Net · matching, gravity-aided" in matching
        # another encoder split, another sentence: the words follow the units
        encoder = next(u for u in units if u.shared_encoder)
        data = dataclasses.replace(encoder.cfg.data, train_split="towns/train")
        encoder.cfg = dataclasses.replace(encoder.cfg, data=data)
        assert "with its own loss on `towns/train`;" in table_protocol("encoders", units)
