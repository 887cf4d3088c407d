"""The head contract: what training and evaluation may call on any head (implicit_pdf style).

An attitude head maps the concatenated pair embedding ``features (B, F)`` to a raw output (a tensor
or a dict of tensors, whatever the head needs) and knows how to turn that raw output into a rotation
and into a loss::

    raw = head(features)            # (B, F) -> raw
    R = head.decode(raw)            # (B, 3, 3), det +1; the label frame is R_uav^sat (Eq. 2)
    loss = head.loss(raw, R_gt)     # scalar, mean over the batch

Probabilistic heads (``is_probabilistic = True``) additionally give::

    head.distribution(raw)          # per-grid probabilities (tensor or dict), each summing to 1
    head.log_prob(raw, R)           # (B,) log density of the rotations R under the prediction,
                                    # w.r.t. the normalised Haar measure on SO(3): a uniform
                                    # prediction scores 0, so every head's value is comparable
    head.uncertainty(raw)           # (B,) higher = less certain (each head documents its measure)
    head.target_distribution(R)     # the training target, same structure as distribution(raw)
    head.decode_distribution(dist)  # (B, 3, 3) == decode(raw) for dist = distribution(raw)

A head whose representation is a density but not a distribution on a grid (Bingham, matrix Fisher)
keeps ``is_probabilistic = False`` and declares what it does give: ``gives_log_prob = True``
(``log_prob`` as above, w.r.t. the normalised Haar measure) and/or ``gives_uncertainty = True``
(``uncertainty``). Evaluation asks for a head's log-likelihood and uncertainty exactly when
``is_probabilistic`` or the matching flag is set.

A translation head is the same with ``decode(raw) -> (B, 3)`` metres ``[dE, dN, dU]`` and
``loss(raw, T_gt (B, 3))``. Translation heads regress standardised values; the training-set mean
and standard deviation are buffers (``set_statistics``) so they are saved in the state dict.
Training calls ``fit_statistics(T_train)``; a head that needs more statistics of the labels
(Re-Net-T: the mean and std of ``|u|``, ``u = (T - mean) / std``) overrides it and keeps them
in buffers too.

Every head is built as ``cls(in_features=F, **options)``; it validates its options in ``__init__``
and raises ``ValueError`` naming the option and value.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import torch
from torch import Tensor, nn

Raw = Any  # a Tensor or a dict of Tensors; only the head that produced it interprets it

# DirectionNet (Chen et al. 2021) predicts distributions on a 64 x 64 equirectangular grid. Its
# alpha = 8e7 weighs a sin-weighted *mean* over those 4096 pixels; see distribution_loss_scale.
DIRECTIONNET_PIXELS = 64 * 64
DIRECTIONNET_PIXEL_SOLID_ANGLE = (math.pi / 64) * (2 * math.pi / 64)  # d(colat) * d(lon), sr


def sphere_volume(dim: int) -> float:
    """Surface measure of the unit sphere in R^dim: 4 pi for S^2 (dim 3), 2 pi^2 for S^3 (dim 4)."""
    return 2 * math.pi ** (dim / 2) / math.gamma(dim / 2)


def distribution_loss_scale(n_points: int, dim: int = 3) -> float:
    """Factor ``s`` that makes ``alpha * s * sum_k (p_k - p*_k)^2`` mean what DirectionNet's
    ``alpha * L_dis`` means, for probabilities ``p`` (sum 1) on an equal-area lattice of
    ``n_points`` points on the sphere in R^dim.

    Let f be a density w.r.t. area (1/sr). DirectionNet normalises its 64 x 64 maps so that
    ``sum_ij q_ij sin(theta_i) = 1``, i.e. ``q_ij = f_ij dtheta dphi``, and its loss is
    ``mean_ij sin(theta_i) (q_ij - q*_ij)^2 = (dOmega0 / 4096) * integral (f - f*)^2 dA`` with
    ``dOmega0 = dtheta dphi = 2 pi^2 / 4096``. On an equal-area lattice with cell measure ``V / N``
    our probabilities are ``p_k = f_k V / N``, so ``sum_k (p_k - p*_k)^2 = (V / N) integral
    (f - f*)^2 dA``. Equating the two gives ``s = dOmega0 N / (4096 V)``; for the paper's N = 4096
    on S^2 that is ``pi / 8192 = 3.83e-4`` (equivalently: DirectionNet's grid with every sin weight
    replaced by its mean 2/pi). The loss then weighs the same L2 distance between densities by the
    same alpha, independently of the grid.
    """
    volume = sphere_volume(dim)
    return DIRECTIONNET_PIXEL_SOLID_ANGLE * n_points / (DIRECTIONNET_PIXELS * volume)


def check_in_features(in_features: object, owner: str) -> int:
    if isinstance(in_features, bool) or not isinstance(in_features, int) or in_features <= 0:
        raise ValueError(f"{owner}: in_features must be a positive int, got {in_features!r}")
    return in_features


def check_option(
    value: float, name: str, owner: str, *, minimum: float = 0.0, inclusive: bool = False
) -> float:
    """A finite float option ``> minimum`` (``>= minimum`` with ``inclusive``)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{owner}: {name} must be a finite number, got {value!r}")
    if value < minimum or (value == minimum and not inclusive):
        op = ">=" if inclusive else ">"
        raise ValueError(f"{owner}: {name} must be {op} {minimum}, got {value!r}")
    return float(value)


def check_lattice_options(
    owner: str, n_points: object, kappa: float, alpha: float, *, min_points: int = 4
) -> tuple[float, float]:
    """The options every lattice-distribution head shares: ``(kappa, alpha)`` checked as floats
    (kappa > 0, alpha >= 0) and ``n_points`` an int >= ``min_points``."""
    kappa = check_option(kappa, "kappa", owner)
    alpha = check_option(alpha, "alpha", owner, inclusive=True)
    if isinstance(n_points, bool) or not isinstance(n_points, int) or n_points < min_points:
        raise ValueError(f"{owner}: n_points must be an int >= {min_points}, got {n_points!r}")
    return kappa, alpha


def mlp(in_features: int, hidden: int, out_features: int) -> nn.Sequential:
    """``Linear(in, hidden) -> ReLU -> Linear(hidden, out)``: the layers of every head."""
    if hidden <= 0:
        raise ValueError(f"hidden must be a positive int, got {hidden!r}")
    return nn.Sequential(
        nn.Linear(in_features, hidden), nn.ReLU(inplace=True), nn.Linear(hidden, out_features)
    )


def nearest_grid_index(x: Tensor, grid: Tensor) -> Tensor:
    """Index of the grid point closest (largest dot product) to each unit vector.

    x: (..., d); grid: (n, d) -> (...) int64.
    """
    return (x @ grid.to(x.dtype).T).argmax(dim=-1)


def _check_features_hook(head: Head, args: tuple) -> None:
    if len(args) != 1:
        raise TypeError(f"{type(head).__name__} takes one features tensor, got {len(args)} args")
    head._check_features(args[0])


class Head(nn.Module):
    """Common base: registry name, the paper's name and the probabilistic flag."""

    name: ClassVar[str] = ""  # set by @register_head
    paper_name: ClassVar[str] = ""  # e.g. "Pd/Re-Net", "Re-Net-R"
    is_probabilistic: ClassVar[bool] = False  # the full grid-distribution contract
    gives_log_prob: ClassVar[bool] = False  # log_prob without the grid contract (see above)
    gives_uncertainty: ClassVar[bool] = False  # uncertainty without the grid contract
    # Bump when the head's maths changes (target, loss, decoding) without its options changing:
    # the runner and `uavbench train` key finished runs on it, so old results are not reused.
    version: ClassVar[int] = 1

    def __init__(self, in_features: int) -> None:
        super().__init__()
        self.in_features = check_in_features(in_features, type(self).__name__)
        # Every head checks its input shape, without each forward having to remember it.
        self.register_forward_pre_hook(_check_features_hook)

    def forward(self, features: Tensor) -> Raw:  # (B, F) -> raw
        raise NotImplementedError

    def _check_features(self, features: object) -> None:
        if (
            not isinstance(features, Tensor)
            or features.dim() != 2
            or features.shape[1] != self.in_features
        ):
            raise ValueError(
                f"{type(self).__name__}: features must have shape (B, {self.in_features}), "
                f"got {tuple(getattr(features, 'shape', ())) or type(features).__name__}"
            )

    def _not_probabilistic(self, what: str) -> NotImplementedError:
        return NotImplementedError(f"{type(self).__name__} is a regression head: no {what}")

    # Optional for probabilistic heads; regression heads raise.
    def distribution(self, raw: Raw) -> Any:
        raise self._not_probabilistic("distribution")

    def uncertainty(self, raw: Raw) -> Tensor:
        raise self._not_probabilistic("uncertainty")

    def target_distribution(self, label: Tensor) -> Any:
        raise self._not_probabilistic("target distribution")

    def decode_distribution(self, dist: Any) -> Tensor:
        raise self._not_probabilistic("decode_distribution")


class AttitudeHead(Head):
    """Base class of attitude heads. Label: ``R_uav^sat (B, 3, 3)``."""

    def decode(self, raw: Raw) -> Tensor:  # -> (B, 3, 3), det +1
        raise NotImplementedError

    def loss(self, raw: Raw, R_gt: Tensor) -> Tensor:  # -> () scalar, mean over the batch
        raise NotImplementedError

    def log_prob(self, raw: Raw, R: Tensor) -> Tensor:  # -> (B,)
        raise self._not_probabilistic("log_prob")

    # Optional: ``log_prob_many(raw, R (B, K, 3, 3)) -> (B, K)``, the log_prob of K rotations per
    # sample, for a head whose log_prob pays a per-sample cost (a normaliser) that K rotations
    # can share. The flight fusion's beliefs use it when present (benchmark.evaluation.beliefs),
    # else log_prob row by row; a test checks the two agree for every head that defines it.


class TranslationHead(Head):
    """Base class of translation heads. Label ``T = [dE, dN, dU] (B, 3)`` in metres.

    ``mean``/``std`` (3,) are buffers holding the training-set statistics used to standardise the
    label; the defaults (0, 1) mean "not set". ``fit_statistics(T_train)`` computes them.
    """

    def __init__(self, in_features: int) -> None:
        super().__init__(in_features)
        self.register_buffer("mean", torch.zeros(3))
        self.register_buffer("std", torch.ones(3))

    def set_statistics(self, mean: Tensor, std: Tensor) -> None:
        """Store the training-set mean and std of ``T`` (each (3,), metres)."""
        mean = torch.as_tensor(mean, dtype=self.mean.dtype)
        std = torch.as_tensor(std, dtype=self.std.dtype)
        if mean.shape != (3,) or std.shape != (3,):
            raise ValueError(
                f"{type(self).__name__}.set_statistics: mean and std must have shape (3,), "
                f"got {tuple(mean.shape)} and {tuple(std.shape)}"
            )
        if not (torch.isfinite(mean).all() and torch.isfinite(std).all() and (std > 0).all()):
            raise ValueError(
                f"{type(self).__name__}.set_statistics: need finite mean and std > 0, "
                f"got mean={mean.tolist()} std={std.tolist()}"
            )
        self.mean.copy_(mean)
        self.std.copy_(std)

    def fit_statistics(self, T: Tensor) -> None:
        """Set the statistics from the training labels ``T (M, 3)`` (population std, floored)."""
        if T.dim() != 2 or T.shape[1] != 3 or T.shape[0] < 2:
            raise ValueError(f"fit_statistics needs T of shape (M >= 2, 3), got {tuple(T.shape)}")
        T = T.double()
        self.set_statistics(T.mean(0), T.std(0, unbiased=False).clamp_min(1e-6))

    def standardize(self, T: Tensor) -> Tensor:
        return (T - self.mean.to(T.dtype)) / self.std.to(T.dtype)

    def unstandardize(self, z: Tensor) -> Tensor:
        return z * self.std.to(z.dtype) + self.mean.to(z.dtype)

    def decode(self, raw: Raw) -> Tensor:  # -> (B, 3) metres
        raise NotImplementedError

    def loss(self, raw: Raw, T_gt: Tensor) -> Tensor:  # -> () scalar
        raise NotImplementedError

    # Optional: ``position_log_prob(raw, en (B, M, 2)) -> (B, M)``, the head's own log-density
    # per m^2 of M horizontal positions (dE, dN metres; marginal over dU) per sample. The flight
    # fusion uses it as the head's position belief when present (benchmark.evaluation
    # .sequence_eval), else a Gaussian + uniform density around ``decode`` calibrated on the
    # validation split.
