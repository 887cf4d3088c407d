"""Divergence (issue 14): a training loss at any step, a weight, a validation loss or metric, or
an evaluation metric that is NaN or inf fails the run with :class:`DivergenceError`, one line
naming when, which term and the fix. Used by the loop (``benchmark.training.loop``) and the
train-then-evaluate path (``benchmark.training.pipeline``).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

import torch


class DivergenceError(RuntimeError):
    """Training diverged: a training loss (any step), a weight, a validation loss or metric, or
    an evaluation metric became NaN or inf. The run fails (the caller marks it FAILED with this
    message as its reason); the checkpoint of the last finished epoch, written before, is kept.

    ``where`` says when (``"epoch 1, step 2"``, ``"validation after epoch 3"``, ...), ``term``
    which loss term or metric went non-finite first, ``values`` every term at that moment."""

    def __init__(
        self, what: str, where: str, term: str, values: Mapping[str, float], lr: float | None
    ) -> None:
        self.what, self.where, self.term = what, where, term
        self.values = dict(values)
        shown = ", ".join(f"{k}={v:.6g}" for k, v in self.values.items())
        now = f" (now {lr:g})" if lr is not None else ""
        super().__init__(
            f"diverged: non-finite {what} at {where}: {term}={self.values.get(term, math.nan):g}"
            f" ({shown}); lower optim.lr{now} or set optim.grad_clip. The checkpoint of the last"
            " finished epoch (if any) is kept"
        )


NonFiniteLossError = DivergenceError  # its name before issue 14 (still exported)


def non_finite_term(values: Mapping[str, float], keys: Iterable[str] | None = None) -> str | None:
    """The first of ``keys`` (default: all) whose value in ``values`` is NaN or inf, naming a
    component before the ``total`` it adds up to; None when all are finite."""
    keys = list(values) if keys is None else [k for k in keys if k in values]
    bad = [k for k in keys if not math.isfinite(float(values[k]))]
    parts = [k for k in bad if not k.endswith("total")]
    return (parts or bad or [None])[0]


def check_finite(
    what: str, where: str, values: Mapping[str, float], lr: float | None,
    keys: Iterable[str] | None = None,
) -> None:  # fmt: skip
    """Raise :class:`DivergenceError` if one of ``keys`` of ``values`` is not finite."""
    term = non_finite_term(values, keys)
    if term is not None:
        checked = [k for k in (values if keys is None else keys) if k in values]
        if len(checked) > 6:  # a long summary: show only what went non-finite
            checked = [k for k in checked if not math.isfinite(float(values[k]))]
        raise DivergenceError(what, where, term, {k: float(values[k]) for k in checked}, lr)


def non_finite_weights(model: torch.nn.Module) -> list[str]:
    """Names of the floating-point parameters and buffers of ``model`` holding a NaN or inf (one
    ``isfinite`` pass over the weights: about a millisecond per million weights on a CPU)."""
    return [
        name
        for name, t in model.state_dict().items()
        if t.is_floating_point() and not bool(torch.isfinite(t).all())
    ]
