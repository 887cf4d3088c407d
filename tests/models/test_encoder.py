"""GoogLeNet encoder, SE attention and the ablation variants."""

from __future__ import annotations

import pytest
import torch

from benchmark.models import VARIANTS, parse_variant
from benchmark.models.attention import SqueezeExcitation
from benchmark.models.googlenet import AuxBranch, GoogLeNet


def count(module, cls):
    return sum(isinstance(m, cls) for m in module.modules())


class TestGoogLeNet:
    def test_convention_inception_widths_match_googlenet_paper(self):
        # Szegedy et al. 2015, Table 1: output depths of inception 3a ... 5b.
        enc = GoogLeNet("/", width=1.0, input_size=224)
        depths = [b.out_channels for b in enc.blocks.values()]
        assert depths == [256, 480, 512, 512, 512, 528, 832, 832, 1024]

    def test_convention_spatial_sizes_at_224(self):
        # GoogLeNet paper Table 1: 3a at 28x28, 4a at 14x14, 5b at 7x7.
        enc = GoogLeNet("a-f", width=0.25, input_size=224).eval()
        sizes = {}
        for name in ("3a", "4a", "5b"):
            enc.blocks[name].register_forward_hook(
                lambda m, i, o, name=name: sizes.__setitem__(name, tuple(o.shape[-2:]))
            )
        enc(torch.rand(1, 3, 224, 224))
        assert sizes == {"3a": (28, 28), "4a": (14, 14), "5b": (7, 7)}

    @pytest.mark.parametrize("variant", list(VARIANTS))
    def test_embedding_dims_per_variant(self, variant):
        enc = GoogLeNet(variant, width=0.25, input_size=32)
        fusion = parse_variant(variant).fusion
        assert enc.embedding_dims == ((256, 256, 512) if fusion else (512,))
        out = enc(torch.rand(2, 3, 32, 32), with_aux=True)
        assert [tuple(e.shape) for e in out] == [(2, d) for d in enc.embedding_dims]
        assert len(enc(torch.rand(2, 3, 32, 32), with_aux=False)) == 1

    @pytest.mark.parametrize(
        ("variant", "n_se", "n_aux"), [("/", 0, 0), ("a", 1, 0), ("f", 0, 2), ("a-f", 3, 2)]
    )
    def test_attention_and_fusion_modules(self, variant, n_se, n_aux):
        enc = GoogLeNet(variant, width=0.25, input_size=32)
        assert count(enc, SqueezeExcitation) == n_se
        assert count(enc, AuxBranch) == n_aux

    @pytest.mark.parametrize("size", [(32, 32), (33, 47), (64, 96), (100, 100)])
    def test_any_input_size_from_32(self, size):
        enc = GoogLeNet("a-f", width=0.25, input_size=32)
        out = enc(torch.rand(1, 3, *size), with_aux=True)
        assert all(torch.isfinite(e).all() for e in out)

    def test_width_scales_parameters_quadratically(self):
        # Conv and FC weights scale with width^2, so halving the width quarters (about) the count.
        n_full = sum(p.numel() for p in GoogLeNet("/", 1.0, 64).parameters())
        n_half = sum(p.numel() for p in GoogLeNet("/", 0.5, 64).parameters())
        assert 0.23 < n_half / n_full < 0.27

    @pytest.mark.parametrize("size", [31, 16, 0])
    def test_too_small_input_size_at_construction(self, size):
        with pytest.raises(ValueError, match=f"input_size.*>= 32.*{size}"):
            GoogLeNet("/", width=0.25, input_size=size)

    def test_too_small_image_at_forward(self):
        enc = GoogLeNet("/", width=0.25, input_size=32)
        with pytest.raises(ValueError, match=r"16x40 px.*at least 32"):
            enc(torch.rand(1, 3, 16, 40))

    @pytest.mark.parametrize("width", [0, -0.5, float("nan")])
    def test_bad_width(self, width):
        with pytest.raises(ValueError, match="width"):
            GoogLeNet("/", width=width, input_size=32)

    def test_unknown_variant(self):
        with pytest.raises(ValueError, match=r"'af'.*a-f"):
            GoogLeNet("af", width=0.25, input_size=32)

    def test_unknown_norm(self):
        with pytest.raises(ValueError, match="layer"):
            GoogLeNet("/", width=0.25, input_size=32, norm="layer")

    @pytest.mark.parametrize("norm", ["group", "none"])
    def test_per_sample_norms_do_not_mix_the_batch(self, norm):
        torch.manual_seed(0)
        enc = GoogLeNet("a-f", width=0.25, input_size=32, norm=norm).train()
        x = torch.rand(3, 3, 32, 32)
        together = enc(x, with_aux=True)
        alone = enc(x[:1], with_aux=True)
        for a, b in zip(together, alone, strict=True):
            torch.testing.assert_close(a[:1], b, rtol=1e-4, atol=1e-5)


class TestSqueezeExcitation:
    def test_closed_form(self):
        torch.manual_seed(0)
        se = SqueezeExcitation(32, reduction=8)
        x = torch.randn(2, 32, 5, 7)
        w1, b1 = se.gate[0].weight[:, :, 0, 0], se.gate[0].bias
        w2, b2 = se.gate[2].weight[:, :, 0, 0], se.gate[2].bias
        squeeze = x.mean(dim=(2, 3))
        gate = torch.sigmoid(torch.relu(squeeze @ w1.T + b1) @ w2.T + b2)
        torch.testing.assert_close(se(x), x * gate[:, :, None, None])

    def test_bottleneck_width(self):
        assert SqueezeExcitation(1024, reduction=16).gate[0].out_channels == 64
        assert SqueezeExcitation(16, reduction=16).gate[0].out_channels == 4  # floor of 4

    def test_bad_arguments(self):
        with pytest.raises(ValueError, match="channels"):
            SqueezeExcitation(0)
