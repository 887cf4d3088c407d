"""The paper's pose metrics (Sec. 3.2), summaries and intervals over seeds. Pure functions.

Frames. Models predict the relative attitude ``R_uav^sat = R_uav^n (R_sat^n)^T`` (Eq. 2). The
paper's attitude errors dtheta, dgamma, dpsi are errors of the UAV's own pitch, roll and yaw, so we
map both prediction and label back to the UAV attitude, ``R_uav^n = R_uav^sat R_sat^n`` with the
known satellite camera ``R_sat^n = SAT_R_N`` (pitch -90 deg, heading 0, Eq. 5), decompose each with
``rotmat_to_euler`` (``R = Rz(yaw) Rx(pitch) Ry(roll)``, Eq. 1) and compare the angles. Euler
angles of the *relative* rotation would not be the UAV's pitch/roll/yaw: with the satellite looking
straight down, the relative rotation's "pitch" is the UAV pitch + 90 deg, far from the
well-conditioned range, and its yaw/roll mix the UAV's heading and roll.

Wrapping. Each Euler difference is wrapped to (-180, 180] deg (a 359 deg heading error is a 1 deg
error). The paper's Table 2 lists dgamma = 253.81 deg, impossible for wrapped differences, so the
paper did not wrap; the ``*_nowrap`` columns give the unwrapped ``|a_hat - a|`` for comparison.
Pitch lies in [-90, 90] deg, so its difference never wraps.

Geodesic error dphi (Eq. 16): the rotation angle of ``R_hat R^T``; it is the same for relative
and absolute attitudes, since right-multiplying both by ``R_sat^n`` cancels in ``R_hat R^T``.

Units: radians and metres inside; the per-sample table and the summaries are the report edge and
are in degrees (``*_deg``) and metres (``*_m``).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import torch
from torch import Tensor

from benchmark.geometry import SAT_R_N, angle_difference, geodesic_distance, rotmat_to_euler

ACCURACY_THRESHOLDS_DEG = (5.0, 10.0, 30.0)
# Per-sample error columns and the paper's names for them; summaries average their absolute value.
ERROR_COLUMNS = (
    "dE_m",
    "dN_m",
    "dU_m",
    "dtheta_deg",  # pitch
    "dgamma_deg",  # roll
    "dpsi_deg",  # yaw
    "dphi_deg",  # geodesic, Eq. 16
    "dtheta_nowrap_deg",
    "dgamma_nowrap_deg",
    "dpsi_nowrap_deg",
)


def relative_to_uav_attitude(R_uav_sat: Tensor) -> Tensor:
    """``R_uav^n = R_uav^sat R_sat^n`` (inverse of Eq. 2). ``(..., 3, 3) -> (..., 3, 3)``."""
    return R_uav_sat @ SAT_R_N.to(dtype=R_uav_sat.dtype, device=R_uav_sat.device)


@dataclass(frozen=True)
class PoseErrors:
    """Per-sample errors, each ``(N,)`` float64. Radians and metres.

    ``d_*`` are signed, estimate minus truth: ``d_yaw, d_pitch, d_roll`` wrapped to (-pi, pi],
    ``d_*_nowrap`` plain differences in (-2 pi, 2 pi); ``geodesic`` in [0, pi];
    ``d_translation (N, 3)`` is ``T_hat - T`` in metres, columns E, N, U.
    """

    d_yaw: Tensor
    d_pitch: Tensor
    d_roll: Tensor
    d_yaw_nowrap: Tensor
    d_pitch_nowrap: Tensor
    d_roll_nowrap: Tensor
    geodesic: Tensor
    d_translation: Tensor


def _check_batch(x: Tensor, name: str, tail: tuple[int, ...]) -> Tensor:
    if not isinstance(x, Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(x).__name__}")
    if x.dim() != 1 + len(tail) or tuple(x.shape[1:]) != tail:
        raise ValueError(
            f"{name} must have shape (N, {', '.join(map(str, tail))}), got {tuple(x.shape)}"
        )
    if not bool(torch.isfinite(x).all()):
        raise ValueError(f"{name} contains non-finite values")
    return x.detach().to(torch.float64)


def pose_errors(R_hat: Tensor, R_gt: Tensor, T_hat: Tensor, T_gt: Tensor) -> PoseErrors:
    """Errors of predicted relative poses.

    Args:
        R_hat, R_gt: ``(N, 3, 3)`` relative attitudes ``R_uav^sat`` (Eq. 2), predicted and true.
        T_hat, T_gt: ``(N, 3)`` translations ``[dE, dN, dU]`` in metres.
    Returns:
        :class:`PoseErrors`, computed in float64.
    """
    R_hat = _check_batch(R_hat, "R_hat", (3, 3))
    R_gt = _check_batch(R_gt, "R_gt", (3, 3))
    T_hat = _check_batch(T_hat, "T_hat", (3,))
    T_gt = _check_batch(T_gt, "T_gt", (3,))
    n = {R_hat.shape[0], R_gt.shape[0], T_hat.shape[0], T_gt.shape[0]}
    if len(n) != 1:
        raise ValueError(f"R_hat, R_gt, T_hat, T_gt must have the same N, got {sorted(n)}")
    yaw_h, pitch_h, roll_h = rotmat_to_euler(relative_to_uav_attitude(R_hat))
    yaw_g, pitch_g, roll_g = rotmat_to_euler(relative_to_uav_attitude(R_gt))
    return PoseErrors(
        d_yaw=angle_difference(yaw_h, yaw_g),
        d_pitch=angle_difference(pitch_h, pitch_g),
        d_roll=angle_difference(roll_h, roll_g),
        d_yaw_nowrap=yaw_h - yaw_g,
        d_pitch_nowrap=pitch_h - pitch_g,
        d_roll_nowrap=roll_h - roll_g,
        geodesic=geodesic_distance(R_hat, R_gt),
        d_translation=T_hat - T_gt,
    )


def predictions_frame(
    R_hat: Tensor,
    R_gt: Tensor,
    T_hat: Tensor,
    T_gt: Tensor,
    *,
    index: Sequence[int] | Tensor | None = None,
    log_likelihood: Tensor | None = None,
    uncertainty: Tensor | None = None,
    extra: Mapping[str, Sequence | Tensor] | None = None,
) -> pd.DataFrame:
    """One row per sample: truth, estimate and absolute errors (the paper's columns, in degrees and
    metres), the predicted relative rotation ``R_hat`` row-major (``Rhat00..Rhat22``, so any other
    metric can be recomputed), and optional ``log_likelihood``, ``uncertainty`` and ``extra``
    columns (e.g. ``city``, ``pitch_bin``)."""
    err = pose_errors(R_hat, R_gt, T_hat, T_gt)
    n = err.geodesic.shape[0]
    deg = 180.0 / math.pi
    yaw_h, pitch_h, roll_h = rotmat_to_euler(relative_to_uav_attitude(R_hat.detach().double()))
    yaw_g, pitch_g, roll_g = rotmat_to_euler(relative_to_uav_attitude(R_gt.detach().double()))
    cols: dict[str, np.ndarray] = {
        "index": np.arange(n) if index is None else np.asarray(torch.as_tensor(index)).reshape(-1)
    }
    for name, hat, gt in (
        ("yaw", yaw_h, yaw_g),
        ("pitch", pitch_h, pitch_g),
        ("roll", roll_h, roll_g),
    ):
        cols[f"{name}_deg"] = (gt * deg).numpy()
        cols[f"{name}_hat_deg"] = (hat * deg).numpy()
    T_hat64, T_gt64 = T_hat.detach().double(), T_gt.detach().double()
    for j, axis in enumerate("ENU"):
        cols[f"{axis}_m"] = T_gt64[:, j].numpy()
        cols[f"{axis}_hat_m"] = T_hat64[:, j].numpy()
        cols[f"d{axis}_m"] = err.d_translation[:, j].abs().numpy()
    cols["dtheta_deg"] = (err.d_pitch.abs() * deg).numpy()
    cols["dgamma_deg"] = (err.d_roll.abs() * deg).numpy()
    cols["dpsi_deg"] = (err.d_yaw.abs() * deg).numpy()
    cols["dphi_deg"] = (err.geodesic * deg).numpy()
    cols["dtheta_nowrap_deg"] = (err.d_pitch_nowrap.abs() * deg).numpy()
    cols["dgamma_nowrap_deg"] = (err.d_roll_nowrap.abs() * deg).numpy()
    cols["dpsi_nowrap_deg"] = (err.d_yaw_nowrap.abs() * deg).numpy()
    R64 = R_hat.detach().double().reshape(n, 9).numpy()
    for k in range(9):
        cols[f"Rhat{k // 3}{k % 3}"] = R64[:, k]
    for name, values in (("log_likelihood", log_likelihood), ("uncertainty", uncertainty)):
        if values is not None:
            cols[name] = _column(values, name, n)
    for name, values in (extra or {}).items():
        cols[name] = _column(values, name, n, numeric=False)
    for name, values in cols.items():
        if len(values) != n:
            raise ValueError(f"column {name!r} has {len(values)} rows, expected {n}")
    return pd.DataFrame(cols)


def _column(values: Sequence | Tensor, name: str, n: int, numeric: bool = True) -> np.ndarray:
    arr = (
        values.detach().cpu().double().numpy() if isinstance(values, Tensor) else np.asarray(values)
    )
    arr = arr.reshape(-1) if arr.ndim > 1 and arr.size == n else arr
    if arr.shape != (n,):
        raise ValueError(f"{name} must have {n} entries, got shape {arr.shape}")
    return arr.astype(np.float64) if numeric else arr


def write_predictions_csv(frame: pd.DataFrame, path: str | Path) -> Path:
    """Write :func:`predictions_frame` output; floats with 10 significant digits, byte-stable."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    frame.to_csv(path, index=False, float_format="%.10g", lineterminator="\n")
    return path


def spearman(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Spearman rank correlation and its p-value (``scipy.stats.spearmanr``); NaN when undefined
    (fewer than 3 samples or a constant input)."""
    from scipy import stats

    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    if x.size < 3 or np.ptp(x) == 0 or np.ptp(y) == 0:
        return math.nan, math.nan
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = stats.spearmanr(x, y)
    return float(res.statistic), float(res.pvalue)


def horizontal_metrics(frame: pd.DataFrame) -> dict[str, float]:
    """Mean and median horizontal position error ``hypot(δE, δN)`` in metres over the frames of
    a :func:`predictions_frame` (``dE_m``, ``dN_m``: per-frame absolute errors).

    The per-axis means of the paper's tables hide how far a frame's position is off; the median
    horizontal distance is what localisation work (OrthoLoC, OrienterNet) reports."""
    horizontal = np.hypot(frame["dE_m"].to_numpy(np.float64), frame["dN_m"].to_numpy(np.float64))
    return {"horizontal_m": float(horizontal.mean()),
            "median_horizontal_m": float(np.median(horizontal))}  # fmt: skip


def summarize(frame: pd.DataFrame) -> dict[str, float]:
    """Scalar metrics of a :func:`predictions_frame`, named as the runner's reports name them:

    - ``<col>`` for every error column: the MEAN absolute error (the paper's numbers, e.g.
      ``dpsi_deg``), and ``median_<col>``;
    - ``horizontal_m`` and ``median_horizontal_m``: :func:`horizontal_metrics`;
    - ``acc5``, ``acc10``, ``acc30``: fraction of samples with dphi <= 5, 10, 30 deg;
    - ``n``: number of samples;
    - with a ``log_likelihood`` column, ``loglik`` (its mean); with an ``uncertainty`` column,
      ``spearman_unc_err`` (Spearman rho between uncertainty and dphi; positive when higher
      uncertainty goes with larger error, i.e. the uncertainty is meaningful) and its
      ``spearman_unc_err_pvalue``.
    """
    if len(frame) == 0:
        raise ValueError("cannot summarize an empty predictions table")
    out: dict[str, float] = {"n": float(len(frame))}
    for col in ERROR_COLUMNS:
        values = frame[col].to_numpy(dtype=np.float64)
        out[col] = float(values.mean())
        out[f"median_{col}"] = float(np.median(values))
    out.update(horizontal_metrics(frame))
    dphi = frame["dphi_deg"].to_numpy(dtype=np.float64)
    for t in ACCURACY_THRESHOLDS_DEG:
        out[f"acc{t:g}"] = float((dphi <= t).mean())
    if "log_likelihood" in frame:
        out["loglik"] = float(frame["log_likelihood"].mean())
    if "uncertainty" in frame:
        rho, p = spearman(frame["uncertainty"].to_numpy(), dphi)
        out["spearman_unc_err"] = rho
        out["spearman_unc_err_pvalue"] = p
    return out


@dataclass(frozen=True)
class SeedInterval:
    """Mean over seeds with a two-sided Student-t interval; ``low``/``high`` NaN for one seed."""

    mean: float
    low: float
    high: float
    n: int

    @property
    def half_width(self) -> float:
        return (self.high - self.low) / 2


def seed_interval(values: Sequence[float] | np.ndarray, confidence: float = 0.95) -> SeedInterval:
    """``mean +- t_{(1+c)/2, n-1} s / sqrt(n)`` over per-seed values (``s``: sample std, ddof 1).

    With one seed the mean is that value and the interval is NaN (no spread can be estimated).
    NaN inputs propagate.
    """
    from scipy import stats

    x = np.asarray(values, dtype=np.float64).reshape(-1)
    if x.size == 0:
        raise ValueError("seed_interval needs at least one value")
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    mean = float(x.mean())
    if x.size == 1:
        return SeedInterval(mean, math.nan, math.nan, 1)
    half = float(stats.t.ppf((1 + confidence) / 2, x.size - 1) * x.std(ddof=1) / math.sqrt(x.size))
    return SeedInterval(mean, mean - half, mean + half, int(x.size))
