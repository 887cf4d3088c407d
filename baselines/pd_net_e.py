"""Pd-Net-E: a discrete von Mises distribution per Euler angle (3D-RCNN style, Table 1).

Label: ``(yaw, pitch, roll) = rotmat_to_euler(R_uav^sat)``; yaw and roll in (-pi, pi], pitch in
[-pi/2, pi/2]. For a nadir satellite camera the relative pitch is ~ +90 deg in level flight, i.e.
near gimbal lock, where yaw and roll are individually ill-defined: that is what the paper measures.

Grid: ``n_bins`` (128) equal bins per angle; yaw and roll bins cover (-pi, pi], pitch bins cover its
bounded range [-pi/2, pi/2].

Targets (soft, each summing to 1 over the bins):
  yaw, roll: ``softmax_b(kappa cos(c_b - angle))``, a von Mises discretised on the circle;
  pitch: the bounded range is mapped onto a circle by doubling, ``phi = 2 pitch``, and the target is
  ``softmax_b((kappa / 4) cos(2 c_b - 2 pitch))``, which has the same angular spread in pitch
  (~1/sqrt(kappa)) as the other two. (A von Mises truncated at +-90 deg would have a mean biased
  away from the bound, where the relative pitch of this dataset lives.) The doubled circle joins
  pitch +90 and -90 deg; both are gimbal lock, so the seam sits where the Euler split is degenerate
  anyway.

Prediction: logits ``(B, 3, n_bins)``, softmax per angle. Decoding: circular mean per angle
(``atan2(sum p sin c, sum p cos c)``; for pitch on the doubled circle, halved), then Eq. 1.

Loss, per angle, summed over the three and averaged over the batch:
``CE(p*, p) + direction_weight * (1 - cos(m, u*))``, where ``m = sum_b p_b (cos c_b, sin c_b)`` is
the expectation the decoder reads (Eq. 9 on the circle) and ``u*`` the label's unit vector on that
circle. The cross-entropy with a discrete von Mises target is 3D-RCNN's loss (the paper's citation);
the cosine term is Eq. 13, the direction term every other probabilistic head of the paper (all built
on DirectionNet) has. Why it is there: with cross-entropy alone (``direction_weight=0``), on the
quick profile (15 epochs, 2,400 pairs) the yaw distribution stayed near uniform (yaw CE 4.55 nats
against 4.85 for uniform; train yaw error 58 deg, test 88 deg) while pitch was learned; with the
Eq. 13 term the same run reached 14 deg train and 37 deg test yaw error. Like Eq. 13 elsewhere, the
cosine of a nearly uniform prediction has a gradient scaled by ``1 / |m|``, which is what gets the
yaw features started. ``direction_weight=0`` gives the literal 3D-RCNN loss.

Uncertainty: mean circular variance ``1 - |sum p e^{i c}|`` of the three angles (pitch on the
doubled circle), in [0, 1]. ``log_prob``: sum of the three log densities (1/rad) at the bins
containing the angles of R: a density w.r.t. d(yaw) d(pitch) d(roll), not w.r.t. the Haar measure.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from benchmark.geometry import euler_to_rotmat, rotmat_to_euler
from benchmark.models import AttitudeHead, register_head
from benchmark.models.heads import check_option
from benchmark.models.spherical import LatticeDecoder, cosine_loss


@register_head("pd_net_e")
class PdNetE(AttitudeHead):
    """Args: in_features; n_bins (128); kappa (10, > 0); hidden (160); direction_weight (1, >= 0),
    the weight of the Eq. 13 term (0: cross-entropy only, as 3D-RCNN)."""

    paper_name = "Pd-Net-E"
    is_probabilistic = True
    version = 2  # 2: the Eq. 13 direction term joined the cross-entropy

    def __init__(
        self,
        in_features: int,
        n_bins: int = 128,
        kappa: float = 10.0,
        hidden: int = 160,
        direction_weight: float = 1.0,
    ) -> None:
        super().__init__(in_features)
        self.kappa = check_option(kappa, "kappa", "pd_net_e")
        self.direction_weight = check_option(
            direction_weight, "direction_weight", "pd_net_e", inclusive=True
        )
        if not isinstance(n_bins, int) or n_bins < 4:
            raise ValueError(f"pd_net_e: n_bins must be an int >= 4, got {n_bins!r}")
        self.n_bins = n_bins
        # Bin centres on the circle each angle is treated on: yaw, 2 * pitch, roll, all (-pi, pi).
        centres = -math.pi + (torch.arange(n_bins, dtype=torch.float64) + 0.5) * (
            2 * math.pi / n_bins
        )
        self.register_buffer("centres", centres.float(), persistent=False)
        # Concentrations on those circles; pitch's doubled circle needs kappa / 4 for equal spread.
        self.register_buffer(
            "kappas", torch.tensor([self.kappa, self.kappa / 4, self.kappa]), persistent=False
        )
        # Multiplier from the circle angle back to the Euler angle.
        self.register_buffer("factors", torch.tensor([1.0, 0.5, 1.0]), persistent=False)
        self.decoder = LatticeDecoder(in_features, 3, n_bins, hidden)

    def forward(self, features: Tensor) -> Tensor:
        """(B, F) -> logits (B, 3, n_bins) for (yaw, pitch, roll)."""
        return self.decoder(features)

    def _circle_angles(self, R: Tensor) -> Tensor:
        yaw, pitch, roll = rotmat_to_euler(R)
        return torch.stack([yaw, 2 * pitch, roll], dim=-1)  # (B, 3) on the circles

    def distribution(self, raw: Tensor) -> Tensor:
        """(B, 3, n_bins) probabilities over the bins of yaw, pitch, roll."""
        return torch.softmax(raw, dim=-1)

    def target_distribution(self, R: Tensor) -> Tensor:
        return self._target(self._circle_angles(R))

    def _target(self, phi: Tensor) -> Tensor:
        """(B, 3) circle angles -> (B, 3, n_bins) discrete von Mises targets."""
        c, k = self.centres.to(phi.dtype), self.kappas.to(phi.dtype)
        return torch.softmax(k[:, None] * torch.cos(c - phi[..., None]), dim=-1)

    def _resultant(self, p: Tensor) -> tuple[Tensor, Tensor]:
        c = self.centres.to(p.dtype)
        return (p * torch.cos(c)).sum(-1), (p * torch.sin(c)).sum(-1)

    def decode_distribution(self, p: Tensor) -> Tensor:
        cos, sin = self._resultant(p)
        angles = torch.atan2(sin, cos) * self.factors.to(p.dtype)
        return euler_to_rotmat(*angles.unbind(-1))

    def decode(self, raw: Tensor) -> Tensor:
        return self.decode_distribution(self.distribution(raw))

    def loss(self, raw: Tensor, R_gt: Tensor) -> Tensor:
        phi = self._circle_angles(R_gt)  # (B, 3), shared by both terms
        target = self._target(phi)
        cross_entropy = -(target * torch.log_softmax(raw, dim=-1)).sum(dim=(-1, -2))  # (B,)
        if self.direction_weight == 0:
            return cross_entropy.mean()
        cos, sin = self._resultant(self.distribution(raw))  # (B, 3) each
        expectation = torch.stack([cos, sin], dim=-1)  # (B, 3, 2)
        label = torch.stack([torch.cos(phi), torch.sin(phi)], dim=-1)  # (B, 3, 2), unit
        direction = cosine_loss(expectation, label).sum(-1)  # (B,)
        return (cross_entropy + self.direction_weight * direction).mean()

    def log_prob(self, raw: Tensor, R: Tensor) -> Tensor:
        """(B,) log density w.r.t. d(yaw) d(pitch) d(roll) (1/rad^3) at R's bins."""
        phi = self._circle_angles(R)
        width = 2 * math.pi / self.n_bins
        index = ((phi + math.pi) / width).floor().long().clamp(0, self.n_bins - 1)
        log_p = torch.log_softmax(raw, dim=-1).gather(-1, index[..., None]).squeeze(-1)
        # Bin widths in the Euler angles: 2 pi / n for yaw and roll, pi / n for pitch.
        bin_widths = width * self.factors.to(log_p.dtype)
        return (log_p - torch.log(bin_widths)).sum(-1)

    def uncertainty(self, raw: Tensor) -> Tensor:
        """(B,) mean circular variance of the three angle distributions, in [0, 1]."""
        cos, sin = self._resultant(self.distribution(raw))
        return 1 - torch.sqrt(cos**2 + sin**2).mean(-1)
