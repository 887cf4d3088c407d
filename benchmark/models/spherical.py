"""Building blocks of the lattice-distribution heads (DirectionNet's spherical decoder, Eq. 9-15).

A lattice head predicts logits over ``n`` equal-area lattice points per direction; the predicted
distribution is their softmax (probabilities summing to 1, the same normalisation as the target
``discrete_vmf``). DirectionNet maps its outputs through softplus and divides by the area-weighted
sum instead; both give a probability vector, and Eq. 14 compares probabilities, so the choice of the
positive map does not change what alpha means (that is fixed by ``distribution_loss_scale``). The
softmax makes the vMF target exactly representable (its log is linear in the lattice coordinates)
and gives ``log_prob`` without a division.

Also here, once for every head that needs them: the single-direction loss and the fallback for an
undefined direction (``single_direction_loss``, ``unit_direction``: Pd-Net-Rv's axis, Re-Net-T's
direction), the S^3 Haar log density (``haar_log_density_s3``), and the binned angles of Pd-Net-E
and Pd-Net-Rv (``von_mises_bins``, ``circle_resultant``, ``angle_bins_loss``,
``interval_decoding_grid``, ``interval_mle``). The shared head classes are in ``head_bases.py``.
"""

from __future__ import annotations

import math
from functools import lru_cache

import torch
from torch import Tensor, nn

from benchmark.geometry import discrete_vmf, fibonacci_sphere, quat_to_rotmat, super_fibonacci
from benchmark.models.heads import distribution_loss_scale, mlp, sphere_volume

# Haar quadrature of the column-product density on SO(3) (``column_product_log_density``): a
# super-Fibonacci grid of this many unit quaternions, i.e. rotations (each rotation once: the
# spiral covers S^3, and q, -q are the same rotation, so the grid is uniform on SO(3) as it is).
HAAR_GRID_SIZE = 2**15


class LatticeDecoder(nn.Module):
    """``features (B, F) -> logits (B, channels, n)`` through a ``hidden``-wide bottleneck.

    A dense 2-layer map, not DirectionNet's upsampling conv decoder: the Fibonacci lattice has no
    image structure. The bottleneck keeps the parameter count near the paper's (Table 6).
    """

    def __init__(self, in_features: int, channels: int, n_points: int, hidden: int) -> None:
        super().__init__()
        self.channels, self.n_points = channels, n_points
        self.net = mlp(in_features, hidden, channels * n_points)

    def forward(self, features: Tensor) -> Tensor:
        return self.net(features).view(-1, self.channels, self.n_points)


def cosine_loss(v: Tensor, target: Tensor) -> Tensor:
    """Eq. 13 for one direction: ``1 - v.t / (|v| |t|)``. v, target: ``(..., d)`` -> ``(...)``.

    ``v`` is the unnormalised expectation ``sum_k p_k x_k``; its norm is clamped at 1e-12, so a
    uniform prediction (resultant ~ 0) gives a finite loss and gradient.
    """
    cos = (v * target).sum(-1) / (
        torch.linalg.vector_norm(v, dim=-1).clamp_min(1e-12)
        * torch.linalg.vector_norm(target, dim=-1).clamp_min(1e-12)
    )
    return 1 - cos


def directionnet_loss(
    p: Tensor, p_target: Tensor, resultant: Tensor, direction: Tensor, alpha: float, dim: int
) -> Tensor:
    """Per-sample ``sum_c [L_dir_c + alpha * s * ||p_c - p*_c||^2]`` (Eq. 13 + alpha Eq. 14).

    Args:
        p, p_target: ``(B, C, n)`` predicted / target probabilities.
        resultant: ``(B, C, d)`` predicted ``sum_k p_k x_k`` (Eq. 9 before normalisation).
        direction: ``(B, C, d)`` label unit vectors.
        alpha: distribution weight in DirectionNet's units (8e7 in the paper).
        dim: ambient dimension d (3 for S^2, 4 for S^3), for ``distribution_loss_scale``.
    Returns:
        ``(B,)``.
    """
    scale = distribution_loss_scale(p.shape[-1], dim)
    l_dir = cosine_loss(resultant, direction).sum(-1)
    l_dis = ((p - p_target) ** 2).sum(dim=(-1, -2))
    return l_dir + alpha * scale * l_dis


def single_direction_loss(
    p: Tensor, direction: Tensor, grid: Tensor, kappa: float, alpha: float
) -> Tensor:
    """``directionnet_loss`` of one direction per sample with the discrete vMF target (Eq. 10).

    p: ``(B, n)`` predicted probabilities; direction: ``(B, d)`` unit label; grid: ``(n, d)``;
    kappa: the target's concentration; alpha: as in ``directionnet_loss``. Returns ``(B,)``.
    """
    grid = grid.to(p.dtype)
    target = discrete_vmf(direction, kappa, grid)
    terms = (p, target, p @ grid, direction)
    return directionnet_loss(*(t[:, None] for t in terms), alpha, grid.shape[-1])


def unit_direction(v: Tensor, min_length: float) -> tuple[Tensor, Tensor]:
    """``v (..., 3)`` -> ``(v / |v|, |v|)``; where ``|v| < min_length`` the direction is undefined
    and ``e_z`` is used (any fixed unit vector would do: the lattices have no boundary)."""
    length = torch.linalg.vector_norm(v, dim=-1)
    e_z = torch.zeros_like(v)
    e_z[..., 2] = 1
    unit = v / length.clamp_min(min_length)[..., None]
    return torch.where((length < min_length)[..., None], e_z, unit), length


def von_mises_bins(angle: Tensor, centres: Tensor, kappa: float) -> Tensor:
    """Discrete von Mises target ``softmax_b(kappa cos(c_b - angle))`` over angle bins (3D-RCNN;
    restricted to the bins, so truncated when they cover an interval).

    angle: ``(...)`` rad; centres: ``(..., n)`` bin centres (rad, broadcast against ``angle``)
    -> ``(..., n)`` probabilities.
    """
    c = centres.to(angle.dtype)
    return torch.softmax(kappa * torch.cos(c - angle[..., None]), dim=-1)


def circle_resultant(p: Tensor, centres: Tensor) -> Tensor:
    """``sum_b p_b (cos c_b, sin c_b)``: ``p (..., n)``, centres ``(..., n)`` -> ``(..., 2)``."""
    c = centres.to(p.dtype)
    return torch.stack([(p * torch.cos(c)).sum(-1), (p * torch.sin(c)).sum(-1)], dim=-1)


def angle_bins_loss(logits: Tensor, target: Tensor, centres: Tensor) -> tuple[Tensor, Tensor]:
    """The two loss terms of a binned angle: cross-entropy ``-sum_b p*_b log p_b`` (3D-RCNN) and
    the Eq. 13 term ``1 - cos(m, m*)`` of the resultants ``m = circle_resultant(p)``, ``m*`` of the
    target. logits, target: ``(..., n)``; centres ``(..., n)`` -> two ``(...)`` tensors.
    """
    cross_entropy = -(target * torch.log_softmax(logits, dim=-1)).sum(-1)
    m = circle_resultant(torch.softmax(logits, dim=-1), centres)
    return cross_entropy, cosine_loss(m, circle_resultant(target, centres))


def interval_decoding_grid(
    centres: Tensor, lower: float, kappa: float, per_bin: int = 8
) -> tuple[Tensor, Tensor]:
    """Candidates and ``log Z`` for ``interval_mle`` on the interval ``[lower, lower + pi]``.

    centres: ``(n,)`` float64 bin centres of the interval. Returns ``candidates (per_bin n + 1,)``
    equally spaced from ``lower`` to ``lower + pi`` and ``log_norm`` of the same shape,
    ``log Z(mu) = logsumexp_b kappa cos(c_b - mu)`` of the truncated target, both float64.
    """
    n = centres.shape[-1]
    candidates = torch.linspace(lower, lower + math.pi, per_bin * n + 1, dtype=torch.float64)
    log_norm = torch.logsumexp(kappa * torch.cos(centres[None] - candidates[:, None]), -1)
    return candidates, log_norm


def lattice_log_density(log_p: Tensor, x: Tensor, grid: Tensor) -> Tensor:
    """Log density (w.r.t. the sphere's surface measure) of the lattice distribution at ``x``.

    The probability of the lattice point nearest ``x`` spread evenly over its cell (measure
    ``V / n``). log_p: ``(..., n)``; x: ``(..., d)`` unit; grid: ``(n, d)`` -> ``(...)``.
    """
    n, d = grid.shape
    index = (x @ grid.to(x.dtype).T).argmax(-1, keepdim=True)
    return log_p.gather(-1, index).squeeze(-1) - math.log(sphere_volume(d) / n)


def resultant_length(p: Tensor, grid: Tensor) -> Tensor:
    """``|sum_k p_k x_k|`` in [0, 1]: 1 for a point mass, ~0 for a uniform distribution.

    p: ``(..., n)``; grid: ``(n, d)`` -> ``(...)``. ``1 - resultant_length`` is the spherical
    variance used as the uncertainty of the direction heads.
    """
    return torch.linalg.vector_norm(p @ grid.to(p.dtype), dim=-1)


def haar_log_density_s3(log_p: Tensor, q: Tensor, grid: Tensor) -> Tensor:
    """Log density, w.r.t. the normalised Haar measure on SO(3), of the rotation ``q`` under a
    lattice distribution on S^3: ``log(p(q) + p(-q)) + log(n / 2)``.

    A density ``g`` on S^3 w.r.t. surface measure (total ``2 pi^2``) gives the rotation density
    ``pi^2 (g(q) + g(-q))`` w.r.t. the normalised Haar measure (S^3 covers SO(3) twice). With each
    lattice point's probability spread over its cell (``2 pi^2 / n``) and read at the nearest
    lattice point, that is the formula above; a uniform prediction scores 0.

    log_p: ``(B, n)``; q: ``(B, 4)`` unit; grid: ``(n, 4)`` -> ``(B,)``.
    """
    return haar_log_density_s3_many(log_p, q[:, None], grid)[:, 0]


def haar_log_density_s3_many(
    log_p: Tensor, q: Tensor, grid: Tensor, tree: bool | None = None
) -> Tensor:
    """:func:`haar_log_density_s3` of ``K`` rotations per sample: ``log_p (B, n)``, ``q (B, K,
    4)`` -> ``(B, K)``. The nearest lattice points of ``q`` and ``-q`` by
    :func:`nearest_lattice_points` (``tree`` passed on); the point nearest ``-q`` is the one
    with the smallest dot product with ``q``."""
    near_pos = log_p.gather(-1, nearest_lattice_points(q, grid, tree))
    near_neg = log_p.gather(-1, nearest_lattice_points(-q, grid, tree))
    return torch.logaddexp(near_pos, near_neg) + math.log(grid.shape[0] / 2)


@lru_cache(maxsize=4)
def _haar_grid_column_indices(n_points: int, n_rotations: int) -> Tensor:
    """``(n_rotations, 3)`` int64: for each rotation of the super-Fibonacci Haar grid, the index of
    the Fibonacci lattice point (of ``n_points``) nearest to each of its three columns.

    Computed once per process in float64 (in chunks, ~1 s for 2^15 x 4096) and cached.
    """
    grid = fibonacci_sphere(n_points, dtype=torch.float64)
    R = quat_to_rotmat(super_fibonacci(n_rotations, dtype=torch.float64))
    columns = R.transpose(-1, -2).reshape(-1, 3)  # (M * 3, 3): rows are the columns of R
    index = torch.cat([(chunk @ grid.T).argmax(-1) for chunk in columns.split(8192)])
    return index.view(n_rotations, 3)


def column_product_log_density(
    log_p: Tensor, R: Tensor, grid: Tensor, n_rotations: int = HAAR_GRID_SIZE
) -> Tensor:
    """Log density on SO(3), w.r.t. the normalised Haar measure, of ``p(R) ~ prod_j f_j(R e_j)``.

    ``f_j`` is the lattice distribution of column j (probability of the nearest lattice point,
    spread over its cell, as in ``lattice_log_density``). The product of three sphere densities is
    not a density on SO(3) (the columns of a rotation are not independent), so it is normalised
    over SO(3): ``log p(R) = s(R) - log mean_m exp(s(R_m))`` with ``s(R) = sum_j log p_j[nearest
    lattice point to R e_j]`` and ``R_m`` the ``n_rotations``-point super-Fibonacci grid, uniform
    for the Haar measure (quasi-Monte Carlo quadrature of the normaliser). A uniform prediction
    scores exactly 0. When every column is a vMF of concentration kappa the result is the matrix
    Fisher density with ``F = kappa R0`` (a closed-form reference used by the tests).

    Quadrature error: the grid spacing is ~(8 pi^2 / M)^(1/3) rad, 6.2 deg for M = 2^15, so the
    normaliser is accurate for distributions broader than that. Measured against the matrix Fisher
    density (lattice vMF columns at three random rotations, log density at the mode): within
    0.01 nat for kappa = 10 (the training target), 0.03 for kappa = 30, 0.06 for kappa = 100
    (spread ~6 deg; this includes the 3-deg lattice's own discretisation). Much sharper predictions
    (a point mass on one lattice cell per column) are not resolved, and their value is not
    meaningful.

    Args:
        log_p: ``(B, 3, n)`` log probabilities of the three column distributions.
        R: ``(B, 3, 3)`` rotations.
        grid: ``(n, 3)`` the Fibonacci lattice of ``n`` points the distributions live on.
        n_rotations: size of the Haar quadrature grid.
    Returns:
        ``(B,)`` log densities (nats; 0 for a uniform prediction).
    """
    return column_product_log_density_many(log_p, R[:, None], grid, n_rotations)[:, 0]


# Above this many query directions the nearest lattice point comes from a k-d tree: the dense
# (queries, n) dot products cost 3 n flops per query and, with an inner dimension of 3, run far
# below the machine's matmul rate (Pd/Re-Net's yaw beliefs: 40 ms a frame dense, ~1 ms by tree).
KD_TREE_QUERIES = 4096


def nearest_lattice_points(x: Tensor, grid: Tensor, tree: bool | None = None) -> Tensor:
    """Index of the lattice point nearest to each unit vector: ``x (..., d)``, ``grid (n, d)``
    -> ``(...)`` int64. For unit vectors the largest dot product is the smallest Euclidean
    distance, so the dense argmax (few queries) and the k-d tree (many, ``KD_TREE_QUERIES``, in
    float64) give the same index (tested in float64) except at near ties: float32 dot products
    pick the other of two points within ~1e-7 of each other for 4e-5 of Pd/Re-Net's yaw-slice
    rotations (measured), where the tree's float64 distances are the exact answer.

    ``tree``: None chooses by the number of queries; True always uses the tree (the ``_many``
    densities of the yaw beliefs: then a frame's bits do not depend on how many frames share
    a call), False never. Autograd inputs always take the dense path."""
    queries = x.reshape(-1, x.shape[-1])
    dense = queries.shape[0] <= KD_TREE_QUERIES if tree is None else not tree
    if dense or x.requires_grad:
        return (x @ grid.to(x.dtype).T).argmax(-1)
    tree = _lattice_tree(grid.detach().cpu().double().numpy().tobytes(), grid.shape[-1])
    _, index = tree.query(queries.detach().cpu().double().numpy())
    return torch.as_tensor(index, dtype=torch.int64, device=x.device).reshape(x.shape[:-1])


@lru_cache(maxsize=4)
def _lattice_tree(points: bytes, dim: int):  # -> scipy.spatial.cKDTree, built once per lattice
    import numpy as np
    from scipy.spatial import cKDTree

    return cKDTree(np.frombuffer(points, dtype=np.float64).reshape(-1, dim))


def column_product_log_density_many(
    log_p: Tensor,
    R: Tensor,
    grid: Tensor,
    n_rotations: int = HAAR_GRID_SIZE,
    tree: bool | None = None,
) -> Tensor:
    """:func:`column_product_log_density` of ``K`` rotations per sample, the normaliser computed
    once per sample: ``log_p (B, 3, n)``, ``R (B, K, 3, 3)`` -> ``(B, K)``. Memory: the nearest
    lattice points take a ``(B, K, 3, n)`` product, so callers batch ``B K`` to a few thousand."""
    n = grid.shape[0]
    index = _haar_grid_column_indices(n, n_rotations).to(log_p.device)  # (M, 3)
    at_R = nearest_lattice_points(R.transpose(-1, -2), grid, tree)  # (B, K, 3) nearest points
    per_sample = log_p[:, None].expand(-1, at_R.shape[1], -1, -1)  # (B, K, 3, n), a view
    score = per_sample.gather(-1, at_R[..., None]).squeeze(-1).sum(-1)  # (B, K)
    # s(R_m) for every grid rotation: gather column j's log-probability at index[:, j].
    on_grid = sum(log_p[:, j, index[:, j]] for j in range(3))  # (B, M)
    return score - (torch.logsumexp(on_grid, dim=-1) - math.log(n_rotations))[:, None]


def interval_mle(
    resultant: Tensor, kappa: float, lower: float, candidates: Tensor, log_norm: Tensor
) -> Tensor:
    """The centre ``mu`` in [lower, lower + pi] whose truncated von Mises target is closest in
    cross-entropy to a distribution with resultant ``m``: ``argmin -kappa m.(cos mu, sin mu) +
    log Z(mu)``. Shared by the interval-valued angles of
    ``pd_net_e`` (pitch on [-pi/2, pi/2]) and ``pd_net_rv`` (rotation angle on [0, pi]).

    Args:
        resultant: ``(..., 2)`` ``sum_b p_b (cos c_b, sin c_b)``.
        kappa: the target's concentration.
        lower: lower end of the interval (rad); the interval has length pi.
        candidates: ``(M,)`` float64 equally spaced candidates from ``lower`` to ``lower + pi``.
        log_norm: ``(M,)`` float64 ``log Z`` at the candidates.
    Returns:
        ``(...)`` radians in [lower, lower + pi], dtype of ``resultant``.
    """
    m = resultant.double()
    f = (
        -kappa * (m[..., :1] * torch.cos(candidates) + m[..., 1:] * torch.sin(candidates))
        + log_norm
    )  # (..., M)
    j = f.argmin(-1)
    last = candidates.shape[0] - 1
    jm, jp = (j - 1).clamp(0, last), (j + 1).clamp(0, last)
    f0 = f.gather(-1, j[..., None]).squeeze(-1)
    fm = f.gather(-1, jm[..., None]).squeeze(-1)
    fp = f.gather(-1, jp[..., None]).squeeze(-1)
    curvature = fm - 2 * f0 + fp
    interior = (j > 0) & (j < last) & (curvature > 0)
    # Vertex of the parabola through the three values; it lies within half a step of j.
    offset = torch.where(interior, 0.5 * (fm - fp) / curvature.clamp_min(1e-300), 0.0)
    step = candidates[1] - candidates[0]
    mu = candidates[j] + offset.clamp(-0.5, 0.5) * step
    return mu.clamp(lower, lower + math.pi).to(resultant.dtype)
