"""``make_optimizer``'s foreach choice on the CPU (issue 20) changes the speed, never the weights:
against torch's default per-tensor loop, three steps of a small model end bit-identical."""

from __future__ import annotations

import pytest
import torch
from tiny_pairs import tiny_config

from benchmark.bench.train import batch_of
from benchmark.models import create_model
from benchmark.training.loop import CPU_FOREACH, make_optimizer

OPTIMIZERS = [
    ("sgd", ()),
    ("sgd", ("optim.weight_decay=1e-4",)),
    ("adam", ("optim.lr=3e-4",)),
    ("adamw", ("optim.weight_decay=0.01",)),
]


def trained_weights(overrides: tuple[str, ...], foreach: bool | None) -> list[torch.Tensor]:
    """The weights after three steps (gradient norm clipped at 10, as the quick profile)."""
    cfg = tiny_config(*overrides)
    torch.manual_seed(0)
    model = create_model(width=0.1, input_size=32, variant="a-f").train()
    model.translation_head.set_statistics(torch.zeros(3), torch.full((3,), 50.0))
    opt = make_optimizer(cfg, model, foreach=foreach)
    assert opt.defaults["foreach"] is (CPU_FOREACH[cfg.optim.name] if foreach is None else foreach)
    batch = batch_of(32, 4, 2)
    for _ in range(3):
        loss = model.loss(
            model(batch["uav"], batch["sat"], batch["sat_id"]), batch["R"], batch["T"]
        )
        opt.zero_grad(set_to_none=True)
        loss["total"].backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 10.0)
        opt.step()
    return [p.detach().clone() for p in model.parameters()]


@pytest.mark.parametrize("name, extra", OPTIMIZERS)
def test_default_equals_the_per_tensor_loop_bit_for_bit(name, extra):
    torch.set_num_threads(1)
    overrides = (f"optim.name={name}", *extra)
    ours, loop = trained_weights(overrides, None), trained_weights(overrides, False)
    assert all(torch.equal(a, b) for a, b in zip(ours, loop, strict=True))
    torch.manual_seed(0)  # the steps did move the weights (the equality is not vacuous)
    start = create_model(width=0.1, input_size=32, variant="a-f").parameters()
    assert sum(not torch.equal(a, b) for a, b in zip(start, ours, strict=True)) > len(ours) // 2
