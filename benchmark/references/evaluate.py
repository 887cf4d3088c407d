"""Evaluate a reference like a model: per-frame predictions and the same summary.

:func:`evaluate_reference` runs a :class:`~benchmark.references.base.Reference` over every pair of
a ``PairDataset`` (the true satellite image, or another place's with ``satellite="swap"``: the
reference then still gets the pair's own satellite geometry and given true values, only the pixels
are another place's, exactly as a model keeps its labels in the swap probe) and returns
``(summary, frame)`` with the columns and metrics of ``benchmark.evaluation.evaluate.evaluate``
(``predictions_frame`` / ``summarize``), plus:

- frame columns ``reference_failed`` (bool) and ``reference_score`` (the method's own score);
- summary keys ``failure_rate`` (fraction of failed frames), ``pos_err_m`` / ``median_pos_err_m``
  (3D position error ``|T_hat - T|``, metres), ``acc_5m_5deg``, ``acc_10m_10deg``,
  ``acc_25m_25deg`` (fraction of frames within both the position error and the geodesic attitude
  error dphi: OrthoLoC's (metres, degrees) thresholds) and ``frames_per_s``.

**Failure rule.** A frame whose estimate is marked failed (too few ground pixels, template cells
or PnP inliers: each reference states its own test) is given the *fallback* pose instead: the
constant predictor's pose (the chordal mean rotation and mean translation of the training split,
``benchmark.evaluation.reference``), exactly what the constant row predicts, and counted in
``failure_rate``.

**What a reference sees.** Each frame is built for the reference (:func:`iter_frames` with its
``given_columns``): the images, the pair's satellite geo-reference, the UAV camera and the true
values of those columns alone (``benchmark.references.base``); the rest of the pair row (the
other true pose values, the labels, the flight and illumination) never reaches it.

Labels: a reference's UAV attitude ``R_b^n`` becomes ``R_uav^sat = R_b^n (R_sat^n)^T`` (Eq. 2)
with the satellite camera ``SAT_R_N``; its position becomes ``T = position - sat capture point``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Collection, Iterator
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from benchmark.data import PairDataset
from benchmark.evaluation.evaluate import pair_columns
from benchmark.evaluation.metrics import predictions_frame, summarize, write_predictions_csv
from benchmark.evaluation.reference import dataset_labels, mean_rotation
from benchmark.geometry import SAT_R_N
from benchmark.progress import Progress
from benchmark.references.base import Frame, Reference, TrueValues
from benchmark.references.ground import SatelliteGrid
from benchmark.sim import Camera

__all__ = [
    "POSE_THRESHOLDS",
    "default_train_split",
    "evaluate_reference",
    "fallback_pose",
    "iter_frames",
]

# OrthoLoC's joint (metres, degrees) accuracy thresholds.
POSE_THRESHOLDS: tuple[tuple[float, float], ...] = ((5.0, 5.0), (10.0, 10.0), (25.0, 25.0))


def default_train_split(split: str, available: list[str] | None = None) -> str:
    """The training split whose mean pose is the fallback for ``split`` (the split the rows
    evaluated on it train on): ``towns/*`` -> ``towns/train``, ``frames/*`` -> ``frames/train``,
    ``height<h>/test`` -> ``height<h>/train``, anything else -> ``standard/train``."""
    family, _, _ = split.partition("/")
    if family in ("towns", "frames") or family.startswith("height"):
        candidate = f"{family}/train"
    else:
        candidate = "standard/train"
    if available is not None and candidate not in available:
        return "standard/train"
    return candidate


def fallback_pose(train_set: PairDataset) -> tuple[np.ndarray, np.ndarray]:
    """The constant predictor's pose from ``train_set``'s labels: ``(R_uav^sat (3, 3), T (3,))``
    float64 (chordal mean rotation, mean translation)."""
    R, T, _ = dataset_labels(train_set)
    return mean_rotation(R).numpy(), T.mean(0).numpy()


def _camera(dataset: PairDataset) -> Camera:
    size = int(dataset.manifest["image_size"])
    fov = float(dataset.manifest.get("profile", {}).get("fov_deg", 60.0))
    return Camera.square(size, fov)


def iter_frames(
    dataset: PairDataset, rows: list[int] | None = None, *, given_columns: Collection[str]
) -> Iterator[tuple[int, Frame]]:
    """``(item index, Frame)`` for the items ``rows`` (default all) of ``dataset``, in order, each
    holding the true values of ``given_columns`` (a reference's ``given_columns``, of
    ``TRUE_POSE_COLUMNS``: anything else raises ValueError) and no other.

    The grid is the pair's own satellite geometry (centre ``sat_E, sat_N``, ground
    ``sat_U - sat_height_m``, footprint of the true image); the pixels are the image served; the
    camera is the manifest's (image size, field of view).
    """
    if not isinstance(dataset, PairDataset):
        raise TypeError(
            f"references evaluate a benchmark.data.PairDataset, got {type(dataset).__name__}"
        )
    camera = _camera(dataset)
    sat = dataset.sat_table
    if not np.array_equal(sat["sat_index"].to_numpy(), np.arange(len(sat))):
        raise ValueError(f"{dataset.root}: sat.parquet's sat_index is not its row number")
    fe = sat["footprint_E_m"].to_numpy(np.float64)
    fn = sat["footprint_N_m"].to_numpy(np.float64)
    poses = dataset.poses
    cols = {
        c: poses[c].to_numpy() for c in ("sat_index", "sat_E", "sat_N", "sat_U", "sat_height_m")
    }
    TrueValues(dict.fromkeys(given_columns, 0.0))  # ValueError for a column that is not a pose's
    truth = {c: poses[c].to_numpy(np.float64) for c in given_columns}
    size = int(dataset.sat_images.shape[1])
    for i in range(len(poses)) if rows is None else rows:
        s_true = int(cols["sat_index"][i])
        grid = SatelliteGrid(
            centre_en=(float(cols["sat_E"][i]), float(cols["sat_N"][i])),
            ground_u=float(cols["sat_U"][i]) - float(cols["sat_height_m"][i]),
            footprint_m=(float(fe[s_true]), float(fn[s_true])),
            size=size,
        )
        yield (
            i,
            Frame(
                uav=np.asarray(dataset.uav_image(i)),
                sat=dataset.sat_images[int(dataset.served_sat_index[i])],
                grid=grid,
                camera=camera,
                truth=TrueValues({c: float(v[i]) for c, v in truth.items()}),
            ),
        )


def evaluate_reference(
    reference: Reference,
    dataset: PairDataset,
    *,
    fallback: tuple[np.ndarray, np.ndarray] | None = None,
    out_csv: str | Path | None = None,
    rows: list[int] | None = None,
    progress: bool = False,
    desc: str = "reference",
) -> tuple[dict[str, float], pd.DataFrame]:
    """Run ``reference`` over ``dataset`` (items ``rows``, default all) -> ``(summary, frame)``.

    ``fallback``: ``(R_uav^sat (3, 3), T (3,))`` given to failed frames (:func:`fallback_pose` of
    the training split); None: a failed frame keeps the reference's own estimate (it is still
    counted in ``failure_rate``). Writes the per-frame CSV to ``out_csv`` if given.
    """
    rows_list = list(range(len(dataset))) if rows is None else [int(r) for r in rows]
    if not rows_list:
        raise ValueError("evaluate_reference: no frames to evaluate")
    R_sat_n = SAT_R_N.double().numpy()
    n = len(rows_list)
    R_hat = np.empty((n, 3, 3))
    T_hat = np.empty((n, 3))
    failed = np.zeros(n, bool)
    scores = np.full(n, math.nan)
    sat_u = dataset.poses["sat_U"].to_numpy(np.float64)
    start, cpu_start = time.perf_counter(), time.process_time()
    with Progress(n, desc, unit="pair", enabled=progress) as bar:
        frames = iter_frames(dataset, rows_list, given_columns=reference.given_columns)
        for k, (i, frame) in enumerate(frames):
            est = reference.estimate(frame)
            sat_pos = np.array([*frame.grid.centre_en, sat_u[i]])  # the capture point
            R_hat[k] = est.R_bn @ R_sat_n.T  # R_uav^sat = R_uav^n (R_sat^n)^T, Eq. 2
            T_hat[k] = est.position - sat_pos
            failed[k] = bool(est.failed)
            scores[k] = est.score
            if est.failed and fallback is not None:
                R_hat[k], T_hat[k] = fallback
            bar.update(1)
    elapsed = time.perf_counter() - start
    cpu = time.process_time() - cpu_start
    R_gt, T_gt, index = dataset_labels(dataset)
    sel = torch.as_tensor(rows_list, dtype=torch.int64)
    extra = {k: [v[r] for r in rows_list] for k, v in pair_columns(dataset).items()}
    extra["reference_failed"] = failed.tolist()
    extra["reference_score"] = scores.tolist()
    frame_df = predictions_frame(
        torch.from_numpy(R_hat),
        R_gt[sel],
        torch.from_numpy(T_hat),
        T_gt[sel],
        index=index[sel],
        extra=extra,
    )
    if out_csv is not None:
        write_predictions_csv(frame_df, out_csv)
    summary = reference_summary(frame_df, elapsed)
    summary["cpu_ms_per_frame"] = 1000.0 * cpu / n
    return summary, frame_df


def reference_summary(frame: pd.DataFrame, elapsed_s: float | None = None) -> dict[str, float]:
    """:func:`~benchmark.evaluation.metrics.summarize` plus the failure rate, the 3D position
    error and the (metres, degrees) accuracies of the module docstring."""
    out = summarize(frame)
    d = frame[["dE_m", "dN_m", "dU_m"]].to_numpy(np.float64)
    pos = np.sqrt((d * d).sum(axis=1))
    dphi = frame["dphi_deg"].to_numpy(np.float64)
    out["pos_err_m"] = float(pos.mean())
    out["median_pos_err_m"] = float(np.median(pos))
    for m, deg in POSE_THRESHOLDS:
        out[f"acc_{m:g}m_{deg:g}deg"] = float(((pos <= m) & (dphi <= deg)).mean())
    if "reference_failed" in frame:
        out["failure_rate"] = float(frame["reference_failed"].astype(bool).mean())
    if elapsed_s is not None and elapsed_s > 0:
        out["frames_per_s"] = len(frame) / elapsed_s
    return out
