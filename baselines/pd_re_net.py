"""Pd/Re-Net attitude head: a vMF lattice distribution per column of R (paper Sec. 2.2.2).

Grid: the 4096-point equal-area spherical Fibonacci lattice (the paper's "64 x 64 points").

Target (Eq. 10): for each column ``r*_j`` of ``R_uav^sat``, ``discrete_vmf(r*_j, kappa=10, grid)``,
the vMF density at the lattice points normalised to sum 1.

Prediction: logits ``(B, 3, n)`` from a dense decoder with a 160-wide bottleneck (the paper does
not give its decoder; 160 puts the AGTFM model within 1 % of Table 6's 95.6 MB); the predicted
distribution is their softmax over the lattice, i.e. probabilities summing to 1 per column, exactly
like the target. (DirectionNet uses softplus and an area-weighted sum instead; either way Eq. 14
compares probability vectors, so alpha's meaning below is unaffected.)

Decoding (DirectionNet, Chen et al. CVPR 2021): the expectation of each column distribution
(Eq. 9, ``sum_k p_k x_k``) is normalised to the unit sphere, the three unit vectors are stacked as
columns and projected to SO(3) by SVD (special orthogonal Procrustes with the determinant fix,
``special_orthogonalize``). Normalising first weighs the three columns alike; without it a broad
column (short resultant) would count less in the projection than a sharp one. A column whose
resultant vanishes (e.g. mass split between antipodes) contributes a zero column (its norm is
clamped at 1e-12); the projection is then decided by the other two columns.

Discontinuities: none inherent in the representation (three directions on S^2 and the SVD are
continuous on SO(3)); the decoding is undefined only for degenerate distributions whose normalised
expectations span less than a plane (two vanishing resultants).

Loss (Eq. 15): ``L_dir (Eq. 13) + alpha * s * L_dis (Eq. 14)`` with alpha = 8e7, averaged over the
batch. L_dir uses the Eq. 9 expectations before orthogonalisation (Algorithm 1, steps 3-4).

Why alpha = 8e7 keeps DirectionNet's meaning: DirectionNet's maps live on a 64 x 64 equirectangular
grid, normalised so that ``sum_ij q_ij sin(theta_i) = 1`` (``q = density * dtheta dphi``), and its
distribution loss is the sin-weighted *mean* over the 4096 pixels, ``mean sin(theta) (q - q*)^2``,
which equals ``(dOmega0 / 4096) * integral (f - f*)^2 dA`` for densities f (1/sr) and
``dOmega0 = 2 pi^2 / 4096``. Our probabilities on an equal-area lattice are ``p = f * 4 pi / n``,
so the plain Eq. 14 sum would be ``(4 pi / n) * integral (f - f*)^2 dA``. Multiplying it by
``s = dOmega0 n / (4096 * 4 pi)`` (``pi / 8192 = 3.8e-4`` for n = 4096; ``distribution_loss_scale``)
makes ``alpha * s * L_dis`` the same multiple of the same L2 distance between densities as in
DirectionNet, so alpha = 8e7 weighs the dense supervision against the cosine term exactly as it
does there. Equivalently: DirectionNet's grid with every sin weight replaced by its average 2/pi.
(Per column, the plain sum with alpha = 8e7 would be ~2600x too strong.) DirectionNet's extra
spread loss (beta = 0.1) is not part of the paper's Eq. 15 and is left out.

Uncertainty: the spherical variance ``1 - |sum_k p_k x_k|`` averaged over the three columns, in
[0, 1] (0 = point masses). ``log_prob``: log density w.r.t. the normalised Haar measure on SO(3)
(a uniform prediction scores 0) of ``p(R) ~ prod_j p_j(R e_j)``, the product of the three column
distributions normalised over SO(3) by quadrature on a Haar-uniform grid
(``column_product_log_density``; the product alone is not a density on SO(3)).

Version 2: decoding normalises the column expectations before the SVD; ``log_prob`` is on the
Haar measure.
"""

from __future__ import annotations

import torch
from torch import Tensor

from benchmark.geometry import fibonacci_sphere, special_orthogonalize
from benchmark.models import LatticeHead, register_head
from benchmark.models.spherical import (
    column_product_log_density,
    column_product_log_density_many,
)


@register_head("pd_re_net")
class PdReNet(LatticeHead):
    """Args: in_features; n_points (4096); kappa (10, > 0); alpha (8e7); hidden (160).

    Raw: logits (B, 3, n), one row per column of R; the rest is ``LatticeHead``'s.
    """

    paper_name = "Pd/Re-Net"
    version = 2
    channels = 3
    lattice = staticmethod(fibonacci_sphere)

    def encode(self, R: Tensor) -> Tensor:
        """(B, 3, 3) -> (B, 3, 3): row j is column j of R."""
        return R.transpose(-1, -2)

    def to_label(self, columns: Tensor) -> Tensor:
        """(B, 3, 3) normalised column expectations (rows) -> SVD projection onto SO(3)."""
        return special_orthogonalize(columns.transpose(-1, -2))

    def log_density(self, log_p: Tensor, R: Tensor) -> Tensor:
        """Product of the column densities normalised over SO(3) by Haar quadrature."""
        return column_product_log_density(log_p, R, self.grid)

    def log_prob_many(self, raw: Tensor, R: Tensor) -> Tensor:
        """``log_prob`` of ``R (B, K, 3, 3)``, K rotations per sample -> ``(B, K)``: the Haar
        quadrature of the normaliser (2^15 rotations) once per sample, not once per rotation."""
        log_p = torch.log_softmax(raw, dim=-1)
        return column_product_log_density_many(log_p, R, self.grid, tree=True)
