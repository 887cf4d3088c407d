"""Shared head bases: a head that derives from one of these declares its representation only.

Two families of heads share their maths (issue 13):

``LatticeHead`` (attitude, probabilistic). The head predicts ``channels`` softmax distributions over
an equal-area lattice of ``n_points`` unit vectors in R^d (DirectionNet, paper Eq. 9-15). The base
owns the options ``n_points`` (4096), ``kappa`` (10, > 0), ``alpha`` (8e7, >= 0), ``hidden`` (160),
their checks, the ``grid`` buffer (not saved: rebuilt from ``n_points``), the ``LatticeDecoder``
(state-dict keys ``decoder.net.*``), the softmax distribution, the vMF target, the Eq. 13 + Eq. 14
loss (``directionnet_loss``), decoding by the normalised expectation (Eq. 9, ``spherical_mean``)
and the uncertainty ``1 - |sum p x|`` (mean over the channels). A subclass declares::

    channels: int          # directions per rotation: raw (B, n) for 1, (B, channels, n) otherwise
    lattice(n) -> (n, d)   # staticmethod: the grid, e.g. fibonacci_sphere, super_fibonacci
    encode(R) -> x         # (B, 3, 3) -> label directions, (B, d) or (B, channels, d), unit
    to_label(m) -> R       # normalised expectations, shaped like encode's output -> (B, 3, 3)
    log_density(log_p, R)  # (B,) log density of R w.r.t. the normalised Haar measure on SO(3)

A one-channel lattice on S^3 (d = 4) is read as unit quaternions ``(w, x, y, z)``: there the base
already supplies ``to_label`` (``quat_to_rotmat``) and ``log_density`` (``q`` and ``-q`` are one
rotation: ``haar_log_density_s3``), so such a head declares ``lattice`` and ``encode`` only.
and may override ``target(x, grid)`` (default the discrete vMF, Eq. 10), ``loss_resultant`` (the
vector the Eq. 13 cosine compares with the label; default ``sum p x``), ``decode_distribution``
and ``uncertainty``.

``RegressionAttitudeHead`` / ``RegressionTranslationHead``. ``Linear(F, hidden) -> ReLU ->
Linear(hidden, prod(raw_shape))`` (state-dict keys ``net.*``, option ``hidden`` = 1024) reshaped to
``(B, *raw_shape)``; the loss is ``distance(normalize(raw), encode(label))`` averaged over the
batch (default: squared Euclidean distance over the representation's axes) and decoding is
``to_label(normalize(raw))``. A subclass declares ``raw_shape``, ``encode`` and ``to_label``
(the translation base already does: the standardised translation) and, where the representation
is constrained, ``normalize`` (e.g. unit quaternions).
"""

from __future__ import annotations

import math
from typing import ClassVar

import torch
from torch import Tensor

from benchmark.geometry import discrete_vmf, quat_to_rotmat, rotmat_to_quat, spherical_mean
from benchmark.models.heads import AttitudeHead, TranslationHead, check_lattice_options, mlp
from benchmark.models.spherical import (
    LatticeDecoder,
    directionnet_loss,
    haar_log_density_s3,
    resultant_length,
)


class LatticeHead(AttitudeHead):
    """Base of the lattice-distribution attitude heads (see the module docstring for the hooks).

    Args: in_features; n_points (4096, >= ``min_points``); kappa (10, > 0); alpha (8e7, >= 0,
    DirectionNet's units, see ``distribution_loss_scale``); hidden (160, decoder bottleneck).
    """

    is_probabilistic = True
    channels: ClassVar[int] = 1
    min_points: ClassVar[int] = 4

    def __init__(
        self,
        in_features: int,
        n_points: int = 4096,
        kappa: float = 10.0,
        alpha: float = 8e7,
        hidden: int = 160,
    ) -> None:
        super().__init__(in_features)
        owner = self.name or type(self).__name__
        self.kappa, self.alpha = check_lattice_options(
            owner, n_points, kappa, alpha, min_points=self.min_points
        )
        self.register_buffer("grid", self.lattice(n_points), persistent=False)
        self.decoder = LatticeDecoder(in_features, self.channels, n_points, hidden)

    # -- the representation (subclasses) ---------------------------------------------------------
    @staticmethod
    def lattice(n_points: int) -> Tensor:
        """``(n_points, d)`` unit vectors, float32, nearly uniform (equal cells)."""
        raise NotImplementedError

    def encode(self, R: Tensor) -> Tensor:
        """``R (B, 3, 3)`` -> label directions ``(B, d)`` (one channel) or ``(B, C, d)``, unit."""
        raise NotImplementedError

    def to_label(self, directions: Tensor) -> Tensor:
        """Unit mean directions shaped like ``encode``'s output -> ``(B, 3, 3)``, det +1.

        Default: only for a one-channel lattice on S^3, whose directions are unit quaternions.
        """
        self._require_quaternions("to_label")
        return quat_to_rotmat(directions)

    def log_density(self, log_p: Tensor, R: Tensor) -> Tensor:
        """``log_p`` (log of ``distribution``), ``R (B, 3, 3)`` -> ``(B,)`` log density of R
        w.r.t. the normalised Haar measure on SO(3) (0 for a uniform prediction).

        Default: only for a one-channel lattice on S^3, ``log(p(q) + p(-q)) + log(n / 2)``.
        """
        self._require_quaternions("log_density")
        return haar_log_density_s3(log_p, rotmat_to_quat(R).to(log_p.dtype), self.grid)

    def _require_quaternions(self, hook: str) -> None:
        if self.channels != 1 or self.grid.shape[-1] != 4:
            raise NotImplementedError(
                f"{type(self).__name__} must define {hook}: the default exists only for one "
                f"channel on S^3 (quaternions), not {self.channels} channel(s) in "
                f"R^{self.grid.shape[-1]}"
            )

    def target(self, directions: Tensor, grid: Tensor) -> Tensor:
        """Target probabilities around the label directions (default Eq. 10, the discrete vMF
        ``softmax_k(kappa x.g_k)``): ``(..., d)``, ``grid (n, d)`` -> ``(..., n)``."""
        return discrete_vmf(directions, self.kappa, grid)

    def loss_resultant(self, p: Tensor, directions: Tensor, grid: Tensor) -> Tensor:
        """The vector Eq. 13 compares with the label: ``sum_k p_k g_k``, ``(..., n)`` ->
        ``(..., d)``, before normalisation (Algorithm 1 step 3)."""
        return p @ grid

    # -- the contract ----------------------------------------------------------------------------
    def forward(self, features: Tensor) -> Tensor:
        """(B, F) -> logits (B, n) for one channel, (B, channels, n) otherwise."""
        logits = self.decoder(features)
        return logits[:, 0] if self.channels == 1 else logits

    def distribution(self, raw: Tensor) -> Tensor:
        """Probabilities shaped like ``raw``, each row summing to 1 (softmax over the lattice)."""
        return torch.softmax(raw, dim=-1)

    def target_distribution(self, R: Tensor) -> Tensor:
        """(B, 3, 3) -> the training target, shaped like ``distribution(raw)``."""
        return self.target(self.encode(R), self.grid.to(R.dtype))

    def decode_distribution(self, p: Tensor) -> Tensor:
        """Probabilities -> (B, 3, 3): the normalised expectation of each channel (Eq. 9)."""
        return self.to_label(spherical_mean(p, self.grid))

    def decode(self, raw: Tensor) -> Tensor:
        return self.decode_distribution(self.distribution(raw))

    def loss(self, raw: Tensor, R_gt: Tensor) -> Tensor:
        """``sum_c [1 - cos(m_c, x_c) + alpha * s * ||p_c - p*_c||^2]``, mean over the batch."""
        p = self.distribution(raw)
        grid = self.grid.to(p.dtype)
        x = self.encode(R_gt)
        terms = (p, self.target(x, grid), self.loss_resultant(p, x, grid), x)
        if self.channels == 1:  # directionnet_loss sums over a channel axis
            terms = tuple(t[:, None] for t in terms)
        return directionnet_loss(*terms, self.alpha, grid.shape[-1]).mean()

    def log_prob(self, raw: Tensor, R: Tensor) -> Tensor:
        """(B,) log density of R w.r.t. the normalised Haar measure (0 for a uniform prediction)."""
        return self.log_density(torch.log_softmax(raw, dim=-1), R)

    def uncertainty(self, raw: Tensor) -> Tensor:
        """(B,) spherical variance ``1 - |sum p x|`` (mean over the channels), in [0, 1]."""
        length = resultant_length(self.distribution(raw), self.grid)
        return 1 - (length if self.channels == 1 else length.mean(-1))


class _Regression:
    """The regression maths shared by attitude and translation heads (mixed into either)."""

    raw_shape: ClassVar[tuple[int, ...]] = ()

    def __init__(self, in_features: int, hidden: int = 1024) -> None:
        super().__init__(in_features)  # type: ignore[call-arg]  # the Head after this mixin
        self.net = mlp(in_features, hidden, math.prod(self.raw_shape))

    def encode(self, label: Tensor) -> Tensor:
        """Label -> its representation ``(B, *raw_shape)``, what the loss compares with."""
        raise NotImplementedError

    def to_label(self, x: Tensor) -> Tensor:
        """Normalised representation ``(B, *raw_shape)`` -> the label (rotation or metres)."""
        raise NotImplementedError

    def normalize(self, raw: Tensor) -> Tensor:
        """Raw outputs -> a valid representation (default: unconstrained, the identity)."""
        return raw

    def distance(self, x: Tensor, y: Tensor) -> Tensor:
        """(B,) squared Euclidean distance over the representation's axes."""
        return ((x - y) ** 2).sum(dim=tuple(range(1, x.dim())))

    def forward(self, features: Tensor) -> Tensor:
        """(B, F) -> (B, *raw_shape)."""
        return self.net(features).view(-1, *self.raw_shape)

    def decode(self, raw: Tensor) -> Tensor:
        return self.to_label(self.normalize(raw))

    def loss(self, raw: Tensor, label: Tensor) -> Tensor:
        """``distance(normalize(raw), encode(label))``, mean over the batch."""
        return self.distance(self.normalize(raw), self.encode(label)).mean()


class RegressionAttitudeHead(_Regression, AttitudeHead):
    """Base of the attitude regression heads: declare ``raw_shape``, ``encode(R)``,
    ``to_label(x) -> (B, 3, 3)`` and, if constrained, ``normalize``. Args: in_features; hidden
    (1024)."""


class RegressionTranslationHead(_Regression, TranslationHead):
    """Base of the translation regression heads. The representation defaults to the standardised
    translation ``(T - mean) / std`` (B, 3); ``to_label`` gives metres. Args: in_features; hidden
    (1024)."""

    raw_shape = (3,)

    def encode(self, label: Tensor) -> Tensor:
        return self.standardize(label)

    def to_label(self, x: Tensor) -> Tensor:
        return self.unstandardize(x)
