"""GoogLeNet / Inception v1 (Szegedy et al. 2015) as used by PoseNet, written in the project.

Layout (channels at width 1.0, spatial size at 224 px)::

    stem   conv7x7/2 64 -> maxpool/2 -> conv1x1 64 -> conv3x3 192 -> maxpool/2     56 -> 28
    3a 256, 3b 480 -> maxpool/2                                                    28 -> 14
    4a 512 -> [aux 1]  4b 512, 4c 512, 4d 528 -> [aux 2]  4e 832 -> maxpool/2      14 -> 7
    5a 832, 5b 1024 -> [final]

    aux i:  [SE] -> adaptive avgpool 4x4 -> conv1x1 128 -> FC 1024 -> ReLU   (embedding 1, 2)
    final:  [SE] -> global avgpool -> FC 2048 -> ReLU                        (embedding 3)

The aux branches sit where PoseNet put its auxiliary regressors (after 4a and 4d); the 2048-wide
final FC is PoseNet's replacement of the classifier. The third inception branch uses a 5x5 conv as
in the original paper. Every channel count and FC width is multiplied by ``width`` (at least 4).
Pooling uses ``ceil_mode`` and the aux pools are adaptive, so any input of at least 32 px per side
works (the final feature map is then 1x1).

Normalisation after each conv: ``'group'`` (GroupNorm of 16-channel groups, per-sample statistics,
default), ``'batch'`` (BatchNorm, batch statistics in training) or ``'none'`` (conv bias only, as
in the original GoogLeNet without LRN). Only the per-sample choices make the result of one image
independent of the rest of the batch in training mode; see ``PoseModel`` on the shared-satellite
optimisation.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

from benchmark.models.attention import SqueezeExcitation
from benchmark.models.encoder import Encoder, parse_variant
from benchmark.models.registry import register_encoder

NORMS = ("batch", "group", "none")
MIN_INPUT_SIZE = 32

# name: (in, 1x1, 3x3 reduce, 3x3, 5x5 reduce, 5x5, pool proj) at width 1.0
INCEPTION_CONFIG: dict[str, tuple[int, ...]] = {
    "3a": (192, 64, 96, 128, 16, 32, 32),
    "3b": (256, 128, 128, 192, 32, 96, 64),
    "4a": (480, 192, 96, 208, 16, 48, 64),
    "4b": (512, 160, 112, 224, 24, 64, 64),
    "4c": (512, 128, 128, 256, 24, 64, 64),
    "4d": (512, 112, 144, 288, 32, 64, 64),
    "4e": (528, 256, 160, 320, 32, 128, 128),
    "5a": (832, 256, 160, 320, 32, 128, 128),
    "5b": (832, 384, 192, 384, 48, 128, 128),
}


def _norm(kind: str, channels: int) -> nn.Module:
    if kind == "batch":
        return nn.BatchNorm2d(channels)
    # 'group': groups of (about) 16 channels; math.gcd keeps it a divisor for any width.
    return nn.GroupNorm(math.gcd(channels, max(1, channels // 16)), channels)


class ConvNormReLU(nn.Sequential):
    def __init__(self, c_in: int, c_out: int, kernel: int, stride: int = 1, norm: str = "group"):
        layers: list[nn.Module] = [
            nn.Conv2d(c_in, c_out, kernel, stride, kernel // 2, bias=norm == "none")
        ]
        if norm != "none":
            layers.append(_norm(norm, c_out))
        layers.append(nn.ReLU(inplace=True))
        super().__init__(*layers)


class Inception(nn.Module):
    """Four parallel branches (1x1 | 1x1-3x3 | 1x1-5x5 | maxpool-1x1), concatenated."""

    def __init__(
        self, c_in: int, c1: int, c3r: int, c3: int, c5r: int, c5: int, cp: int, norm: str
    ):
        super().__init__()
        self.b1 = ConvNormReLU(c_in, c1, 1, norm=norm)
        self.b2 = nn.Sequential(
            ConvNormReLU(c_in, c3r, 1, norm=norm), ConvNormReLU(c3r, c3, 3, norm=norm)
        )
        self.b3 = nn.Sequential(
            ConvNormReLU(c_in, c5r, 1, norm=norm), ConvNormReLU(c5r, c5, 5, norm=norm)
        )
        self.b4 = nn.Sequential(
            nn.MaxPool2d(3, stride=1, padding=1, ceil_mode=True),
            ConvNormReLU(c_in, cp, 1, norm=norm),
        )
        self.out_channels = c1 + c3 + c5 + cp

    def forward(self, x: Tensor) -> Tensor:
        return torch.cat([self.b1(x), self.b2(x), self.b3(x), self.b4(x)], dim=1)


class AuxBranch(nn.Module):
    """``[SE] -> avgpool 4x4 -> conv1x1 -> FC -> ReLU``: embedding 1 or 2 (PoseNet's aux branch)."""

    def __init__(self, c_in: int, conv: int, dim: int, attention: bool, norm: str):
        super().__init__()
        self.se = SqueezeExcitation(c_in) if attention else nn.Identity()
        self.pool = nn.AdaptiveAvgPool2d(4)
        self.conv = ConvNormReLU(c_in, conv, 1, norm=norm)
        self.fc = nn.Linear(conv * 16, dim)

    def forward(self, x: Tensor) -> Tensor:
        x = self.conv(self.pool(self.se(x)))
        return torch.relu(self.fc(torch.flatten(x, 1)))


class FinalBranch(nn.Module):
    """``[SE] -> global avgpool -> FC -> ReLU``: embedding 3."""

    def __init__(self, c_in: int, dim: int, attention: bool):
        super().__init__()
        self.se = SqueezeExcitation(c_in) if attention else nn.Identity()
        self.fc = nn.Linear(c_in, dim)

    def forward(self, x: Tensor) -> Tensor:
        x = self.se(x).mean(dim=(2, 3))
        return torch.relu(self.fc(x))


class GoogLeNet(Encoder):
    """Inception v1 trunk with PoseNet-style embeddings; see the module docstring.

    Args:
        variant: ``'/'``, ``'a'``, ``'f'`` or ``'a-f'`` (see ``benchmark.models.encoder``).
        width: channel/width multiplier (> 0); 1.0 is the paper's network.
        input_size: nominal input side in px (>= 32); used for validation and FLOP counts.
        norm: ``'batch'``, ``'group'`` or ``'none'``.
    """

    min_input_size = MIN_INPUT_SIZE

    def __init__(
        self, variant: str = "a-f", width: float = 1.0, input_size: int = 224, norm: str = "group"
    ):
        super().__init__()
        spec = parse_variant(variant)
        if isinstance(width, bool) or not isinstance(width, (int, float)) or not width > 0:
            raise ValueError(f"GoogLeNet: width must be > 0, got {width!r}")
        if (
            isinstance(input_size, bool)
            or not isinstance(input_size, int)
            or input_size < MIN_INPUT_SIZE
        ):
            raise ValueError(
                f"GoogLeNet: input_size must be an int >= {MIN_INPUT_SIZE} px, got {input_size!r}"
            )
        if norm not in NORMS:
            raise ValueError(f"GoogLeNet: norm must be one of {NORMS}, got {norm!r}")
        self.variant, self.width, self.input_size, self.norm = (
            spec.name,
            float(width),
            input_size,
            norm,
        )

        def c(n: int) -> int:
            return max(4, round(n * width))

        self.stem = nn.Sequential(
            ConvNormReLU(3, c(64), 7, stride=2, norm=norm),
            nn.MaxPool2d(3, stride=2, ceil_mode=True),
            ConvNormReLU(c(64), c(64), 1, norm=norm),
            ConvNormReLU(c(64), c(192), 3, norm=norm),
            nn.MaxPool2d(3, stride=2, ceil_mode=True),
        )
        blocks: dict[str, Inception] = {}
        c_in = c(192)
        for name, cfg in INCEPTION_CONFIG.items():
            blocks[name] = Inception(c_in, *(c(n) for n in cfg[1:]), norm=norm)
            c_in = blocks[name].out_channels
        self.blocks = nn.ModuleDict(blocks)
        self.pool3 = nn.MaxPool2d(3, stride=2, ceil_mode=True)
        self.pool4 = nn.MaxPool2d(3, stride=2, ceil_mode=True)

        final_dim, aux_dim = c(2048), c(1024)
        self.final = FinalBranch(blocks["5b"].out_channels, final_dim, "final" in spec.attention)
        self.fusion = spec.fusion
        if spec.fusion:
            self.aux1 = AuxBranch(
                blocks["4a"].out_channels, c(128), aux_dim, "aux1" in spec.attention, norm
            )
            self.aux2 = AuxBranch(
                blocks["4d"].out_channels, c(128), aux_dim, "aux2" in spec.attention, norm
            )
            self.embedding_dims = (aux_dim, aux_dim, final_dim)
        else:
            self.embedding_dims = (final_dim,)

    def forward(self, x: Tensor, with_aux: bool = False) -> list[Tensor]:
        self.check_input(x)
        b = self.blocks
        x = b["3b"](b["3a"](self.stem(x)))
        x = b["4a"](self.pool3(x))
        aux = with_aux and self.fusion
        e1 = self.aux1(x) if aux else None
        x = b["4d"](b["4c"](b["4b"](x)))
        e2 = self.aux2(x) if aux else None
        x = b["5b"](b["5a"](self.pool4(b["4e"](x))))
        e3 = self.final(x)
        return [e1, e2, e3] if aux else [e3]


@register_encoder("googlenet")
def googlenet(
    variant: str = "a-f", width: float = 1.0, input_size: int = 224, norm: str = "group"
) -> GoogLeNet:
    return GoogLeNet(variant=variant, width=width, input_size=input_size, norm=norm)
