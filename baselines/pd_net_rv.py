"""Pd-Net-Rv: a vMF lattice distribution over the rotation axis plus a distribution over the
rotation angle (Table 1).

The paper builds it "on the basis of DirectionNet-R by adding a parallel branch to estimate the
two-norm of the equivalent rotation vector" (Sec. 3.3.1). The branch here predicts a distribution
over the angle (version 1 predicted a point), so the head has a density on SO(3) and its
log-likelihood is comparable with the other heads'.

Label: ``v = rotmat_to_rotvec(R_uav^sat)`` (angle in [0, pi]); axis ``v / |v|`` (``e_z`` when the
angle is below 1e-6, where the axis is undefined) and angle ``|v|``.

Axis: grid the 4096-point Fibonacci lattice; target ``discrete_vmf(axis, kappa)`` (sum 1);
prediction softmax over the lattice; decoded by the Eq. 9 expectation; loss ``L_dir + alpha * s *
L_dis`` (as in ``pd_re_net``, alpha in DirectionNet's units).

Angle: ``n_angle_bins`` (128) equal bins on the interval [0, pi] (width 1.4 deg); target the von
Mises ``softmax_b(kappa cos(c_b - angle))`` restricted to the interval; prediction a softmax. As
for Pd-Net-E's pitch, the mean of a truncated target is biased near the ends, so the angle is
decoded as the centre whose target is closest to the prediction in cross-entropy,
``argmin_mu -kappa m.(cos mu, sin mu) + log Z(mu)`` with ``m = sum_b p_b (cos c_b, sin c_b)``
(``8 n + 1`` candidates on [0, pi], a parabola through the minimum, clipped to [0, pi]); the target
decodes to its angle within 1e-3 deg, also at 0 and pi. Loss ``angle_weight * [CE(p*, p) + 1 -
cos(m, m*)]`` (cross-entropy plus the Eq. 13 term on the half circle ``e(c) = (cos c, sin c)``,
``m*`` the target's mean, so the target minimises both). Version 1's ``(angle - angle*)^2`` on a
point estimate is gone.

Decoding: ``rotvec_to_rotmat(axis * angle)``. Loss: axis loss + angle loss, mean over the batch.

Uncertainty: the mean of the axis' spherical variance ``1 - |sum p x|`` and the angle's
``1 - |m|``, in [0, 1].

``log_prob``: log density of R w.r.t. the normalised Haar measure on SO(3). In axis-angle
coordinates (axis on S^2, angle in [0, pi]) the Haar measure is ``(1 - cos t) dt dOmega / (4 pi^2)``
(``int_0^pi (1 - cos t) dt = pi``, times ``4 pi`` sr, over ``4 pi^2``: 1). The prediction is read as
a histogram whose mass ``P_axis(k) P_angle(j)`` is spread Haar-uniformly over its cell (lattice
cell k, area ``4 pi / n``, times angle bin j = [l, u]), of Haar measure
``(1 / n) ((u - sin u) - (l - sin l)) / pi``: ``log_prob = log P_axis + log P_angle - log(cell)``.
The Haar-uniform prediction (uniform axis, angle masses ``Delta(t - sin t) / pi``) scores 0; over
Haar-uniform R the exponential has expectation 1 (up to the lattice cells' unequal areas).

Discontinuities (inherent to the rotation vector, they stay): at angle pi the axis flips to its
antipode (``v`` and ``-v`` are the same rotation; Eq. 7's discontinuity), so the axis target jumps
there; at angle 0 the axis is undefined (label ``e_z``) and the axis distribution carries no
information. Introduced: none.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from benchmark.geometry import rotmat_to_rotvec, rotvec_to_rotmat
from benchmark.models import AttitudeHead, LatticeDirections, register_head
from benchmark.models.heads import check_option, mlp
from benchmark.models.spherical import (
    angle_bins_loss,
    circle_resultant,
    interval_decoding_grid,
    interval_mle,
    nearest_lattice_points,
    unit_direction,
    von_mises_bins,
)

_MIN_ANGLE = 1e-6


def rotmat_to_axis_angle(R: Tensor) -> tuple[Tensor, Tensor]:
    """(B, 3, 3) -> unit axis (B, 3) and angle (B,) in [0, pi]; axis e_z for (near) identity."""
    return unit_direction(rotmat_to_rotvec(R), _MIN_ANGLE)


@register_head("pd_net_rv")
class PdNetRv(LatticeDirections, AttitudeHead):
    """Options: n_points (4096), kappa (10), alpha (8e7), hidden (160), angle_weight (1, >= 0),
    n_angle_bins (128). The axis lattice (options, grid, target, loss, expectation, spread) and
    ``decode`` come from ``LatticeDirections``; one ``net`` gives both branches' logits."""

    paper_name = "Pd-Net-Rv"
    # 2: the angle branch predicts a distribution on [0, pi] (was a point estimate); log_prob
    # w.r.t. the normalised Haar measure (was the axis alone, per steradian).
    version = 2

    def __init__(
        self,
        in_features: int,
        n_points: int = 4096,
        kappa: float = 10.0,
        alpha: float = 8e7,
        hidden: int = 160,
        angle_weight: float = 1.0,
        n_angle_bins: int = 128,
    ) -> None:
        super().__init__(in_features)
        self.init_lattice(n_points, kappa, alpha)
        self.angle_weight = check_option(angle_weight, "angle_weight", "pd_net_rv", inclusive=True)
        if not isinstance(n_angle_bins, int) or isinstance(n_angle_bins, bool) or n_angle_bins < 4:
            raise ValueError(f"pd_net_rv: n_angle_bins must be an int >= 4, got {n_angle_bins!r}")
        self.n_angle_bins = n_angle_bins
        edges = math.pi * torch.arange(n_angle_bins + 1, dtype=torch.float64) / n_angle_bins
        centres = (edges[1:] + edges[:-1]) / 2
        self.register_buffer("centres", centres, persistent=False)
        # log Haar measure of (one lattice cell) x (angle bin): (1/n) Delta(t - sin t) / pi.
        cells = torch.diff(edges - torch.sin(edges)) / (math.pi * n_points)
        self.register_buffer("log_cells", torch.log(cells), persistent=False)
        candidates, log_norm = interval_decoding_grid(centres, 0.0, self.kappa)
        self.register_buffer("candidates", candidates, persistent=False)
        self.register_buffer("log_norm", log_norm, persistent=False)
        self.net = mlp(in_features, hidden, n_points + n_angle_bins)

    def forward(self, features: Tensor) -> dict[str, Tensor]:
        """(B, F) -> {"logits": (B, n) axis logits, "angle_logits": (B, n_angle_bins)}."""
        out = self.net(features)
        return {"logits": out[:, : self.n_points], "angle_logits": out[:, self.n_points :]}

    def distribution(self, raw: dict[str, Tensor]) -> dict[str, Tensor]:
        """{"axis": (B, n), "angle": (B, n_angle_bins)} probabilities."""
        return {
            "axis": torch.softmax(raw["logits"], dim=-1),
            "angle": torch.softmax(raw["angle_logits"], dim=-1),
        }

    def _angle_target(self, angle: Tensor) -> Tensor:
        """(B,) rad in [0, pi] -> (B, n_angle_bins) truncated discrete von Mises."""
        return von_mises_bins(angle, self.centres, self.kappa)

    def target_distribution(self, R: Tensor) -> dict[str, Tensor]:
        axis, angle = rotmat_to_axis_angle(R)
        return {
            "axis": self.direction_target(axis),
            "angle": self._angle_target(angle),
        }

    def decode_distribution(self, dist: dict[str, Tensor]) -> Tensor:
        axis = self.direction_mean(dist["axis"])
        m = circle_resultant(dist["angle"], self.centres)
        angle = interval_mle(m, self.kappa, 0.0, self.candidates, self.log_norm)
        return rotvec_to_rotmat(axis * angle[..., None])

    def loss(self, raw: dict[str, Tensor], R_gt: Tensor) -> Tensor:
        axis, angle = rotmat_to_axis_angle(R_gt)
        p = torch.softmax(raw["logits"], dim=-1)
        l_axis = self.direction_loss(p, axis)
        if self.angle_weight == 0:
            return l_axis.mean()
        t_angle = self._angle_target(angle)
        cross_entropy, direction = angle_bins_loss(raw["angle_logits"], t_angle, self.centres)
        return (l_axis + self.angle_weight * (cross_entropy + direction)).mean()

    def log_prob(self, raw: dict[str, Tensor], R: Tensor) -> Tensor:
        """(B,) log density of R w.r.t. the normalised Haar measure on SO(3) (module docstring):
        ``log P_axis + log P_angle - log((1/n) Delta(t - sin t) / pi)``."""
        return self._log_prob(raw, R[:, None], tree=None)[:, 0]

    def log_prob_many(self, raw: dict[str, Tensor], R: Tensor) -> Tensor:
        """``log_prob`` of ``R (B, K, 3, 3)``, K rotations per sample -> ``(B, K)``: the two
        softmaxes once per sample, the K axes' nearest lattice points from the lattice's k-d
        tree (``nearest_lattice_points``)."""
        return self._log_prob(raw, R, tree=True)

    def _log_prob(self, raw: dict[str, Tensor], R: Tensor, tree: bool | None) -> Tensor:
        axis, angle = rotmat_to_axis_angle(R)
        log_axis = torch.log_softmax(raw["logits"], dim=-1)
        k = nearest_lattice_points(axis.to(log_axis.dtype), self.grid, tree)  # (B, K)
        j = (angle / (math.pi / self.n_angle_bins)).floor().long().clamp(0, self.n_angle_bins - 1)
        log_angle = torch.log_softmax(raw["angle_logits"], dim=-1)
        log_mass = log_axis.gather(-1, k) + log_angle.gather(-1, j)
        return log_mass - self.log_cells.to(log_mass.dtype)[j]

    def uncertainty(self, raw: dict[str, Tensor]) -> Tensor:
        """(B,) mean of the axis' ``1 - |sum p x|`` and the angle's ``1 - |m|``, in [0, 1]."""
        dist = self.distribution(raw)
        axis_var = self.direction_spread(dist["axis"])
        angle_var = 1 - torch.linalg.vector_norm(
            circle_resultant(dist["angle"], self.centres), dim=-1
        )
        return (axis_var + angle_var) / 2
