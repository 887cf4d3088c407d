"""``bench_breakdown``: one step's self time by kind of work, checked on hand-made profiler events
(the arithmetic) and on a real profiled step (the op names torch really records)."""

from __future__ import annotations

from dataclasses import dataclass

import pytest
import torch
from torch import nn

from benchmark.bench.train_breakdown import (
    CLIP_LABEL,
    KINDS,
    breakdown_line,
    kind_of,
    profile_step,
    time_by_kind,
)


@dataclass
class Event:
    """The fields of ``torch.autograd.profiler_util.FunctionEvent`` the breakdown reads."""

    name: str
    self_cpu_time_total: float  # microseconds
    cpu_parent: Event | None = None


class TestKindOf:
    @pytest.mark.parametrize(
        "name, kind",
        [
            ("aten::mkldnn_convolution", "convolution"),
            ("aten::convolution_backward", "convolution"),
            ("aten::_slow_conv2d_forward", "convolution"),
            ("aten::mm", "matmul"),
            ("aten::addmm", "matmul"),
            ("aten::native_group_norm_backward", "normalisation"),
            ("aten::max_pool2d_with_indices", "pooling"),
            ("aten::grid_sampler_2d", "sampling"),
            ("aten::grid_sampler_2d_backward", "sampling"),
            ("aten::add_", "other"),
            ("aten::mul", "other"),
            ("Optimizer.step#SGD.step", "other"),  # only its descendants' context counts
            ("autograd::engine::evaluate_function: AddmmBackward0", "other"),
        ],
    )
    def test_names(self, name, kind):
        assert kind_of(name) == kind


class TestTimeByKind:
    def test_self_times_add_up_and_optimizer_owns_its_children(self):
        step = Event("Optimizer.step#Adam.step", 100.0)
        clip = Event(CLIP_LABEL, 5.0)
        events = [
            Event("aten::mkldnn_convolution", 4000.0),
            Event("aten::convolution_backward", 6000.0),
            Event("aten::addmm", 1500.0),
            Event("aten::native_group_norm", 700.0),
            Event("aten::max_pool2d_with_indices", 300.0),
            Event("aten::grid_sampler_2d_backward", 400.0),
            Event("aten::relu_", 200.0),
            step,
            Event("aten::add_", 900.0, step),  # inside the optimiser: not "other"
            Event("aten::mm", 50.0, Event("x", 0.0, step)),  # a grandchild counts too
            clip,
            Event("aten::_foreach_norm", 250.0, clip),
        ]
        got = time_by_kind(events)
        expected = {
            "convolution": 0.010,
            "matmul": 0.0015,
            "sampling": 0.0004,
            "normalisation": 0.0007,
            "pooling": 0.0003,
            "optimizer": (100 + 900 + 50 + 5 + 250) / 1e6,
            "other": 0.0002,
        }
        for kind in KINDS:
            assert got[kind] == pytest.approx(expected[kind], abs=1e-12), kind
        assert got["ops"] == 10  # events named aten::
        assert sum(got[k] for k in KINDS) == pytest.approx(
            sum(e.self_cpu_time_total for e in events) / 1e6
        )


class TestBreakdownLine:
    def test_percentages_and_rates(self):
        kinds = {"convolution": 0.5, "matmul": 0.1, "normalisation": 0.1, "pooling": 0.05,
                 "optimizer": 0.05, "other": 0.2, "ops": 1234.0}  # fmt: skip
        flops = {"total": 12_000_000_000, "convolution": 10_000_000_000, "matmul": 2_000_000_000}
        line = breakdown_line(kinds, flops, ceiling=40.0)
        # 10 GFLOP in 0.5 s = 20 GFLOP/s = 50% of 40; 2 GFLOP in 0.1 s = 20 GFLOP/s.
        assert "1000 ms, 1234 ATen op calls" in line
        assert "convolution 50% (20.0 GFLOP/s, 50% of the conv ceiling)" in line
        assert "matmul 10% (20.0 GFLOP/s)" in line
        assert "normalisation 10%, pooling 5%, optimizer 5%, other 20%" in line
        assert "of the conv ceiling" not in breakdown_line(kinds, flops, ceiling=None)

    def test_complex_products_and_sampling_rates(self):
        """The profiler names complex GEMMs (FLOP kind ``dft``) like real ones: their FLOPs join
        the matmul time's; ``grid_sample``'s FLOPs give the sampling rate."""
        kinds = {"convolution": 0.4, "matmul": 0.3, "sampling": 0.1, "normalisation": 0.0,
                 "pooling": 0.0, "optimizer": 0.1, "other": 0.1, "ops": 10.0}  # fmt: skip
        flops = {"convolution": 4_000_000_000, "matmul": 1_000_000_000, "dft": 8_000_000_000,
                 "spectrum": 1, "sampling": 200_000_000}  # fmt: skip
        line = breakdown_line(kinds, flops, ceiling=None)
        # (1 + 8) GFLOP in 0.3 s = 30 GFLOP/s; 0.2 GFLOP in 0.1 s = 2 GFLOP/s.
        assert "matmul 30% (30.0 GFLOP/s), sampling 10% (2.0 GFLOP/s), normalisation 0%" in line


def test_real_step_finds_the_kinds():
    """A profiled step of conv -> GroupNorm -> pool -> linear with SGD: every kind but "other"
    gets time from the ops torch really records."""
    torch.manual_seed(0)
    model = nn.Sequential(
        nn.Conv2d(3, 8, 3, padding=1), nn.GroupNorm(2, 8), nn.ReLU(), nn.MaxPool2d(2),
        nn.Flatten(), nn.Linear(8 * 8 * 8, 4),
    )  # fmt: skip
    opt = torch.optim.SGD(model.parameters(), lr=0.1, momentum=0.9)
    x = torch.randn(4, 3, 16, 16)

    def step() -> float:
        opt.zero_grad()
        model(x).square().sum().backward()
        opt.step()
        return 0.0

    step()
    table, kinds = profile_step(step, 3)
    assert "Self CPU" in table
    for kind in ("convolution", "matmul", "normalisation", "pooling", "optimizer"):
        assert kinds[kind] > 0, (kind, kinds)
    assert kinds["ops"] > 10
