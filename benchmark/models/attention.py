"""Squeeze-and-excitation channel attention (Hu et al., SENet; paper Sec. 2.2.3, ref. 35)."""

from __future__ import annotations

from torch import Tensor, nn


class SqueezeExcitation(nn.Module):
    """Reweigh channels by a gate learned from their global average.

    ``x (B, C, H, W) -> x * sigmoid(W2 relu(W1 mean_hw(x)))``, bottleneck ``C // reduction``
    (at least 4 channels so that narrow test encoders keep a usable gate).
    """

    def __init__(self, channels: int, reduction: int = 16) -> None:
        super().__init__()
        if channels <= 0 or reduction <= 0:
            raise ValueError(
                f"SE needs channels > 0 and reduction > 0, got {channels}, {reduction}"
            )
        hidden = max(4, channels // reduction)
        self.pool = nn.AdaptiveAvgPool2d(1)
        self.gate = nn.Sequential(
            nn.Conv2d(channels, hidden, 1),
            nn.ReLU(inplace=True),
            nn.Conv2d(hidden, channels, 1),
            nn.Sigmoid(),
        )

    def forward(self, x: Tensor) -> Tensor:
        return x * self.gate(self.pool(x))
