"""Shared head bases: a head that derives from one of these declares its representation only.

Two families of heads share their maths (issue 13), and every grid-distribution head shares the
lattice setup (issue 22):

``GridDistribution`` (mixin, probabilistic). ``is_probabilistic``; ``distribution(raw)`` the
softmax of the logits over their last axis; ``decode(raw) = decode_distribution(distribution(raw))``
(the contract's identity, stated once). Pd-Net-E (bins of three angles) and IPDF (an implicit
function scored on a grid of rotations) use it as it is.

``LatticeDirections`` (mixin of ``GridDistribution``). The lattice options ``n_points`` (>=
``min_points``), ``kappa`` (> 0) and ``alpha`` (>= 0), checked under the head's registry name,
and the ``grid`` buffer (``lattice(n_points)``, not saved: rebuilt from ``n_points``), set up by
``init_lattice``; for one direction per sample on that grid: its target ``direction_target`` (the
discrete vMF, Eq. 10), loss ``direction_loss`` (Eq. 13 + alpha Eq. 14), decoding
``direction_mean`` (Eq. 9) and spread ``direction_spread`` (``1 - |sum p x|``). Pd-Net-Rv (the
rotation axis beside an angle branch) and Re-Net-T (the translation's direction beside a scale)
keep their own layers (one ``net``: state-dict keys ``net.*``, the layer sizes and the RNG draws
of version 2/3) and take the rest from here.

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
rotation: ``haar_log_density_s3``), so such a head declares ``lattice`` and ``encode`` only. A
subclass may override ``target(x, grid)`` (default the discrete vMF, Eq. 10), ``loss_resultant``
(the vector the Eq. 13 cosine compares with the label; default ``sum p x``),
``decode_distribution`` and ``uncertainty``.

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

from benchmark.geometry import (
    discrete_vmf,
    fibonacci_sphere,
    quat_to_rotmat,
    rotmat_to_quat,
    spherical_mean,
)
from benchmark.models.heads import (
    AttitudeHead,
    Raw,
    TranslationHead,
    check_lattice_options,
    mlp,
)
from benchmark.models.spherical import (
    LatticeDecoder,
    directionnet_loss,
    haar_log_density_s3,
    haar_log_density_s3_many,
    resultant_length,
    single_direction_loss,
)


class GridDistribution:
    """A head whose prediction is a softmax distribution on a grid (mixed in before the
    ``AttitudeHead`` / ``TranslationHead`` it completes). A head with dict raws overrides
    ``distribution``; every one defines ``decode_distribution``."""

    is_probabilistic: ClassVar[bool] = True

    def distribution(self, raw: Raw) -> Tensor:
        """Logits ``(..., n)`` -> probabilities shaped like them, each row summing to 1."""
        return torch.softmax(raw, dim=-1)

    def decode_distribution(self, dist: Raw) -> Tensor:
        raise NotImplementedError

    def decode(self, raw: Raw) -> Tensor:
        """``decode_distribution(distribution(raw))``: the contract's identity by construction."""
        return self.decode_distribution(self.distribution(raw))


class LatticeDirections(GridDistribution):
    """The lattice options and the ``grid`` buffer, and one direction per sample on that grid
    (module docstring). ``__init__`` of the head calls ``init_lattice`` after ``Head.__init__``."""

    min_points: ClassVar[int] = 4
    lattice = staticmethod(fibonacci_sphere)  # n -> (n, d) unit vectors, float32, equal cells
    grid: Tensor
    kappa: float
    alpha: float
    n_points: int

    def init_lattice(self, n_points: int, kappa: float, alpha: float) -> None:
        """Check ``n_points``, ``kappa``, ``alpha`` (errors name the head) and register ``grid``
        ``(n_points, d)`` as a buffer that is not saved."""
        owner = getattr(self, "name", "") or type(self).__name__
        self.kappa, self.alpha = check_lattice_options(
            owner, n_points, kappa, alpha, min_points=self.min_points
        )
        self.n_points = n_points
        grid = self.lattice(n_points)
        self.register_buffer("grid", grid, persistent=False)  # type: ignore[attr-defined]

    def direction_target(self, direction: Tensor) -> Tensor:
        """Unit ``(B, d)`` -> the discrete vMF ``(B, n)`` around it (Eq. 10)."""
        return discrete_vmf(direction, self.kappa, self.grid.to(direction.dtype))

    def direction_loss(self, p: Tensor, direction: Tensor) -> Tensor:
        """``(B, n)`` probabilities, unit label ``(B, d)`` -> ``(B,)`` Eq. 13 + alpha Eq. 14."""
        return single_direction_loss(p, direction, self.grid, self.kappa, self.alpha)

    def direction_mean(self, p: Tensor) -> Tensor:
        """``(..., n)`` -> the normalised expectation ``(..., d)`` (Eq. 9)."""
        return spherical_mean(p, self.grid)

    def direction_spread(self, p: Tensor) -> Tensor:
        """``(..., n)`` -> spherical variance ``1 - |sum p x|`` ``(...)``, in [0, 1]."""
        return 1 - resultant_length(p, self.grid)


class LatticeHead(LatticeDirections, AttitudeHead):
    """Base of the lattice-distribution attitude heads (see the module docstring for the hooks).

    Args: in_features; n_points (4096, >= ``min_points``); kappa (10, > 0); alpha (8e7, >= 0,
    DirectionNet's units, see ``distribution_loss_scale``); hidden (160, decoder bottleneck).
    """

    channels: ClassVar[int] = 1

    def __init__(
        self,
        in_features: int,
        n_points: int = 4096,
        kappa: float = 10.0,
        alpha: float = 8e7,
        hidden: int = 160,
    ) -> None:
        super().__init__(in_features)
        self.init_lattice(n_points, kappa, alpha)
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

    def target_distribution(self, R: Tensor) -> Tensor:
        """(B, 3, 3) -> the training target, shaped like ``distribution(raw)``."""
        return self.target(self.encode(R), self.grid.to(R.dtype))

    def decode_distribution(self, p: Tensor) -> Tensor:
        """Probabilities -> (B, 3, 3): the normalised expectation of each channel (Eq. 9)."""
        return self.to_label(self.direction_mean(p))

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

    def log_prob_many(self, raw: Tensor, R: Tensor) -> Tensor:
        """``log_prob`` of ``R (B, K, 3, 3)``, K rotations per sample -> ``(B, K)``: the softmax
        once per sample; the default S^3 density looks its K rotations up together in the
        lattice's k-d tree. A subclass with its own ``log_density`` gets it row by row."""
        log_p = torch.log_softmax(raw, dim=-1)
        B, K = R.shape[:2]
        if type(self).log_density is LatticeHead.log_density:
            self._require_quaternions("log_density")
            q = rotmat_to_quat(R).to(log_p.dtype)
            return haar_log_density_s3_many(log_p, q, self.grid, tree=True)
        rows = log_p[:, None].expand(B, K, *log_p.shape[1:]).reshape(B * K, *log_p.shape[1:])
        return self.log_density(rows, R.reshape(B * K, 3, 3)).reshape(B, K)

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
