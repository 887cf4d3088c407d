"""Pixel-level parts of the matching encoder (issue 21, item 4: features that transfer to an
unseen city style).

- :func:`grey_gradient`: two fixed feature channels, the grey level and its gradient magnitude,
  standardised per image. Correlating them is what the geometry oracle does
  (``benchmark.references.oracle``: normalised cross-correlation of grey levels and gradient
  magnitude), and it does not depend on a style's palette the way learned colour features do.
- :func:`photometric_jitter`: random, label-free changes of an image's colours (saturation,
  gamma, contrast, brightness, a colour cast and, sometimes, a permutation of the RGB channels),
  drawn per image. Geometry is untouched, so every label stays exact.

Both work on RGB images in [0, 1] (``PoseModel`` hands encoders ImageNet-normalised images:
:func:`denormalize` and :func:`normalize` go back and forth).
"""

from __future__ import annotations

import torch
import torch.nn.functional as nnf
from torch import Tensor

from benchmark.models.pair_encoder import IMAGENET_MEAN, IMAGENET_STD

__all__ = ["denormalize", "grey_gradient", "normalize", "photometric_jitter"]

# Sobel kernels / 8: the gradient of a unit ramp is 1 per pixel.
_SOBEL = (((-1.0, 0.0, 1.0), (-2.0, 0.0, 2.0), (-1.0, 0.0, 1.0)),)


def _stats(x: Tensor) -> tuple[Tensor, Tensor]:
    mean = x.new_tensor(IMAGENET_MEAN).view(1, 3, 1, 1)
    std = x.new_tensor(IMAGENET_STD).view(1, 3, 1, 1)
    return mean, std


def denormalize(x: Tensor) -> Tensor:
    """ImageNet-normalised ``(B, 3, H, W)`` -> RGB in [0, 1] (up to rounding)."""
    mean, std = _stats(x)
    return x * std + mean


def normalize(x: Tensor) -> Tensor:
    """RGB ``(B, 3, H, W)`` in [0, 1] -> ImageNet-normalised."""
    mean, std = _stats(x)
    return (x - mean) / std


def grey_gradient(x: Tensor, pool: tuple[int, int]) -> Tensor:
    """``(B, 3, H, W)`` images (any affine per-channel scaling: the result is standardised) ->
    ``(B, 2, H / pool[1], W / pool[0])``: the grey level (channel mean) and its Sobel gradient
    magnitude, average-pooled by ``pool`` = (columns, rows) like the trunk's features, each
    standardised over the image (zero mean, unit standard deviation; a flat image gives zeros)."""
    grey = x.mean(1, keepdim=True)
    kernel = grey.new_tensor(_SOBEL) / 8.0  # (1, 3, 3)
    kernels = torch.stack([kernel, kernel.transpose(1, 2)])  # (2, 1, 3, 3): d/dx, d/dy
    grad = nnf.conv2d(nnf.pad(grey, (1, 1, 1, 1), mode="replicate"), kernels)
    # +1e-12 keeps the square root differentiable where the gradient is exactly zero
    magnitude = (grad.square().sum(1, keepdim=True) + 1e-12).sqrt()
    f = nnf.avg_pool2d(torch.cat([grey, magnitude], 1), kernel_size=(pool[1], pool[0]))
    mu = f.mean((2, 3), keepdim=True)
    sd = f.std((2, 3), keepdim=True).clamp(min=1e-3)
    return (f - mu) / sd


def photometric_jitter(
    x: Tensor, strength: float, generator: torch.Generator | None = None
) -> Tensor:
    """RGB ``(B, 3, H, W)`` in [0, 1] -> the same images with random colours, drawn per image from
    the default generator (or ``generator``): saturation x ``1 + 0.5 s N``, gamma
    ``exp(0.3 s N)``, contrast and brightness x ``exp(0.3 s N)``, per-channel gain
    ``exp(0.1 s N)``, and with probability ``0.3 s`` (at most 1) the RGB channels in a random order;
    ``s = strength`` (0: unchanged). Clamped to [0, 1]."""
    if strength <= 0:
        return x
    b = x.shape[0]

    def draw(*shape: int) -> Tensor:
        return torch.randn(*shape, generator=generator, device=x.device, dtype=x.dtype)

    grey = x.mean(1, keepdim=True)
    saturation = (1 + 0.5 * strength * draw(b, 1, 1, 1)).clamp(0, 2)
    # clamped above 0 so that the gamma of a black pixel stays finite in the backward pass
    y = (grey + (x - grey) * saturation).clamp(1e-4, 1)
    y = y.pow(torch.exp(0.3 * strength * draw(b, 1, 1, 1)))
    m = y.mean((1, 2, 3), keepdim=True)
    y = (y - m) * torch.exp(0.3 * strength * draw(b, 1, 1, 1)) + m
    y = (
        y
        * torch.exp(0.3 * strength * draw(b, 1, 1, 1))
        * torch.exp(0.1 * strength * draw(b, 3, 1, 1))
    )
    p_permute = min(1.0, 0.3 * strength)
    permute = torch.rand(b, generator=generator, device=x.device) < p_permute
    order = torch.argsort(torch.rand(b, 3, generator=generator, device=x.device), dim=1)
    order = torch.where(permute[:, None], order, torch.arange(3, device=x.device))
    y = torch.gather(y, 1, order[:, :, None, None].expand_as(y))
    return y.clamp(0, 1)
