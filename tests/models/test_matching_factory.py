"""The matching encoder's options are declared once, in their groups
(``benchmark.models.matching_options``): the registered ``matching`` factory publishes the same
flat names, defaults and annotations, ``ModelConfig`` types and checks them from there, and the
class takes the groups, so the factory, the configs and the class cannot drift (issue 41)."""

from __future__ import annotations

import dataclasses
import inspect
import typing

import pytest

from benchmark.models import create_model
from benchmark.models.matching import MatchingEncoder, matching
from benchmark.models.matching_options import MatchingGeometry, MatchingLoss, MatchingOptions
from benchmark.models.model_config import ModelConfig, option_parameters


def group_of_each_option() -> dict[str, type]:
    """``flat option name -> its group's class``; a name in two groups fails."""
    out: dict[str, type] = {}
    for group in vars(MatchingOptions()).values():
        for f in dataclasses.fields(group):
            assert f.name not in out, f"{f.name} is in two groups"
            out[f.name] = type(group)
    return out


class TestOneDeclaration:
    def test_factory_options_are_the_groups_fields(self):
        # What ModelConfig reads (the factory's options without the arguments build_model passes).
        got = option_parameters(matching, ("variant", "width", "input_size"))
        groups = group_of_each_option()
        assert got is not None and list(got) == list(groups) == MatchingOptions.names()
        assert {n: p.default for n, p in got.items()} == MatchingOptions().flat()
        hints = typing.get_type_hints(matching)
        for name, group in groups.items():
            assert hints[name] == typing.get_type_hints(group)[name], name
        # Every option has a default, so the factory alone builds the default encoder.
        assert all(p.default is not inspect.Parameter.empty for p in got.values())

    def test_the_class_takes_the_groups_and_declares_no_option(self):
        params = inspect.signature(MatchingEncoder.__init__).parameters
        assert list(params) == ["self", "input_size", "options"]

    def test_every_group_is_frozen(self):
        with pytest.raises(dataclasses.FrozenInstanceError):
            MatchingOptions().geometry.n_yaw = 12  # type: ignore[misc]


class TestRouting:
    def test_from_flat_routes_each_option_to_its_group(self):
        flat = {"n_yaw": 12, "protocol": "gravity_aided", "photometric": 0.5}
        options = MatchingOptions.from_flat(flat)
        assert options.geometry == MatchingGeometry(n_yaw=12)
        assert options.loss == MatchingLoss(protocol="gravity_aided")
        assert options.augmentation.photometric == 0.5
        assert options.flat() == {**MatchingOptions().flat(), **flat}

    def test_factory_builds_what_the_class_builds(self):
        enc = matching(input_size=32, n_yaw=12, protocol="gravity_aided")
        flat = {"n_yaw": 12, "protocol": "gravity_aided"}
        ref = MatchingEncoder(32, MatchingOptions.from_flat(flat))
        assert (enc.n_yaw, enc.protocol, enc.search_cells) == (ref.n_yaw, ref.protocol, 19)
        assert enc.options == ref.options
        assert [k for k, _ in enc.named_parameters()] == [k for k, _ in ref.named_parameters()]

    def test_default_encoder_is_the_factorys_default(self):
        assert MatchingEncoder(32).options == matching(input_size=32).options


class TestModelConfig:
    def test_types_and_refuses_options(self):
        cfg = ModelConfig(encoder="matching", variant="/", encoder_options={"n_yaw": "24"})
        assert cfg.encoder_options == {"n_yaw": 24}  # typed from the group's annotation
        # The default is dropped: one model, one hash.
        assert ModelConfig(encoder="matching", variant="/", encoder_options={"n_yaw": 36}) == (
            ModelConfig(encoder="matching", variant="/")
        )
        with pytest.raises(ValueError, match=r"takes no option 'n_yaws'.*n_yaw \(default 36\)"):
            ModelConfig(encoder="matching", variant="/", encoder_options={"n_yaws": 24})
        with pytest.raises(ValueError, match=r"encoder_options.cell_m='wide': expected float"):
            ModelConfig(encoder="matching", variant="/", encoder_options={"cell_m": "wide"})
        model = create_model(encoder="matching", variant="/", input_size=32,
                             encoder_options={"n_yaw": 24})  # fmt: skip
        assert model.encoder.n_yaw == 24


def test_direct_call_refuses_unknown_options():
    with pytest.raises(ValueError, match="no option 'n_yaws'; it takes: protocol, "):
        matching(input_size=32, n_yaws=24)
    with pytest.raises(ValueError, match="set variant to '/'"):
        matching(variant="a-f", input_size=32)
