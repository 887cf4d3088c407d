"""``Float32GroupNorm``: ``nn.GroupNorm`` exactly in float32 and float64, float32 statistics
under a bf16 autocast (against ``nn.GroupNorm`` on the upcast input), gradients by gradcheck."""

from __future__ import annotations

import torch
from torch import nn

from benchmark.models.norm import Float32GroupNorm


def pair(groups: int = 4, channels: int = 16) -> tuple[Float32GroupNorm, nn.GroupNorm]:
    torch.manual_seed(0)
    ours, ref = Float32GroupNorm(groups, channels), nn.GroupNorm(groups, channels)
    with torch.no_grad():
        ours.weight.uniform_(0.5, 1.5)
        ours.bias.uniform_(-0.5, 0.5)
    ref.load_state_dict(ours.state_dict())  # same parameters, same keys
    return ours, ref


class TestFloat32GroupNorm:
    def test_is_group_norm_in_float32_and_float64(self):
        ours, ref = pair()
        x = torch.randn(3, 16, 9, 7)
        assert torch.equal(ours(x), ref(x))
        ours64, ref64 = ours.double(), ref.double()
        assert torch.equal(ours64(x.double()), ref64(x.double()))

    def test_bf16_input_normalised_in_float32(self):
        ours, ref = pair()
        x = (torch.randn(2, 16, 12, 12) * 3 + 1).bfloat16()
        with torch.autocast("cpu", dtype=torch.bfloat16):
            y = ours(x)
        assert y.dtype == torch.bfloat16
        want = ref(x.float())  # the statistics of the same (bf16) values, in float32
        torch.testing.assert_close(y.float(), want.bfloat16().float(), rtol=0, atol=0)

    def test_state_dict_keys_are_group_norms(self):
        ours, ref = pair()
        assert list(ours.state_dict()) == list(ref.state_dict())

    def test_gradcheck_float64(self):
        ours, _ = pair(2, 4)
        ours = ours.double()
        x = torch.randn(2, 4, 3, 3, dtype=torch.float64, requires_grad=True)
        assert torch.autograd.gradcheck(ours, (x,))
