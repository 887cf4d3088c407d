"""``ModelConfig``: the one model description (issue 13): options checked against the head's own
constructor, typed, canonical (defaults dropped), frozen; checkpoints of format 1 still load."""

from __future__ import annotations

import copy
import dataclasses
import inspect
import pickle

import pytest
import torch

from benchmark.config import convert
from benchmark.models import ModelConfig, create_model, get_head_class
from benchmark.models.checkpoint import load_trained_model
from benchmark.models.model_config import normalize_options, parse_scalar

SMALL = {"width": 0.25, "input_size": 32, "variant": "/"}


def n_params(model: torch.nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


class TestOptions:
    def test_every_attitude_option_reaches_the_head(self):
        torch.manual_seed(0)
        model = create_model(**SMALL, attitude="pd_net_e",
                             attitude_options={"hidden": 32, "direction_weight": 0.0})  # fmt: skip
        head = model.attitude_head
        # hidden is the decoder bottleneck: the first linear layer has 32 outputs.
        assert any(isinstance(m, torch.nn.Linear) and m.out_features == 32 for m in head.modules())
        default = create_model(**SMALL, attitude="pd_net_e")
        assert n_params(model) < n_params(default)

    def test_translation_and_encoder_options_reach_their_module(self):
        model = create_model(**SMALL, translation_options={"hidden": 16},
                             encoder_options={"norm": "batch"})  # fmt: skip
        assert any(
            isinstance(m, torch.nn.Linear) and m.out_features == 16
            for m in model.translation_head.modules()
        )
        assert any(isinstance(m, torch.nn.BatchNorm2d) for m in model.encoder.modules())
        assert not any(isinstance(m, torch.nn.GroupNorm) for m in model.encoder.modules())

    def test_unknown_option_names_head_and_accepted_options(self):
        with pytest.raises(ValueError) as err:
            ModelConfig(attitude="re_net_r", attitude_options={"kappa": 5})
        assert str(err.value) == (
            "attitude_options: attitude head 're_net_r' takes no option 'kappa'; "
            "it takes: hidden (default 1024)"
        )
        with pytest.raises(ValueError, match="translation head 'regression' takes no option"):
            ModelConfig(translation_options={"direction_weight": 0})
        with pytest.raises(ValueError, match=r"encoder 'googlenet' takes no option 'nrm'.*norm"):
            ModelConfig(encoder_options={"nrm": "batch"})

    def test_accepted_list_is_the_constructor_signature(self):
        cls = get_head_class("pd_re_net")
        expected = [
            n
            for n in inspect.signature(cls.__init__).parameters
            if n not in ("self", "in_features")
        ]
        with pytest.raises(ValueError) as err:
            ModelConfig(attitude_options={"nope": 1})
        for name in expected:
            assert f"{name} (default" in str(err.value)

    @pytest.mark.parametrize(
        ("given", "stored"),
        [
            ({"kappa": 5}, {"kappa": 5.0}),  # int -> float (the annotation)
            ({"kappa": "5"}, {"kappa": 5.0}),  # CLI string
            ({"alpha": "1e-3"}, {"alpha": 0.001}),  # YAML 1.1 keeps this a string
            ({"hidden": "512"}, {"hidden": 512}),
            ({"hidden": 512.0}, {"hidden": 512}),
            ({"kappa": 10}, {}),  # the head's default: dropped
            ({"kappa": 10.0, "hidden": 160, "n_points": 4096, "alpha": 8e7}, {}),
        ],
    )
    def test_values_typed_and_defaults_dropped(self, given, stored):
        assert ModelConfig(attitude_options=given).attitude_options == stored

    @pytest.mark.parametrize(
        ("options", "match"),
        [
            ({"hidden": 2.5}, r"attitude_options.hidden=2.5: expected int"),
            ({"hidden": True}, r"attitude_options.hidden=True: expected int"),
            ({"kappa": "many"}, r"attitude_options.kappa='many': expected float"),
        ],
    )
    def test_wrong_types(self, options, match):
        with pytest.raises(ValueError, match=match):
            ModelConfig(attitude_options=options)

    def test_default_and_unset_are_one_model(self):
        a, b = ModelConfig(attitude_options={"kappa": 10}), ModelConfig()
        assert a == b and hash(a) == hash(b) and a.to_dict() == b.to_dict()
        assert ModelConfig(attitude_options={"kappa": 5}) != b

    def test_parse_scalar(self):
        assert [parse_scalar(t) for t in ("5", "1e-3", "true", "null", "batch", "0.5")] == [
            5, 0.001, True, None, "batch", 0.5,
        ]  # fmt: skip

    @pytest.mark.parametrize(
        ("annotation", "text"),
        [(int, "1e3"), (int, "1_000"), (float, "nan"), (bool, "on"), (bool, "No"),
         (int | None, "null"), (str | None, "none"), (str, "512")],
    )  # fmt: skip
    def test_options_typed_like_config_fields(self, annotation, text):
        """One converter (issue 22): an option reads a string as a config field of its type."""

        def factory(in_features: int, x=None):
            return None

        factory.__annotations__["x"] = annotation  # a real type: this module's are strings
        got = normalize_options(factory, {"x": text}, owner="f", field_name="o").get("x")
        assert got == convert(text, annotation | None, "o.x") or (got != got and text == "nan")

    def test_var_keyword_heads_take_anything(self):
        def factory(in_features: int, **kwargs):  # a plug-in taking **kwargs
            return None

        assert normalize_options(factory, {"b": 1, "a": "x"}, owner="f", field_name="o") == {
            "a": "x",
            "b": 1,
        }


class TestFrozenConfig:
    def test_frozen_hashable_picklable(self):
        cfg = ModelConfig(attitude_options={"kappa": 5})
        with pytest.raises(dataclasses.FrozenInstanceError):
            cfg.attitude = "re_net_r"
        assert pickle.loads(pickle.dumps(cfg)) == cfg == copy.deepcopy(cfg)
        assert len({cfg, ModelConfig(attitude_options={"kappa": 5.0})}) == 1

    def test_caller_dict_is_copied(self):
        options = {"kappa": 5}
        cfg = ModelConfig(attitude_options=options)
        options["kappa"] = 7
        assert cfg.attitude_options == {"kappa": 5.0}

    def test_input_size_resolution(self):
        assert create_model(width=0.25, variant="/").config.input_size == 224
        cfg = ModelConfig(width=0.25, variant="/")
        assert cfg.input_size is None and cfg.resolved(48).input_size == 48
        with pytest.raises(ValueError, match="input_size=64 but the images are 48 px"):
            ModelConfig(input_size=64).resolved(48)

    def test_config_object_and_keywords_build_the_same_model(self):
        cfg = ModelConfig(**SMALL, attitude="re_net_q")
        torch.manual_seed(0)
        a = create_model(cfg)
        torch.manual_seed(0)
        b = create_model(**SMALL, attitude="re_net_q")
        sa, sb = a.state_dict(), b.state_dict()
        assert sa.keys() == sb.keys() and all(torch.equal(sa[k], sb[k]) for k in sa)

    def test_unshared_satellite_ignores_ids(self):
        model = create_model(**SMALL, shared_satellite=False).eval()
        seen = []
        model.encoder.register_forward_hook(lambda m, i, o: seen.append(i[0].shape[0]))
        uav, sat = torch.rand(4, 3, 32, 32), torch.rand(1, 3, 32, 32).expand(4, 3, 32, 32)
        model(uav, sat, torch.zeros(4, dtype=torch.int64))
        assert seen == [8]  # every satellite image encoded


class TestCheckpointFormats:
    def test_format_1_checkpoint_loads(self, tmp_path):
        torch.manual_seed(0)
        model = create_model(**SMALL, attitude="pd_re_net", attitude_options={"kappa": 5})
        old_config = {
            "encoder": "googlenet", "variant": "/", "width": 0.25, "input_size": 32,
            "attitude": "pd_re_net", "translation": "regression",
            "attitude_kwargs": {"kappa": 5.0}, "translation_kwargs": {}, "encoder_kwargs": {},
            "aux_weight": 0.3, "channels_last": True, "satellite_input": "image",
        }  # fmt: skip
        path = tmp_path / "old.pt"
        torch.save({"format": 1, "model_config": old_config, "model": model.state_dict()}, path)
        loaded = load_trained_model(path)
        assert loaded.config == model.config
        uav, sat = torch.rand(2, 3, 32, 32), torch.rand(2, 3, 32, 32)
        torch.testing.assert_close(loaded(uav, sat).attitude, model.eval()(uav, sat).attitude)

    def test_unreadable_format_names_file_and_what_to_do(self, tmp_path):
        path = tmp_path / "future.pt"
        torch.save({"format": 99, "model": {}}, path)
        with pytest.raises(ValueError, match=r"future.pt .*format 99.*retrain"):
            load_trained_model(path)

    def test_config_the_heads_refuse_names_file(self, tmp_path):
        path = tmp_path / "odd.pt"
        bad = {"attitude": "re_net_r", "attitude_kwargs": {"kappa": 5.0}}
        torch.save({"format": 1, "model_config": bad, "model": {}}, path)
        with pytest.raises(ValueError, match=r"odd.pt.*takes no option 'kappa'.*retrain"):
            load_trained_model(path)
