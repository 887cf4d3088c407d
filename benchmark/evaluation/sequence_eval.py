"""Run a trained model over a split and fuse its beliefs along the flights (issue 39).

:func:`evaluate_sequence` is the evaluation step behind the ``sequence`` table: one pass of the
model that also records every frame's yaw belief through the head contract
(:func:`benchmark.evaluation.beliefs.yaw_beliefs`: the head's own density, or the calibrated
density of a regression head), then :func:`benchmark.evaluation.sequence.fuse_split` twice:

- ``odometry = "data"``: with the odometry the dataset carries (``odo_*`` columns, the profile's
  stated noise, which the filters are told);
- ``odometry = "<s>x"``: with odometry drawn again from the true poses at ``s`` times every noise
  figure (default 4x, the stress row of the issue), the filters told the same figures. Seeded by
  the split name and the dataset seed, so it is the same for every head and every run.

Calibration (regression heads' densities, every head's position belief) comes from the unit's
validation predictions only (``calibrate_from_predictions`` refuses any other split).
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
from collections.abc import Callable
from functools import partial
from typing import Any

import numpy as np
import pandas as pd
import torch
from torch.utils.data import Dataset

from benchmark.data import ODOMETRY_COLUMNS, flight_odometry
from benchmark.evaluation.beliefs import (
    AttitudeCalibration,
    PositionCalibration,
    calibrate_from_predictions,
    calibrated_yaw_beliefs,
    position_beliefs,
    take_raw,
    yaw_beliefs,
)
from benchmark.evaluation.evaluate import (
    BeliefFn,
    model_outputs,
    predict,
    predictions_to_frame,
)
from benchmark.evaluation.fusion import CircularGrid, OdometryNoise
from benchmark.evaluation.fusion_joint import JointBelief, volume_joint_belief
from benchmark.evaluation.sequence import (
    FusionSettings,
    SplitFrames,
    fuse_split,
    fuse_split_joint,
    summarize_sequence,
)
from benchmark.evaluation.volume_beliefs import (
    VolumeMarginals,
    volume_estimates,
    volume_position_beliefs,
    volume_yaw_beliefs,
)
from benchmark.progress import Progress

STRESS_SCALE = 4.0
# Summary key: 1.0 when the translation head's own density was the position belief (a head with
# ``position_log_prob``), 0.0 for the calibrated Gaussian + uniform density around its estimate.
POSITION_FROM_HEAD = "position_from_head"
# (frame rows (M,) int64, -1 for padding; the position grid) -> (M, n_east, n_north) log-density
PositionBeliefFn = Callable[[torch.Tensor, Any], torch.Tensor]


def _scaled(noise: OdometryNoise, scale: float) -> OdometryNoise:
    return OdometryNoise(**{k: v * scale for k, v in dataclasses.asdict(noise).items()})


def stress_odometry(
    poses: pd.DataFrame, noise: OdometryNoise, seed: int, split: str
) -> pd.DataFrame:
    """``odo_*`` columns drawn again from the true poses of ``poses`` with ``noise``, one
    generator per flight seeded by (``seed``, ``split``, flight): aligned with ``poses``."""
    tag = int.from_bytes(hashlib.sha256(split.encode()).digest()[:4], "little")
    out = pd.DataFrame(index=poses.index, columns=list(ODOMETRY_COLUMNS), dtype=np.float64)
    for flight, rows in poses.groupby("flight", sort=True):
        rows = rows.sort_values("time_s", kind="stable")
        rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(tag, int(flight))))
        odo = flight_odometry(
            *(rows[k].to_numpy(np.float64) for k in ("E", "N", "U", "yaw", "time_s")),
            noise=noise,
            rng=rng,
        )
        out.loc[rows.index, list(ODOMETRY_COLUMNS)] = odo
    return out


def _odometry_runs(
    rows: pd.DataFrame, noise: OdometryNoise, stress_scale: float | None, seed: int, split: str
) -> list[tuple[str, pd.DataFrame, OdometryNoise]]:
    """``(name, odometry columns, the noise the filter is told)``: the dataset's odometry
    ("data"), then with ``stress_scale`` the stress odometry ("{s}x", :func:`stress_odometry`)."""
    runs = [("data", rows, noise)]
    if stress_scale is not None:
        stressed = _scaled(noise, stress_scale)
        runs.append((f"{stress_scale:g}x", stress_odometry(rows, stressed, seed, split), stressed))
    return runs


def _run_summary(table: pd.DataFrame, name: str) -> dict[str, float]:
    """:func:`summarize_sequence` of one odometry run, keys ``seq_*`` for "data" and
    ``seq{name}_*`` for a stress run."""
    prefix = "seq" if name == "data" else f"seq{name}"
    return {k.replace("seq", prefix, 1): v for k, v in summarize_sequence(table).items()}


def _frames(
    frame: pd.DataFrame,
    poses: pd.DataFrame,
    beliefs: torch.Tensor,
    odometry: pd.DataFrame,
    footprint: np.ndarray,
    position: PositionCalibration | None,
    position_belief: PositionBeliefFn | None = None,
) -> SplitFrames:
    rad = math.pi / 180.0
    hats = frame[["E_hat_m", "N_hat_m"]].to_numpy(np.float64)
    if position_belief is None:
        if position is None:
            raise ValueError("a position calibration or a position_belief is needed")
        position_belief = partial(_calibrated_position, hats=hats, calibration=position)
    return SplitFrames(
        flight=poses["flight"].to_numpy(np.int64),
        time_s=poses["time_s"].to_numpy(np.float64),
        yaw_beliefs=beliefs,
        yaw_hat=frame["yaw_hat_deg"].to_numpy(np.float64) * rad,
        pitch_hat=frame["pitch_hat_deg"].to_numpy(np.float64) * rad,
        roll_hat=frame["roll_hat_deg"].to_numpy(np.float64) * rad,
        position_hat=hats,
        position_log_belief=position_belief,
        odo_dyaw=odometry["odo_dyaw"].to_numpy(np.float64),
        odo_dxy=odometry[["odo_dx", "odo_dy"]].to_numpy(np.float64),
        footprint_m=footprint,
        yaw=poses["yaw"].to_numpy(np.float64),
        pitch=poses["pitch"].to_numpy(np.float64),
        roll=poses["roll"].to_numpy(np.float64),
        position=poses[["dE", "dN"]].to_numpy(np.float64),
        index=frame["index"].to_numpy(np.int64),
    )


def _calibrated_position(
    rows: torch.Tensor, grid: Any, hats: np.ndarray, calibration: PositionCalibration
) -> torch.Tensor:
    """The calibrated belief around each row's estimate (padding rows: row 0's). ``hats`` may be
    a read-only view of a frame's column: copied, since torch cannot wrap a read-only array."""
    estimates = torch.from_numpy(np.array(hats, copy=True))
    return position_beliefs(estimates[rows.clamp_min(0)], grid, calibration)


def footprints(poses: pd.DataFrame, sat_table: pd.DataFrame) -> np.ndarray:
    """``(N, 2)`` E x N extent (m) of the satellite image each pair was shown."""
    sat = sat_table.set_index("sat_index").loc[poses["sat_index"].to_numpy()]
    return sat[["footprint_E_m", "footprint_N_m"]].to_numpy(np.float64)


def sequence_belief_fn(
    attitude: AttitudeCalibration | None, settings: FusionSettings | None = None
) -> BeliefFn:
    """The per-batch belief recorder of :func:`~benchmark.evaluation.evaluate.predict` that
    :func:`fuse_predictions` expects: yaw beliefs on ``settings``' circular grid, a regression
    head's calibrated by ``attitude``."""
    settings = settings or FusionSettings()
    return partial(yaw_beliefs, grid=CircularGrid(settings.yaw_bins), calibration=attitude)


def evaluate_sequence(
    model: torch.nn.Module,
    dataset: Dataset,
    poses: pd.DataFrame,
    sat_table: pd.DataFrame,
    calibration: tuple[AttitudeCalibration, PositionCalibration],
    noise: OdometryNoise,
    *,
    split: str,
    seed: int,
    settings: FusionSettings | None = None,
    stress_scale: float | None = STRESS_SCALE,
    batch_size: int = 64,
    shared_satellite: bool = True,
    precision: str = "fp32",
    num_workers: int = 0,
    progress: bool = False,
) -> tuple[dict[str, float], pd.DataFrame]:
    """Fuse ``model``'s beliefs over the flights of ``dataset`` (items indexing ``poses``, the
    split's pair table with the ``odo_*`` columns): one pass of the model recording every
    frame's belief, then :func:`fuse_predictions` (see there for the result). The position
    belief is the translation head's own density when it gives one (:func:`head_position_belief`,
    ``summary[POSITION_FROM_HEAD] = 1``), else the calibrated one."""
    pred = predict(
        model,
        dataset,
        batch_size=batch_size,
        shared_satellite=shared_satellite,
        progress=progress,
        desc=f"beliefs {split}",
        precision=precision,
        num_workers=num_workers,
        beliefs=sequence_belief_fn(calibration[0], settings),
    )
    assert pred.beliefs is not None
    frame = predictions_to_frame(pred)
    own_density = gives_position_density(model.translation_head)
    position = (
        head_position_belief(model, dataset, frame, batch_size=batch_size,
                             shared_satellite=shared_satellite, precision=precision,
                             num_workers=num_workers)
        if own_density else None
    )  # fmt: skip
    summary, table = fuse_predictions(
        frame, pred.beliefs, poses, sat_table, calibration, noise, split=split, seed=seed,
        settings=settings, stress_scale=stress_scale, position_belief=position,
    )  # fmt: skip
    summary[POSITION_FROM_HEAD] = float(own_density)
    return summary, table


def fuse_predictions(
    frame: pd.DataFrame,
    beliefs: torch.Tensor | np.ndarray,
    poses: pd.DataFrame,
    sat_table: pd.DataFrame,
    calibration: tuple[AttitudeCalibration | None, PositionCalibration | None],
    noise: OdometryNoise,
    *,
    split: str,
    seed: int,
    settings: FusionSettings | None = None,
    stress_scale: float | None = STRESS_SCALE,
    position_belief: PositionBeliefFn | None = None,
) -> tuple[dict[str, float], pd.DataFrame]:
    """Fuse a split's per-frame predictions along its flights, with no model: ``frame`` the
    per-frame table (``index`` into ``poses``, ``yaw/pitch/roll_hat_deg``, ``E/N_hat_m``: the
    evaluation CSV), ``beliefs (N, bins)`` its rows' yaw beliefs (:func:`sequence_belief_fn`);
    ``position_belief`` the rows' position beliefs (default: the calibrated density around
    ``E/N_hat_m``, ``calibration[1]``).
    Returns the summary (``seq_*`` keys for the dataset's odometry, ``seq{s}x_*`` for the
    stress odometry, whose positions are not fused: its filtered and smoothed horizontal
    errors are NaN; ``stress_scale=None``: none) and the long per-frame table of
    :func:`~benchmark.evaluation.sequence.fuse_split` with an ``odometry`` column."""
    settings = settings or FusionSettings()
    attitude, position = calibration
    beliefs = torch.as_tensor(np.asarray(beliefs, dtype=np.float64))
    if beliefs.shape != (len(frame), settings.yaw_bins):
        raise ValueError(
            f"split {split}: beliefs of shape {tuple(beliefs.shape)} for {len(frame)} frames; "
            f"expected ({len(frame)}, {settings.yaw_bins}) (one per frame and yaw bin)"
        )
    rows = poses.iloc[frame["index"].to_numpy()].reset_index(drop=True)
    missing = [c for c in ODOMETRY_COLUMNS if c not in rows.columns]
    if missing:
        raise ValueError(f"split {split}: the pair table has no odometry columns {missing}")
    extent = footprints(rows, sat_table)
    runs = _odometry_runs(rows, noise, stress_scale, seed, split)
    tables, summary = [], {}
    for name, odometry, told in runs:
        frames = _frames(frame, rows, beliefs, odometry, extent, position, position_belief)
        # the stress odometry fuses the heading only: the figure draws δψ, and no table or
        # claim reads a position fused under it (the position grid is most of the cost)
        table = fuse_split(frames, told, settings, position=name == "data")
        table.insert(0, "odometry", name)
        tables.append(table)
        summary.update(_run_summary(table, name))
    summary["calibration_kappa"] = attitude.kappa if attitude is not None else math.nan
    summary["calibration_sigma_m"] = position.sigma_m if position is not None else math.nan
    return summary, pd.concat(tables, ignore_index=True)


def fuse_estimates(
    frame: pd.DataFrame,
    val_frame: pd.DataFrame,
    poses: pd.DataFrame,
    sat_table: pd.DataFrame,
    noise: OdometryNoise,
    *,
    split: str,
    val_split: str,
    seed: int,
    area_m2: float,
    settings: FusionSettings | None = None,
    stress_scale: float | None = STRESS_SCALE,
) -> tuple[dict[str, float], pd.DataFrame]:
    """Fuse per-frame point estimates that come with no density of their own (the constant
    predictor, the non-learned references, a user's own estimator) exactly as a regression head
    is fused: the calibrated isotropic matrix Fisher + uniform density around each frame's
    estimate and the calibrated position density, both fitted on ``val_frame`` (the same
    estimator's per-frame table on the validation split ``val_split``; any other split is
    refused), then :func:`fuse_predictions`. ``frame``/``val_frame``: evaluation tables
    (``index``, ``yaw/pitch/roll_hat_deg``, ``E/N_hat_m``; ``dphi_deg``, ``dE_m``, ``dN_m`` on
    the validation one); ``area_m2`` the satellite footprint (the position density's uniform
    part). Returns what :func:`fuse_predictions` returns."""
    settings = settings or FusionSettings()
    attitude, position = calibrate_from_predictions(val_frame, val_split, area_m2)
    grid = CircularGrid(settings.yaw_bins)
    yaw_hat = torch.as_tensor(np.radians(frame["yaw_hat_deg"].to_numpy(np.float64)))
    beliefs = calibrated_yaw_beliefs(yaw_hat, grid, attitude)
    return fuse_predictions(
        frame, beliefs, poses, sat_table, (attitude, position), noise, split=split, seed=seed,
        settings=settings, stress_scale=stress_scale,
    )  # fmt: skip


def _volume_frames(
    frame: pd.DataFrame, marginals: VolumeMarginals, grid: CircularGrid, split: str
) -> tuple[VolumeMarginals, pd.DataFrame]:
    """``marginals`` in the order of ``frame``'s rows (matched on ``index``; the whole volume
    too when kept) and ``frame`` with the volume's own per-frame estimates in place of the
    head's yaw and position (pitch and roll stay the head's)."""
    position_of = {int(i): k for k, i in enumerate(marginals.index.tolist())}
    missing = [int(i) for i in frame["index"] if int(i) not in position_of]
    if missing:
        raise ValueError(
            f"split {split}: the volume pass has no frame {missing[:5]} of the evaluation table"
        )
    order = torch.as_tensor([position_of[int(i)] for i in frame["index"]], dtype=torch.long)

    def rows(x: torch.Tensor | None) -> torch.Tensor | None:
        return x[order] if x is not None else None

    aligned = dataclasses.replace(
        marginals, index=marginals.index[order], yaw_log_p=marginals.yaw_log_p[order],
        position_log_p=marginals.position_log_p[order], log_volume=rows(marginals.log_volume),
        raw_yaw_log_p=rows(marginals.raw_yaw_log_p),
        raw_position_log_p=rows(marginals.raw_position_log_p),
    )  # fmt: skip
    yaw_hat, en_hat = volume_estimates(aligned, grid)
    own = frame.copy()
    own["yaw_hat_deg"] = np.degrees(yaw_hat.numpy())
    own["E_hat_m"], own["N_hat_m"] = en_hat[:, 0].numpy(), en_hat[:, 1].numpy()
    return aligned, own


def fuse_volume(
    frame: pd.DataFrame,
    marginals: VolumeMarginals,
    poses: pd.DataFrame,
    sat_table: pd.DataFrame,
    noise: OdometryNoise,
    *,
    split: str,
    seed: int,
    settings: FusionSettings | None = None,
    stress_scale: float | None = STRESS_SCALE,
) -> tuple[dict[str, float], pd.DataFrame]:
    """Fuse a pair encoder's own pose volume along the flights (``benchmark.evaluation.
    volume_beliefs``): its yaw marginal and its position marginal are the beliefs (as tempered
    in ``marginals``: ``volume_marginals``' temperatures, fitted on the validation split), the
    untempered marginals' maxima the per-frame estimates; pitch and roll are the heads'
    (``frame``: the evaluation CSV of the same split, matched to ``marginals`` on ``index``).
    Returns what :func:`fuse_predictions` returns."""
    settings = settings or FusionSettings()
    grid = CircularGrid(settings.yaw_bins)
    aligned, own = _volume_frames(frame, marginals, grid, split)
    return fuse_predictions(
        own, volume_yaw_beliefs(aligned, grid), poses, sat_table, (None, None), noise,
        split=split, seed=seed, settings=settings, stress_scale=stress_scale,
        position_belief=partial(volume_position_beliefs, aligned),
    )  # fmt: skip


def fuse_volume_joint(
    frame: pd.DataFrame,
    marginals: VolumeMarginals,
    poses: pd.DataFrame,
    sat_table: pd.DataFrame,
    noise: OdometryNoise,
    *,
    split: str,
    seed: int = 0,
    settings: FusionSettings | None = None,
    stress_scale: float | None = None,
    progress: bool = False,
) -> tuple[dict[str, float], pd.DataFrame]:
    """Fuse a pair encoder's whole pose volume along the flights, jointly over heading and
    position (:func:`~benchmark.evaluation.sequence.fuse_split_joint`; ``marginals`` with its
    ``log_volume``, tempered as it comes): the same per-frame estimates and pitch and roll as
    :func:`fuse_volume`. With the dataset's odometry, and with ``stress_scale`` (e.g.
    :data:`STRESS_SCALE`) the stress odometry of :func:`fuse_predictions` (seeded by ``seed`` and
    ``split``), causal filter only: the figure draws the filter, and the joint grid is the cost.
    Returns the summary (``seq_*`` keys; ``seq{s}x_*`` for the stress run) and the table of
    :func:`fuse_volume` (``odometry`` "data", and "{s}x" without smoothed rows)."""
    settings = settings or FusionSettings()
    if marginals.log_volume is None:
        raise ValueError(
            f"split {split}: the joint fusion needs the whole volume "
            f"(volume_marginals(keep_volume=True)); got its marginals only"
        )
    grid = CircularGrid(settings.yaw_bins)
    aligned, own = _volume_frames(frame, marginals, grid, split)
    rows = poses.iloc[own["index"].to_numpy()].reset_index(drop=True)
    missing_cols = [c for c in ODOMETRY_COLUMNS if c not in rows.columns]
    if missing_cols:
        raise ValueError(f"split {split}: the pair table has no odometry columns {missing_cols}")
    yaw_beliefs, extent = volume_yaw_beliefs(aligned, grid), footprints(rows, sat_table)
    position_belief = partial(volume_position_beliefs, aligned)
    runs = _odometry_runs(rows, noise, stress_scale, seed, split)
    volume = aligned.log_volume
    assert volume is not None  # kept (checked above), reordered with the rest

    def joint_belief(flight_rows: np.ndarray, plane: Any) -> JointBelief:
        return volume_joint_belief(
            volume[torch.as_tensor(flight_rows)], aligned.yaw, aligned.north, aligned.east,
            aligned.cell_m, plane,
        )  # fmt: skip

    n_flights = len(np.unique(rows["flight"].to_numpy()))
    bar = Progress(n_flights * len(runs), f"joint fusion {split}", unit="flight",
                   enabled=progress)  # fmt: skip
    tables, summary = [], {}
    for name, odometry, told in runs:
        frames = _frames(own, rows, yaw_beliefs, odometry, extent, None, position_belief)
        table = fuse_split_joint(frames, joint_belief, told, settings, smooth=name == "data",
                                 progress=lambda done, total: bar.update(1))  # fmt: skip
        table.insert(0, "odometry", name)
        tables.append(table)
        summary.update(_run_summary(table, name))
    bar.close()
    return summary, pd.concat(tables, ignore_index=True)


def gives_position_density(head: torch.nn.Module) -> bool:
    """Whether a translation head gives its own horizontal density (``position_log_prob``)."""
    return callable(getattr(head, "position_log_prob", None))


@torch.no_grad()
def head_position_belief(
    model: torch.nn.Module,
    dataset: Dataset,
    frame: pd.DataFrame,
    *,
    batch_size: int = 64,
    shared_satellite: bool = True,
    precision: str = "fp32",
    num_workers: int = 0,
) -> PositionBeliefFn:
    """The translation head's own position belief (``position_log_prob``) of the frames of
    ``frame`` (rows matched on ``index``), for :func:`fuse_predictions`: one pass of the model's
    heads over ``dataset`` (a frozen encoder's cached features cost no encoder pass) keeps the
    head's raw output of every frame; the belief function evaluates its density at the grid's
    cell centres."""
    head = model.translation_head
    if not gives_position_density(head):
        raise ValueError(f"{type(head).__name__} gives no position_log_prob")
    index, raws = [], []
    passes = model_outputs(
        model, dataset, batch_size=batch_size, shared_satellite=shared_satellite,
        precision=precision, num_workers=num_workers, desc="position",
    )  # fmt: skip
    for batch, out in passes:
        index.append(batch["index"].cpu())
        raws.append(_to_cpu64(out.translation))
    row_of = {int(i): k for k, i in enumerate(torch.cat(index).tolist())}
    order = torch.as_tensor([row_of[int(i)] for i in frame["index"]], dtype=torch.long)
    raw = take_raw(_cat_raw(raws), order)
    return partial(_head_position, head=head, raw=raw)


def _head_position(rows: torch.Tensor, grid: Any, head: torch.nn.Module, raw: Any) -> torch.Tensor:
    """``(M, n_east, n_north)``: the head's density at the grid's cell centres for the frames
    ``rows`` (padding, -1: frame 0's), evaluated in float64 (the raw outputs are)."""
    east, north = grid.centres(torch.float64)
    cells = torch.stack(torch.meshgrid(east, north, indexing="ij"), -1).reshape(-1, 2)
    part = take_raw(raw, rows.clamp_min(0))
    log_p = head.position_log_prob(part, cells[None].expand(len(rows), -1, -1))
    return log_p.to(torch.float64).reshape(len(rows), *grid.shape)


def _to_cpu64(raw: Any) -> Any:
    if isinstance(raw, torch.Tensor):
        return raw.detach().to("cpu", torch.float64)
    return {k: _to_cpu64(v) for k, v in raw.items()}


def _cat_raw(parts: list[Any]) -> Any:
    if isinstance(parts[0], torch.Tensor):
        return torch.cat(parts)
    return {k: _cat_raw([p[k] for p in parts]) for k in parts[0]}
