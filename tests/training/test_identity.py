"""One run identity and one tag set for ``uavbench train`` and ``uavbench reproduce`` (issue 13)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from benchmark.models import get_head_class
from benchmark.runner.plan.repro_profiles import PROFILES
from benchmark.runner.plan.specs import load_specs
from benchmark.runner.plan.units import plan_units
from benchmark.runner.report.logbook import Logbook
from benchmark.tracking import RunStatus, create_tracker
from benchmark.training import load_train_config, run_key, run_tags

SPLITS = ["standard/train", "standard/val", "standard/test", "generalized/test"]
# What a user types to train the smoke profile's Table 1 Pd/Re-Net (profile width and optimiser,
# the row's encoder variant); thread count and data path do not enter the identity.
SMOKE_PD_RE_NET = [
    "model.width=0.25",
    "model.variant=/",
    "optim.name=adam",
    "optim.lr=1e-3",
    "optim.batch_size=8",
    "optim.epochs=1",
]


def train_cfg(*extra: str, root: str = "/somewhere/data"):
    return load_train_config(None, [f"data.root={root}", *SMOKE_PD_RE_NET, *extra])


def smoke_unit(label: str, table: str = "table1", x: str | None = None, root: str = "/else/d"):
    """The smoke profile's unit of the job ``label`` (at sweep value ``x``) of ``table``."""
    units = plan_units(load_specs(only=[table]), PROFILES["smoke"], [0], Path(root), SPLITS, "m")
    return next(u for u in units if any(j.label == label and j.x == x for j in u.jobs))


class TestRunKey:
    def test_train_and_reproduce_unit_share_the_key(self):
        unit = smoke_unit("Pd/Re-Net")
        assert run_key(train_cfg(), "m") == unit.key
        assert run_key(train_cfg("threads=2"), "m") == unit.key  # scheduling only

    def test_head_default_hashes_like_unset(self):
        # Fig. 7's kappa 10 is Table 1's Pd/Re-Net, from the CLI as from a spec row.
        unit = smoke_unit("Pd/Re-Net", "fig7", x="10")
        assert unit.key == smoke_unit("Pd/Re-Net").key
        assert run_key(train_cfg("model.attitude_options.kappa=10"), "m") == unit.key
        five = smoke_unit("Pd/Re-Net", "fig7", x="5")
        assert run_key(train_cfg("model.attitude_options.kappa=5"), "m") == five.key != unit.key

    def test_control_row_and_options_match_the_cli(self):
        unit = smoke_unit("UAV-only control")
        assert run_key(train_cfg("model.satellite_input=blank"), "m") == unit.key

    def test_what_changes_the_key(self, monkeypatch):
        base = run_key(train_cfg(), "m")
        assert run_key(train_cfg(), "other manifest") != base
        assert run_key(train_cfg("seed=1"), "m") != base
        assert run_key(train_cfg("model.attitude_options.hidden=64"), "m") != base
        assert run_key(train_cfg("model.encoder_options.norm=batch"), "m") != base
        monkeypatch.setattr(get_head_class("pd_re_net"), "version", 99)
        assert run_key(train_cfg(), "m") != base


class TestTags:
    def test_train_tags_are_the_reproduce_tags(self, tmp_path):
        unit = smoke_unit("Pd/Re-Net")
        expected = run_tags(train_cfg(), "m")
        assert expected == run_tags(unit.cfg, "m")
        assert expected["model_key"] == unit.key
        assert json.loads(expected["head_options"]) == {"attitude": {}, "translation": {}}

        # What the reproduce logbook writes on the job's tracked run carries the same tags: the
        # model's from the plan, where it computed from the worker's own resolution.
        from benchmark.runner.execute.worker import UnitResult, unit_placement
        from benchmark.training import device_tags

        tracker = create_tracker("local", workdir=tmp_path)
        logbook = Logbook(tracker, "smoke", {"git_commit": "abc", "dataset_manifest": "m"})
        where = device_tags(unit.cfg, unit_placement(unit.cfg))
        logbook.log_job(unit.jobs[0], unit, UnitResult(unit.key, True, placement_tags=where))
        logbook.close(RunStatus.FINISHED)
        runs = [
            json.loads(p.read_text())
            for p in (tmp_path / "tracking-local").rglob("run.json")
            if json.loads(p.read_text())["tags"].get("label") == "Pd/Re-Net"
        ]
        (record,) = runs
        assert {k: record["tags"][k] for k in expected} == expected

    @pytest.mark.parametrize(
        ("override", "tag", "value"),
        [
            ("model.attitude_options.kappa=5", "head_options",
             '{"attitude": {"kappa": 5.0}, "translation": {}}'),
            ("model.translation=re_net_t", "translation_head", "re_net_t"),
            ("model.variant=a-f", "encoder", "googlenet a-f w0.25"),
        ],
    )  # fmt: skip
    def test_tags_describe_the_model(self, override, tag, value):
        assert run_tags(train_cfg(override), "m")[tag] == value
