"""The registered ``matching`` factory takes its options from ``MatchingEncoder`` (declared once,
in the class): same names, defaults and annotations, still checked and typed by ``ModelConfig``."""

from __future__ import annotations

import inspect
import typing

import pytest

from benchmark.models import create_model
from benchmark.models.matching import MatchingEncoder, matching
from benchmark.models.model_config import ModelConfig, option_parameters


def _class_options() -> dict[str, inspect.Parameter]:
    params = inspect.signature(MatchingEncoder.__init__).parameters
    return {n: p for n, p in params.items() if n not in ("self", "input_size")}


def test_factory_options_and_defaults_are_the_class_ones():
    # What ModelConfig reads (the factory's options without the arguments build_model passes).
    got = option_parameters(matching, ("variant", "width", "input_size"))
    want = _class_options()
    assert got is not None and list(got) == list(want)
    assert {n: p.default for n, p in got.items()} == {n: p.default for n, p in want.items()}
    hints, class_hints = (
        typing.get_type_hints(matching),
        typing.get_type_hints(MatchingEncoder.__init__),
    )
    assert {n: hints[n] for n in want} == {n: class_hints[n] for n in want}
    # Every option has a default, so the factory alone builds the class's default encoder.
    assert all(p.default is not inspect.Parameter.empty for p in want.values())


def test_factory_builds_what_the_class_builds():
    enc = matching(input_size=32, n_yaw=12, protocol="gravity_aided")
    ref = MatchingEncoder(32, n_yaw=12, protocol="gravity_aided")
    assert (enc.n_yaw, enc.protocol, enc.search_cells) == (ref.n_yaw, ref.protocol, 19)
    assert [k for k, _ in enc.named_parameters()] == [k for k, _ in ref.named_parameters()]


def test_model_config_types_and_refuses_options():
    cfg = ModelConfig(encoder="matching", variant="/", encoder_options={"n_yaw": "24"})
    assert cfg.encoder_options == {"n_yaw": 24}  # typed from the class's annotation
    # The class's default is dropped: one model, one hash.
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
