"""``precision=bf16`` computes in bf16, not only says so (issue 41 item 4).

The tags and the run key name the precision; these tests look at the computation itself: the
dtype of the activations of every convolution and dense layer while the model trains, recorded
by a global forward hook during a real (tiny) training run of ``run_training``. With bf16 the
convolutions and dense layers of the encoder compute in bfloat16 under autocast; with fp32
nothing does. Where the CPU has no native bf16 the slow emulation is allowed for the test
(``UAVBENCH_ALLOW_SLOW_BF16=1``): the dtype is the same, only the speed differs.
"""

from __future__ import annotations

from collections import Counter

import pytest
import torch
from torch import nn

from benchmark.training import load_train_config, run_training

ENCODERS = {
    "googlenet": ["model.width=0.25", "model.variant=/"],
    "matching": ["model.encoder=matching", "model.variant=/"],
}


def tiny(root, precision: str, encoder: str):
    return load_train_config(
        None,
        [
            f"data.root={root}", "data.limit_train=8", "data.limit_val=4",
            *ENCODERS[encoder], "model.attitude=re_net_r", "model.attitude_options.hidden=32",
            "optim.name=adam", "optim.batch_size=4", "optim.epochs=1", "threads=1",
            "device=cpu", f"precision={precision}",
        ],
    )  # fmt: skip


def forward_dtypes(cfg, out_dir) -> Counter:
    """``(layer type, training mode, output dtype) -> count`` over every Conv2d and Linear
    forward while ``cfg`` trains for its epoch (a frozen encoder's features are computed in
    eval mode)."""
    seen: Counter = Counter()

    def hook(module: nn.Module, _inputs, output) -> None:
        if isinstance(module, (nn.Conv2d, nn.Linear)) and isinstance(output, torch.Tensor):
            seen[(type(module).__name__, module.training, output.dtype)] += 1

    handle = torch.nn.modules.module.register_module_forward_hook(hook)
    try:
        run_training(cfg, out_dir, progress=False)
    finally:
        handle.remove()
    return seen


def training_activation_dtypes(cfg, out_dir) -> Counter:
    """``(layer type, output dtype) -> count`` over the forwards of modules in training mode."""
    seen: Counter = Counter()
    for (kind, training, dtype), count in forward_dtypes(cfg, out_dir).items():
        if training:
            seen[(kind, dtype)] += count
    return seen


@pytest.mark.parametrize("encoder", sorted(ENCODERS))
class TestTrainingPrecision:
    def test_bf16_trains_in_bf16(self, encoder, smoke_dataset, tmp_path, monkeypatch):
        monkeypatch.setenv("UAVBENCH_ALLOW_SLOW_BF16", "1")
        seen = training_activation_dtypes(tiny(smoke_dataset, "bf16", encoder), tmp_path)
        assert seen[("Conv2d", torch.bfloat16)] > 0, seen
        assert seen[("Linear", torch.bfloat16)] > 0, seen
        assert seen[("Conv2d", torch.float32)] == 0, seen  # no convolution left in fp32

    def test_fp32_trains_in_fp32(self, encoder, smoke_dataset, tmp_path):
        seen = training_activation_dtypes(tiny(smoke_dataset, "fp32", encoder), tmp_path)
        assert seen and {dtype for _, dtype in seen} == {torch.float32}, seen


class TestFrozenEncoderPrecision:
    """The runner's heads-only units: the frozen encoder's features are computed (and cached)
    in the unit's precision, and the heads train in it."""

    @pytest.fixture(scope="class")
    def checkpoint(self, smoke_dataset, tmp_path_factory):
        out = tmp_path_factory.mktemp("encoder")
        run_training(tiny(smoke_dataset, "fp32", "matching"), out, progress=False)
        return out / "checkpoint.pt"

    @pytest.mark.parametrize("precision", ["bf16", "fp32"])
    def test_encoding_and_heads(self, precision, checkpoint, smoke_dataset, tmp_path, monkeypatch):
        monkeypatch.setenv("UAVBENCH_ALLOW_SLOW_BF16", "1")
        cfg = load_train_config(
            None, [f"data.root={smoke_dataset}", "data.limit_train=8", "data.limit_val=4",
                   *ENCODERS["matching"], "model.attitude=re_net_r",
                   "model.attitude_options.hidden=32", "optim.name=adam", "optim.batch_size=4",
                   "optim.epochs=1", "threads=1", "device=cpu", f"precision={precision}",
                   f"pretrained.checkpoint={checkpoint}"],
        )  # fmt: skip
        seen = forward_dtypes(cfg, tmp_path)
        dtype = torch.bfloat16 if precision == "bf16" else torch.float32
        encoded = {d for (kind, training, d) in seen if kind == "Conv2d" and not training}
        heads = {d for (kind, training, d) in seen if kind == "Linear" and training}
        assert encoded == {dtype}, seen  # the frozen encoder's features, computed once
        assert heads == {dtype}, seen  # the heads' training steps
