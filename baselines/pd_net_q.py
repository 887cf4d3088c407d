"""Pd-Net-Q: a lattice distribution over unit quaternions on S^3 (paper Sec. 3.3.1, "16^3").

This is the paper's Pd-Net-Q (the Table 1 row), with the paper's label, which is *not* antipodally
symmetric; the q / -q symmetric variant is the separately named head ``pd_net_q_sym``.

Label (paper Eq. 3-5), quaternions ``(w, x, y, z)``, w first::

    Q_uav^n   = Eq. 3 (R_uav^n),  R_uav^n = R_uav^sat R_sat^n   (the head's label is R_uav^sat)
    Q_uav^sat = Q_uav^n (x) conj(Q_sat^n),  Q_sat^n = [-0.7071, 0.7071, 0, 0]   (Eq. 4, Eq. 5)

Eq. 3 (``rotmat_to_quat_paper``) takes the first of its four cases that holds and makes that
case's pivot component positive; Eq. 5 is used with the sign the paper prints. Hemisphere
convention: there is no fixed hemisphere (not ``w >= 0``); the sign is "pivot of Eq. 3 on the UAV
attitude is positive", carried through Eq. 4. When the case changes, the label jumps to (nearly)
its antipode: for UAV pitch -20 deg and roll -10 deg at heading ~ -63.03 deg (Eq. 6, Fig. 2). In
this dataset (UAV pitch in [-50, 0] deg, small roll) the cases are w (|heading| below ~60 deg) and
z (above), so the jump is crossed by a fraction of the training labels. That discontinuity is the
one the paper blames on quaternions; it is inherent to this target and stays.

Grid: ``super_fibonacci(4096)``, nearly uniform on all of S^3, so every rotation appears twice
(``q`` and ``-q``). Target: ``p*_k = softmax_k(kappa q*.x_k)`` (a vMF on S^3 around the label).
Prediction: softmax over the lattice (sum 1). Decoding: the normalised expectation (Eq. 9),
``sum p x / |sum p x|``, as a quaternion; a prediction that spreads its mass over both ``q`` and
``-q`` (what a network does near the jump) has a short, unreliable mean: that is the cost of the
discontinuity. Loss: ``1 - cos(sum p x, q*) + alpha * s * sum (p - p*)^2`` (Eq. 13 + Eq. 14,
``s = distribution_loss_scale(n, dim=4)``, alpha in DirectionNet's units), mean over the batch.

Uncertainty: ``1 - |sum p x|`` in [0, 1].

``log_prob``: log density of the rotation R w.r.t. the normalised Haar measure on SO(3). A density
``g`` on S^3 w.r.t. surface measure (total ``2 pi^2``) gives the rotation density
``pi^2 (g(q) + g(-q))`` w.r.t. the normalised Haar measure (S^3 covers SO(3) twice; the Haar measure
of SO(3) is the surface measure of S^3 / 2, normalised by ``pi^2``). With each lattice point's
probability spread over its cell (``2 pi^2 / n``): ``log(p(q) + p(-q)) + log(n / 2)``, each
probability read at the nearest lattice point. A uniform prediction scores 0.

Discontinuities: the case switch of Eq. 3 (inherent to the paper's target, above); none added.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from benchmark.geometry import (
    SAT_R_N,
    quat_conjugate,
    quat_multiply,
    rotmat_to_quat_paper,
    super_fibonacci,
)
from benchmark.models import LatticeHead, register_head

# Eq. 5 as printed: the satellite camera (pitch -90 deg, heading 0), w first.
PAPER_SAT_Q_N = (-math.sqrt(0.5), math.sqrt(0.5), 0.0, 0.0)


def paper_relative_quat(R: Tensor) -> Tensor:
    """The paper's label quaternion of ``R = R_uav^sat (..., 3, 3)``: Eq. 3 on ``R_uav^n``, then
    Eq. 4 with Eq. 5 as printed. ``(..., 4)`` ``(w, x, y, z)``, unit, sign as the paper's."""
    R_uav_n = R @ SAT_R_N.to(R.dtype)
    q_sat = torch.tensor(PAPER_SAT_Q_N, dtype=R.dtype, device=R.device)
    return quat_multiply(rotmat_to_quat_paper(R_uav_n), quat_conjugate(q_sat))


@register_head("pd_net_q")
class PdNetQ(LatticeHead):
    """Options: n_points (4096), kappa (10), alpha (8e7), hidden (160). Raw: logits (B, n).

    ``LatticeHead`` on S^3: decoding by ``quat_to_rotmat`` of the normalised expectation and
    ``log_prob`` by ``haar_log_density_s3`` come with the base; this head is its label.
    """

    paper_name = "Pd-Net-Q"
    # 2: the paper's label (Eq. 3 on R_uav^n, Eq. 4-5) only; the symmetric variant moved to
    # pd_net_q_sym; log_prob w.r.t. the normalised Haar measure.
    version = 2
    min_points = 8
    lattice = staticmethod(super_fibonacci)

    def encode(self, R: Tensor) -> Tensor:
        """(B, 3, 3) -> (B, 4) the paper's label quaternion (``paper_relative_quat``)."""
        return paper_relative_quat(R)
