"""Every head and encoder option of ``TrainConfig.model`` is settable from YAML and ``--set``."""

from __future__ import annotations

import pytest

from benchmark.config import ConfigError, save_yaml
from benchmark.training import ModelConfig, TrainConfig, load_train_config

YAML = """\
model:
  variant: /
  attitude: pd_net_e
  attitude_options: {hidden: 512, direction_weight: 0, kappa: 10}
  translation: re_net_t
  translation_options:
    scale_weight: 2
  encoder_options: {norm: batch}
"""


class TestFromYaml:
    def test_options_typed_and_canonical(self, tmp_path):
        (tmp_path / "c.yaml").write_text(YAML)
        cfg = load_train_config(tmp_path / "c.yaml")
        assert isinstance(cfg.model, ModelConfig)
        # kappa 10 is the head's default: the same model as no kappa
        assert cfg.model.attitude_options == {"direction_weight": 0.0, "hidden": 512}
        assert cfg.model.translation_options == {"scale_weight": 2.0}
        assert cfg.model.encoder_options == {"norm": "batch"}

    def test_round_trip(self, tmp_path):
        (tmp_path / "c.yaml").write_text(YAML)
        cfg = load_train_config(tmp_path / "c.yaml", ["model.attitude_options.kappa=5"])
        save_yaml(cfg, tmp_path / "again.yaml")
        assert load_train_config(tmp_path / "again.yaml") == cfg

    @pytest.mark.parametrize(
        ("text", "message"),
        [
            ("model:\n  attitude_options: {kapa: 5}\n",
             r"c\.yaml: model: attitude_options: attitude head 'pd_re_net' takes no option "
             r"'kapa'; it takes: alpha \(default 80000000\.0\), hidden \(default 160\)"),
            ("model:\n  attitude: re_net_r\n  attitude_options: {kappa: 5}\n",
             r"c\.yaml: .*'re_net_r' takes no option 'kappa'; it takes: hidden \(default 1024\)"),
            ("loss:\n  kappa: 5\n", r"c\.yaml: config key 'loss' has moved: loss\.kappa -> "
             r"model\.attitude_options\.kappa"),
            ("model:\n  attitude_kwargs: {kappa: 5}\n",
             r"c\.yaml: config key 'model\.attitude_kwargs' has moved: .*model\.attitude_options"),
            ("model:\n  encoder_options: [batch]\n", r"c\.yaml: model\.encoder_options=\['batch'\]"
             r": expected .*mapping"),
        ],
    )  # fmt: skip
    def test_errors_name_file_head_and_accepted_options(self, tmp_path, text, message):
        (tmp_path / "c.yaml").write_text(text)
        with pytest.raises(ConfigError, match=message):
            load_train_config(tmp_path / "c.yaml")


class TestFromSet:
    @pytest.mark.parametrize(
        ("overrides", "field", "expected"),
        [
            (["model.attitude_options.hidden=512"], "attitude_options", {"hidden": 512}),
            (["model.attitude=pd_net_e", "model.attitude_options.direction_weight=0"],
             "attitude_options", {"direction_weight": 0.0}),
            (["model.translation=re_net_t", "model.translation_options.scale_weight=0.5"],
             "translation_options", {"scale_weight": 0.5}),
            (["model.translation_options.hidden=64"], "translation_options", {"hidden": 64}),
            (["model.encoder_options.norm=batch"], "encoder_options", {"norm": "batch"}),
            (["model.attitude_options={kappa: 5, alpha: 1e-3}"], "attitude_options",
             {"kappa": 5.0, "alpha": 0.001}),
            (["model.attitude_options.kappa=5", "model.attitude_options.kappa=10"],
             "attitude_options", {}),
        ],
    )  # fmt: skip
    def test_every_option_kind(self, overrides, field, expected):
        assert getattr(load_train_config(None, overrides).model, field) == expected

    @pytest.mark.parametrize(
        ("override", "message"),
        [
            ("loss.kappa=5", r"'loss\.kappa' has moved: loss\.kappa -> model\.attitude_options"),
            ("loss.alpha=0", r"loss\.alpha -> model\.attitude_options\.alpha"),
            ("loss.aux_weight=0", r"loss\.aux_weight -> model\.aux_weight"),
            ("model.translation_options.direction_weight=0",
             r"translation head 'regression' takes no option 'direction_weight'; it takes: "
             r"hidden \(default 1024\)"),
            ("model.encoder_options.depth=3",
             r"encoder 'googlenet' takes no option 'depth'; it takes: norm \(default 'group'\)"),
            ("model.attitude_options.hidden=wide",
             r"attitude_options\.hidden='wide': expected int"),
            ("model.attitude=pd_re_nt", r"unknown attitude head 'pd_re_nt'; known: .*pd_re_net"),
        ],
    )  # fmt: skip
    def test_errors(self, override, message):
        with pytest.raises(ConfigError, match=message):
            load_train_config(None, [override])

    def test_defaults_are_the_paper_model(self):
        assert TrainConfig().model == ModelConfig()
        assert ModelConfig().aux_weight == 0.3 and ModelConfig().variant == "a-f"
