"""Input validation shared by the geometry functions.

Every public geometry function validates its inputs eagerly so that a wrong shape or a NaN fails
where it enters, with the shape or value in the message, instead of deep inside a network.
"""

from __future__ import annotations

import torch
from torch import Tensor


def check_tensor(x: object, name: str) -> Tensor:
    if not isinstance(x, Tensor):
        raise ValueError(f"{name} must be a torch.Tensor, got {type(x).__name__}")
    if not (x.is_floating_point()):
        raise ValueError(f"{name} must be a floating point tensor, got dtype {x.dtype}")
    return x


def check_finite(x: Tensor, name: str) -> None:
    # Skipped while tracing/compiling would be nice, but the cost (one reduction) is negligible next
    # to a network forward pass and it catches NaNs where they enter.
    if not bool(torch.isfinite(x).all()):
        bad = x[~torch.isfinite(x)].flatten()[:3].tolist()
        raise ValueError(f"{name} contains non-finite values (e.g. {bad}), shape {tuple(x.shape)}")


def check_last_dims(x: object, dims: tuple[int, ...], name: str) -> Tensor:
    """Check that ``x`` is a finite float tensor of shape ``(..., *dims)``."""
    x = check_tensor(x, name)
    shape_str = "(..., " + ", ".join(str(d) for d in dims) + ")"
    if x.dim() < len(dims) or tuple(x.shape[-len(dims) :]) != dims:
        raise ValueError(f"{name} must have shape {shape_str}, got {tuple(x.shape)}")
    check_finite(x, name)
    return x


def check_positive(value: float | Tensor, name: str) -> None:
    if isinstance(value, Tensor):
        ok = bool(torch.isfinite(value).all()) and bool((value > 0).all())
        shown = value.flatten()[:3].tolist()
    else:
        ok = value == value and value > 0 and value != float("inf")
        shown = value
    if not ok:
        raise ValueError(f"{name} must be finite and > 0, got {shown}")
