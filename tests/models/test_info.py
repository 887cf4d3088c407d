"""``uavbench model-info``: counts against independent hand counts, CLI errors."""

from __future__ import annotations

import json

import pytest
import torch
from torch import nn

from benchmark.cli import main
from benchmark.models import create_model
from benchmark.models.info import count_flops, count_parameters


def hand_count(model: nn.Module, size: int, training: bool) -> tuple[int, int]:
    """FLOPs (2 x multiply-adds) of every conv and linear layer, from forward hooks."""
    totals = {"conv": 0, "dense": 0}

    def conv_hook(m, inputs, out):
        k = m.kernel_size[0] * m.kernel_size[1]
        totals["conv"] += 2 * out.numel() * (m.in_channels // m.groups) * k

    def linear_hook(m, inputs, out):
        totals["dense"] += 2 * out.numel() * m.in_features

    for mod in model.modules():
        if isinstance(mod, nn.Conv2d):
            mod.register_forward_hook(conv_hook)
        elif isinstance(mod, nn.Linear):
            mod.register_forward_hook(linear_hook)
    model.train(training)
    x = torch.rand(1, 3, size, size)
    with torch.no_grad():
        model(x, x.clone())
    return totals["conv"] + totals["dense"], totals["dense"]


class TestCountFlops:
    @pytest.mark.parametrize("training", [False, True])
    @pytest.mark.parametrize("variant", ["/", "a-f"])
    def test_matches_hand_count(self, variant, training):
        torch.manual_seed(0)
        model = create_model(variant=variant, width=0.25, input_size=48)
        total, dense = count_flops(model, 48, training=training)
        assert (total, dense) == hand_count(model, 48, training)

    def test_aux_branches_only_in_training(self):
        model = create_model(variant="a-f", width=0.25, input_size=32)
        assert count_flops(model, 32, training=True)[0] > count_flops(model, 32, training=False)[0]


class TestModelInfoCommand:
    def test_json_output(self, capsys):
        args = ["model-info", "--width", "0.25", "--size", "32", "--repeats", "1", "--json"]
        assert main([*args, "--head", "re_net_r", "--variant", "/"]) == 0
        info = json.loads(capsys.readouterr().out)
        model = create_model(variant="/", width=0.25, input_size=32, attitude="re_net_r")
        assert info["parameters"] == count_parameters(model)
        assert info["size_mb"] == pytest.approx(4 * info["parameters"] / 1e6)
        assert info["latency_ms"] > 0

    def test_head_options(self, capsys):
        args = ["model-info", "--width", "0.25", "--size", "32", "--repeats", "1", "--json"]
        extra = ["--set", "attitude_options.hidden=32", "--set", "translation_options.hidden=16"]
        assert main([*args, "--head", "re_net_r", "--variant", "/", *extra]) == 0
        info = json.loads(capsys.readouterr().out)
        model = create_model(
            variant="/",
            width=0.25,
            input_size=32,
            attitude="re_net_r",
            attitude_options={"hidden": 32},
            translation_options={"hidden": 16},
        )
        assert info["parameters"] == count_parameters(model)
        default = create_model(variant="/", width=0.25, input_size=32, attitude="re_net_r")
        assert info["parameters"] < count_parameters(default)  # fmt: skip

    @pytest.mark.parametrize(
        ("flags", "message"),
        [
            (["--set", "attitude_options.kapa=1"], "attitude head 'pd_re_net' takes no option"),
            (["--set", "hidden=1"], "expected FIELD.OPTION=VALUE"),
            (["--head", "nope"], "unknown attitude head 'nope'"),
            (["--variant", "x"], "unknown encoder variant 'x'"),
            (["--size", "16"], "got 16"),
            (["--width", "0"], "width must be > 0"),
            (["--repeats", "0"], "--repeats >= 1"),
        ],
    )
    def test_bad_configuration_is_a_usage_error(self, flags, message, capsys):
        assert main(["model-info", "--width", "0.25", "--size", "32", *flags]) == 2
        assert message in capsys.readouterr().err


class TestBenchModel:
    def test_runs_and_prints_ratios(self, capsys):
        from benchmark.commands.bench import run_target

        def bench_main(argv: list[str]) -> int:
            return run_target("model", argv)

        args = ["--width", "0.25", "--size", "32", "--batch", "4", "--sats", "2", "--repeats", "1"]
        assert bench_main(args) == 0
        out = capsys.readouterr().out
        assert "shared satellite" in out and "channels_last" in out and "pairs/s" in out

    def test_bad_arguments(self):
        from benchmark.commands.bench import run_target

        def bench_main(argv: list[str]) -> int:
            return run_target("model", argv)

        with pytest.raises(SystemExit):
            bench_main(["--sats", "5", "--batch", "4"])
