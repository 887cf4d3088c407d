"""A pair encoder's own pose volume as the belief the flight fusion carries (issue 39, item 2).

The matching encoder scores every (yaw, north, east) cell of its search square and normalises
them into ``log p`` (``extras["log_volume"] (B, K, P, Q)``; axes in
:class:`~benchmark.models.pair_encoder.PoseVolumeAxes`). Its marginals are the encoder's own
beliefs, before any head:

- **yaw**: the mass ``p_k`` of each of the ``K`` bins (width ``w = 2 pi / K``) as a density
  ``p_k / w`` at the bin centre, interpolated linearly (periodically) to the fusion's circular
  grid. The interpolant integrates to ``sum_k p_k = 1`` exactly (trapezoid rule of a periodic
  piecewise-linear function), and its maximum is a bin centre.
- **position**: the mass of each cell (``cell_m`` square) as a density per m^2 at the cell
  centre, interpolated bilinearly to the fusion grid's cell centres (the outer cells' value out
  to their edges, so the interpolant holds the volume's mass), zero outside the searched
  square (the fusion's robust likelihood gives every cell a uniform share: a UAV outside the
  square is not impossible, only unseen by this frame).

Per-frame estimates for the "frame" rows: the yaw of the interpolated belief's maximum (a bin
centre) and the position cell of the marginal's maximum; pitch and roll stay the head's.

**Calibration** (:func:`fit_volume_temperature`). A volume trained by its NLL on the training
frames can be over- or underconfident on new ones, and a wrong match's sharp peak then outvotes
correct frames along a flight. Like a regression head's belief
(:mod:`benchmark.evaluation.beliefs`), each belief the fusion uses is calibrated on the
validation split before it is fused: one temperature ``tau``, ``log q = log_softmax(log p /
tau)``, fitted by maximum likelihood of the truth (temperature scaling), for the whole volume
(the joint fusion), its yaw marginal and its position marginal (the marginal fusions). The
likelihood fitted is the one the fusion reads, ``(1 - w) q + w / M`` with the fusion's outlier
weight ``w`` (``FusionSettings.outlier_weight``; its uniform share read in cell masses, spread
over the ``M`` cells): fitted on ``q`` alone, the wrong matches' frames, which the fusion's
uniform share already explains, would soften every frame's vote (the quick units' volumes on
standard/val: 1.83-1.91 vision-only and 1.30-1.37 gravity-aided without the outlier share,
1.57-1.58 and 1.24-1.32 with it). With ``w = 0`` the NLL is convex in ``beta = 1 / tau``
(``-beta s_c + logsumexp(beta s)``: a log-partition function), so a bounded scalar search finds
its one minimum; with ``w > 0`` a scan brackets it first (:func:`fit_temperature`). Tempering
keeps the order of the cells: the per-frame estimates stay the untempered marginals' maxima (a
calibration changes how strongly a frame votes along a flight, not what it says; the "frame"
rows do not move with it).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import asdict, dataclass

import torch
from torch import Tensor
from torch.utils.data import Dataset

from benchmark.evaluation.evaluate import model_outputs
from benchmark.evaluation.fusion_grid import CircularGrid, PlanarGrid


@dataclass(frozen=True)
class VolumeMarginals:
    """Per-frame marginals of a pose volume, float64 on the CPU, rows in dataset order:
    ``index (N,)`` int64 the items' indices, ``yaw_log_p (N, K)`` log-mass of each yaw bin,
    ``position_log_p (N, P, Q)`` log-mass of each (north row, east column) cell, and the axes
    ``yaw (K,)`` rad, ``north (P,)``, ``east (Q,)`` m, ``cell_m``."""

    index: Tensor
    yaw_log_p: Tensor
    position_log_p: Tensor
    yaw: Tensor
    north: Tensor
    east: Tensor
    cell_m: float
    # ``(N, K, P, Q)`` float32 log-mass of every cell, rows as ``index``; None unless asked for
    # (``volume_marginals(keep_volume=True)``: the joint fusion reads it; ~0.2 MB a frame)
    log_volume: Tensor | None = None
    # the untempered volume's marginals ``(N, K)`` and ``(N, P, Q)`` when the fields above are
    # tempered (``volume_marginals(temperature != 1)``): the per-frame estimates are read from
    # them, so that a calibration changes how a frame votes, not what it says; None: the above
    raw_yaw_log_p: Tensor | None = None
    raw_position_log_p: Tensor | None = None

    def __post_init__(self) -> None:
        n, k = self.yaw_log_p.shape
        if self.position_log_p.shape != (n, len(self.north), len(self.east)):
            raise ValueError(
                f"position_log_p must be (N, P, Q) = {(n, len(self.north), len(self.east))}, "
                f"got {tuple(self.position_log_p.shape)}"
            )
        if k != len(self.yaw) or self.index.shape != (n,):
            raise ValueError("VolumeMarginals: yaw_log_p (N, K), yaw (K,) and index (N,) disagree")
        for name, like in (("raw_yaw_log_p", self.yaw_log_p),
                           ("raw_position_log_p", self.position_log_p)):  # fmt: skip
            raw = getattr(self, name)
            if raw is not None and raw.shape != like.shape:
                raise ValueError(
                    f"VolumeMarginals: {name} must be {tuple(like.shape)}, got {tuple(raw.shape)}"
                )


def gives_pose_volume(model: torch.nn.Module) -> bool:
    """Whether ``model``'s encoder describes a pose volume (``PairEncoder.pose_volume_axes``)."""
    axes = getattr(getattr(model, "encoder", None), "pose_volume_axes", None)
    return axes is not None and axes() is not None


@torch.no_grad()
def volume_marginals(
    model: torch.nn.Module,
    dataset: Dataset,
    *,
    batch_size: int = 64,
    shared_satellite: bool = True,
    precision: str = "fp32",
    num_workers: int = 0,
    progress: bool = False,
    desc: str = "volume",
    keep_volume: bool = False,
    temperature: float = 1.0,
    yaw_temperature: float = 1.0,
    position_temperature: float = 1.0,
) -> VolumeMarginals:
    """Run ``model`` over the images of ``dataset`` (a ``PairDataset``: the encoder must see the
    pairs, not cached features) and keep its pose volume's marginals. Eval mode, restored after;
    the forward under autocast for ``precision``, the marginals in float64; ``keep_volume``: the
    whole volume too (float32, ``VolumeMarginals.log_volume``), tempered by ``temperature``;
    the yaw and position marginals tempered by ``yaw_temperature`` and ``position_temperature``
    (:func:`temper_log_volume`, :class:`VolumeCalibration`; 1 leaves each bit-identical; any
    other keeps the untempered marginals in ``raw_*`` for the per-frame estimates)."""
    tempers = {"temperature": temperature, "yaw_temperature": yaw_temperature,
               "position_temperature": position_temperature}  # fmt: skip
    for name, value in tempers.items():
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a finite positive number, got {value!r}")
    tempered = any(value != 1.0 for value in tempers.values())
    axes = model.encoder.pose_volume_axes() if gives_pose_volume(model) else None
    if axes is None:
        raise ValueError(
            f"{type(getattr(model, 'encoder', model)).__name__} has no pose volume "
            f"(PairEncoder.pose_volume_axes is None): fuse its heads' beliefs instead"
        )
    index, yaw, position, volumes, raw_yaw, raw_position = [], [], [], [], [], []
    passes = model_outputs(
        model, dataset, batch_size=batch_size, shared_satellite=shared_satellite,
        precision=precision, num_workers=num_workers, progress=progress, desc=desc,
    )  # fmt: skip
    for batch, out in passes:
        if "uav" not in batch:
            raise ValueError("volume_marginals needs the images: got cached features")
        raw = out.encoder["log_volume"].double()  # (B, K, P, Q)
        yaw_p, position_p = torch.logsumexp(raw, dim=(2, 3)), torch.logsumexp(raw, dim=1)
        if tempered:
            raw_yaw.append(yaw_p.cpu())
            raw_position.append(position_p.cpu())
        yaw.append(temper_log_volume(yaw_p, yaw_temperature).cpu())
        position.append(temper_log_volume(position_p, position_temperature).cpu())
        if keep_volume:
            volumes.append(temper_log_volume(raw, temperature).float().cpu())
        index.append(batch["index"].cpu())
    return VolumeMarginals(
        torch.cat(index).long(), torch.cat(yaw), torch.cat(position),
        axes.yaw.double().cpu(), axes.north.double().cpu(), axes.east.double().cpu(),
        float(axes.cell_m), torch.cat(volumes) if keep_volume else None,
        torch.cat(raw_yaw) if raw_yaw else None, torch.cat(raw_position) if raw_position else None,
    )  # fmt: skip


# Below this log-mass a cell holds nothing in float64 (the smallest normal double is e^-708): an
# excluded cell (the encoder's masked positions) stays excluded at any temperature.
_EMPTY_LOG_MASS = math.log(torch.finfo(torch.float64).tiny)


def temper_log_volume(log_volume: Tensor, temperature: float) -> Tensor:
    """``log_softmax(log_volume / temperature)`` over each frame's cells: ``log_volume (B, ...)``
    log-masses, the same shape back (float64 in, float64 out). Empty cells (below
    :data:`_EMPTY_LOG_MASS`) stay empty. ``temperature == 1`` returns ``log_volume`` itself."""
    if temperature == 1.0:
        return log_volume
    empty = log_volume < _EMPTY_LOG_MASS
    scaled = torch.where(empty, log_volume, log_volume / temperature)
    lse = torch.logsumexp(scaled.flatten(1), dim=1)
    return scaled - lse.view(-1, *([1] * (log_volume.dim() - 1)))


@dataclass(frozen=True)
class VolumeCalibration:
    """A pose volume's temperatures fitted on a validation split (:func:`fit_volume_temperature`),
    one per belief the fusion uses: ``temperature`` of the whole volume (the joint fusion),
    ``yaw_temperature`` of its yaw marginal and ``position_temperature`` of its position marginal
    (the marginal fusions); > 1 softens an overconfident belief. Fitted on the ``n_frames``
    whose true pose lies inside the searched square, of ``n_total``, under the mixture with
    ``outlier_weight`` (:func:`fit_temperature`). Mean NLLs (nats) of the truth before
    (``*_raw``, temperature 1) and after, under that mixture, and the uniform's (``*_uniform``)."""

    temperature: float
    yaw_temperature: float
    position_temperature: float
    n_frames: int
    n_total: int
    nll_raw: float
    nll: float
    nll_uniform: float
    yaw_nll_raw: float
    yaw_nll: float
    yaw_nll_uniform: float
    position_nll_raw: float
    position_nll: float
    position_nll_uniform: float
    outlier_weight: float = 0.0

    def to_dict(self) -> dict[str, float | int]:
        return dict(asdict(self))


def true_cells(
    axes: tuple[Tensor, Tensor, Tensor], yaw: Tensor, east: Tensor, north: Tensor, cell_m: float
) -> tuple[Tensor, Tensor]:
    """Each frame's true cell of a volume with axes ``(yaw (K,), north (P,), east (Q,))``: the
    flat index ``(N,)`` into ``(K, P, Q)`` of the nearest yaw bin (around the circle) and the
    nearest position cell, and ``inside (N,)`` bool, whether the true (E, N) lies within that
    cell (``cell_m`` square), i.e. inside the searched square. ``yaw`` rad, ``east``, ``north``
    m, each ``(N,)``."""
    yaw_axis, north_axis, east_axis = (a.double() for a in axes)
    gap = torch.remainder(yaw.double()[:, None] - yaw_axis[None] + math.pi, 2 * math.pi) - math.pi
    k = gap.abs().argmin(1)
    dn = (north.double()[:, None] - north_axis[None]).abs()
    de = (east.double()[:, None] - east_axis[None]).abs()
    p, q = dn.argmin(1), de.argmin(1)
    half = 0.5 * cell_m + 1e-9
    inside = (dn.min(1).values <= half) & (de.min(1).values <= half)
    return (k * len(north_axis) + p) * len(east_axis) + q, inside


def fit_temperature(
    log_p: Tensor,
    target: Tensor,
    bounds: tuple[float, float] = (0.25, 16.0),
    outlier_weight: float = 0.0,
) -> tuple[float, float, float]:
    """The temperature ``tau`` maximising the likelihood of ``target (N,)`` (indices) under
    ``(1 - w) softmax(log_p / tau) + w / M`` of ``log_p (N, M)`` log-masses, ``w`` the
    ``outlier_weight`` (the fusion's robust likelihood, :func:`~benchmark.evaluation.fusion.
    robust_log_likelihood`, read in cell masses: its uniform share spread over the ``M`` cells);
    returns ``(tau, NLL at 1, NLL at tau)`` (mean nats). With ``w = 0`` the NLL is convex in
    ``beta = 1 / tau`` (module docstring): bounded Brent over ``1 / bounds``, to 1e-5 in beta.
    With ``w > 0`` it need not be (``-log`` of a mixture): the best of 65 log-spaced ``beta``
    first, then bounded Brent between its two neighbours. float64, 64 rows at a time."""
    from scipy.optimize import minimize_scalar

    if not 0.0 <= outlier_weight < 1.0:
        raise ValueError(f"outlier_weight must lie in [0, 1), got {outlier_weight!r}")
    floor = math.log(outlier_weight) - math.log(log_p.shape[1]) if outlier_weight > 0 else None
    keep = math.log1p(-outlier_weight)

    def nll(beta: float) -> float:
        total = 0.0
        for start in range(0, len(target), 64):
            tempered = temper_log_volume(log_p[start : start + 64].double(), 1.0 / beta)
            at_truth = tempered.gather(1, target[start : start + 64, None])
            if floor is not None:
                at_truth = torch.logaddexp(at_truth + keep, torch.full_like(at_truth, floor))
            total -= float(at_truth.sum())
        return total / len(target)

    low, high = 1.0 / bounds[1], 1.0 / bounds[0]
    if floor is not None:
        betas = torch.logspace(math.log10(low), math.log10(high), 65, dtype=torch.float64)
        scan = [nll(float(b)) for b in betas]
        best = min(range(len(scan)), key=scan.__getitem__)
        low, high = float(betas[max(best - 1, 0)]), float(betas[min(best + 1, len(scan) - 1)])
    beta = float(
        minimize_scalar(nll, bounds=(low, high), method="bounded", options={"xatol": 1e-5}).x
    )
    return 1.0 / beta, nll(1.0), nll(beta)


def fit_volume_temperature(
    log_volume: Tensor,
    axes: tuple[Tensor, Tensor, Tensor],
    cell_m: float,
    yaw: Tensor,
    east: Tensor,
    north: Tensor,
    bounds: tuple[float, float] = (0.25, 16.0),
    outlier_weight: float = 0.0,
) -> VolumeCalibration:
    """The temperatures of maximum likelihood (module docstring) of the whole volume at the true
    cell, of its yaw marginal at the true yaw bin and of its position marginal at the true
    position cell (:func:`fit_temperature`, each within ``bounds``): ``log_volume (N, K, P, Q)``
    log-masses of a validation split's frames, ``axes`` ``(yaw (K,), north (P,), east (Q,))``
    and ``cell_m`` as :class:`VolumeMarginals`, the true ``yaw`` rad, ``east``, ``north`` m
    ``(N,)``, under the fusion's ``outlier_weight`` (the mixture of :func:`fit_temperature`).
    Frames whose truth lies outside the searched square have no true cell and are left out of
    all three (counted). Each belief gets its own temperature because tempering the
    volume is not tempering its marginals: on the quick units' standard/val the volume's
    temperature (1.3-1.9) made its yaw marginal worse than untempered (its own best: about 1)."""
    if log_volume.dim() != 4 or log_volume.shape[0] != yaw.shape[0]:
        raise ValueError(
            f"log_volume must be (N, K, P, Q) with N = len(yaw) = {yaw.shape[0]}, "
            f"got {tuple(log_volume.shape)}"
        )
    cells, inside = true_cells(axes, yaw, east, north, cell_m)
    rows = torch.nonzero(inside).flatten()
    if len(rows) == 0:
        raise ValueError("fit_volume_temperature: no frame's true pose lies inside the volume")
    k, p, q = log_volume.shape[1:]
    volume = log_volume[rows].double()
    target = cells[rows]
    w = outlier_weight
    tau, raw, fitted = fit_temperature(volume.flatten(1), target, bounds, w)
    yaw_tau, yaw_raw, yaw_fitted = fit_temperature(
        torch.logsumexp(volume, dim=(2, 3)), target // (p * q), bounds, w
    )
    pos_tau, pos_raw, pos_fitted = fit_temperature(
        torch.logsumexp(volume, dim=1).flatten(1), target % (p * q), bounds, w
    )
    return VolumeCalibration(
        temperature=tau, yaw_temperature=yaw_tau, position_temperature=pos_tau,
        n_frames=len(rows), n_total=int(yaw.shape[0]),
        nll_raw=raw, nll=fitted, nll_uniform=math.log(k * p * q),
        yaw_nll_raw=yaw_raw, yaw_nll=yaw_fitted, yaw_nll_uniform=math.log(k),
        position_nll_raw=pos_raw, position_nll=pos_fitted, position_nll_uniform=math.log(p * q),
        outlier_weight=w,
    )  # fmt: skip


def volume_yaw_beliefs(marginals: VolumeMarginals, grid: CircularGrid) -> Tensor:
    """``(N, n_bins)`` float64 log-density per radian of the UAV yaw on ``grid`` (module
    docstring: the bins' densities interpolated linearly around the circle)."""
    yaw = marginals.yaw
    k = len(yaw)
    width = 2 * math.pi / k
    start = float(yaw[0])
    # the fusion grid's centres as fractional positions along the (sorted, equally spaced) bins
    order = torch.argsort(torch.remainder(yaw - start, 2 * math.pi))
    density = marginals.yaw_log_p[:, order].exp() / width  # (N, K) per radian
    t = torch.remainder(grid.centres(torch.float64) - start, 2 * math.pi) / width  # (n,)
    low = torch.floor(t).long() % k
    frac = t - torch.floor(t)
    value = density[:, low] * (1 - frac) + density[:, (low + 1) % k] * frac
    return torch.log(value.clamp_min(torch.finfo(torch.float64).tiny))


def volume_position_beliefs(marginals: VolumeMarginals, rows: Tensor, grid: PlanarGrid) -> Tensor:
    """``(M, n_east, n_north)`` float64 log-density per m^2 on ``grid`` of the frames ``rows
    (M,)`` (positions in the marginals; a negative row, a flight's padding, gets frame 0's):
    bilinear between the volume's cell centres, the edge cells' value to their outer edges,
    zero (``log tiny``) beyond the searched square (:func:`_linear_weights`)."""
    east, north = grid.centres(torch.float64)
    we, ie = _linear_weights(marginals.east, east)  # (n_east, 2) each
    wn, in_ = _linear_weights(marginals.north, north)  # (n_north, 2)
    density = marginals.position_log_p[rows.clamp_min(0)].exp() / marginals.cell_m**2
    out = torch.zeros(len(rows), len(east), len(north), dtype=torch.float64)
    for a in range(2):  # the four neighbours: north index a, east index b
        rows_n = density[:, in_[:, a], :]  # (M, n_north, Q)
        for b in range(2):
            part = rows_n[:, :, ie[:, b]]  # (M, n_north, n_east)
            out += (wn[:, a][:, None] * we[:, b][None, :] * part).transpose(1, 2)
    return torch.log(out.clamp_min(torch.finfo(torch.float64).tiny))


def _linear_weights(axis: Tensor, points: Tensor) -> tuple[Tensor, Tensor]:
    """Linear interpolation from the cell centres ``axis (A,)`` (equally spaced, ascending or
    descending) to ``points (n,)``: weights and indices ``(n, 2)``. The outer cells reach half
    a cell beyond their centres, where the value stays the edge's (so the interpolant's
    integral is the cells' total: the trapezoid rule plus the two half-cell strips); weight 0
    beyond."""
    ascending = bool(axis[-1] > axis[0])
    x = axis if ascending else axis.flip(0)
    step = float(x[1] - x[0])
    t = (points - float(x[0])) / step
    inside = (t >= -0.5) & (t <= len(x) - 0.5)
    t = t.clamp(0, len(x) - 1)
    low = torch.floor(t).clamp(0, len(x) - 2).long()
    frac = (t - low).clamp(0, 1)
    weights = torch.stack([1 - frac, frac], dim=1) * inside[:, None]
    index = torch.stack([low, low + 1], dim=1)
    if not ascending:
        index = len(x) - 1 - index
    return weights.to(torch.float64), index


def volume_estimates(marginals: VolumeMarginals, grid: CircularGrid) -> tuple[Tensor, Tensor]:
    """The volume's own per-frame estimates: ``yaw (N,)`` rad, the maximum of
    :func:`volume_yaw_beliefs` on ``grid``, and ``(N, 2)`` (E, N) metres, the centre of the
    position marginal's most probable cell; of the untempered marginals when ``marginals`` holds
    them (``raw_*``)."""
    if marginals.raw_yaw_log_p is not None and marginals.raw_position_log_p is not None:
        marginals = dataclasses.replace(
            marginals, yaw_log_p=marginals.raw_yaw_log_p,
            position_log_p=marginals.raw_position_log_p, raw_yaw_log_p=None,
            raw_position_log_p=None,
        )  # fmt: skip
    yaw = grid.centres(torch.float64)[volume_yaw_beliefs(marginals, grid).argmax(-1)]
    flat = marginals.position_log_p.flatten(1).argmax(-1)
    q = len(marginals.east)
    en = torch.stack([marginals.east[flat % q], marginals.north[flat // q]], dim=-1)
    return yaw, en


__all__ = [
    "VolumeCalibration",
    "VolumeMarginals",
    "fit_temperature",
    "fit_volume_temperature",
    "gives_pose_volume",
    "temper_log_volume",
    "true_cells",
    "volume_estimates",
    "volume_marginals",
    "volume_position_beliefs",
    "volume_yaw_beliefs",
]
