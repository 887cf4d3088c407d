"""Intervals of the report's table cells over training seeds and test flights.

A cell is a statistic of one model's per-frame errors on one split (the mean error, or the median,
an accuracy, a log-likelihood, a rank correlation: :data:`CELL_METRICS`), averaged over its
training seeds. Two things
make it uncertain: which seed trained the model, and which flights happen to be in the test split
(frames of a flight are strongly correlated, so the flights, not the frames, are the independent
units). :func:`seed_flight_bootstrap` resamples both: each replicate draws the seeds with
replacement and the flights with replacement, and recomputes the mean over the drawn seeds of the
frame-weighted mean over the drawn flights' frames. Every seed is evaluated on the same frames,
so a replicate draws the flights once and applies them to every drawn seed (the seeds share the
test set; drawing flights per seed would pretend they do not). Medians and rank correlations are
resampled the same way (``benchmark.evaluation.paired.median_bootstrap``, ``spearman_bootstrap``):
the same draws, the statistic recomputed on each replicate's multiset of frames.

:func:`cell_interval` finds a table row's per-frame errors: the predictions CSVs the runner wrote
(``<workdir>/units/<unit>/eval/<split>.csv``, one per seed) or, for the constant predictor (no
seed), its own per-frame table. Without them the caller keeps the Student-t interval over seeds.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd

from benchmark.evaluation.metrics import ACCURACY_THRESHOLDS_DEG
from benchmark.evaluation.paired import median_bootstrap, pooled_bootstrap, spearman_bootstrap
from benchmark.runner.execute.worker import eval_key, split_filename

# Per-frame error columns of a predictions CSV whose mean is a table cell.
FRAME_METRICS = ("dE_m", "dN_m", "dU_m", "dtheta_deg", "dgamma_deg", "dpsi_deg", "dphi_deg")
# Cells that are another statistic of per-frame columns, as ``benchmark.evaluation.metrics.
# summarize`` computes them per seed. Medians: metric -> the columns it reads (two: the
# horizontal distance hypot(δE, δN)).
MEDIANS = {"median_dpsi_deg": ("dpsi_deg",), "median_dphi_deg": ("dphi_deg",),
           "median_horizontal_m": ("dE_m", "dN_m")}  # fmt: skip
ACCURACIES = {f"acc{t:g}": t for t in ACCURACY_THRESHOLDS_DEG}  # fraction of frames δφ <= t
OPTIONAL = {"loglik": ("log_likelihood",), "spearman_unc_err": ("uncertainty", "dphi_deg")}
CELL_METRICS = (*FRAME_METRICS, *MEDIANS, *ACCURACIES, *OPTIONAL)
N_BOOT = 2000
FLIGHT_BOOT, SEED_T = "flight×seed bootstrap", "seed t"


def frame_columns(metrics: list[str] | tuple[str, ...]) -> tuple[str, ...]:
    """The per-frame columns the cells ``metrics`` are computed from (in first-use order)."""
    columns: list[str] = []
    for m in metrics:
        if m in FRAME_METRICS:
            columns.append(m)
        elif m in MEDIANS:
            columns += MEDIANS[m]
        elif m in ACCURACIES:
            columns.append("dphi_deg")
        elif m in OPTIONAL:
            columns += OPTIONAL[m]
    return tuple(dict.fromkeys(columns))


def seed_flight_bootstrap(
    errors: np.ndarray,
    groups: np.ndarray,
    n_boot: int = N_BOOT,
    seed: int = 0,
    confidence: float = 0.95,
) -> tuple[float, float, float]:
    """Mean over seeds of the per-seed mean error, and its percentile bootstrap interval.

    Args:
        errors: ``(S, N)`` per-frame errors of S seeds on the same N frames (any unit), or ``(N,)``
            for one seed.
        groups: ``(N,)`` flight of each frame; the G distinct flights are resampled (G draws with
            replacement per replicate), and so are the S seeds (S draws).
        n_boot: replicates (>= 1); seed: of ``numpy.random.default_rng`` (same inputs, same bytes).
        confidence: two-sided coverage in (0, 1).
    The resampling is ``benchmark.evaluation.paired.pooled_bootstrap`` of ``errors`` against
    zero errors.
    Returns:
        ``(mean, lo, hi)``; ``lo``/``hi`` are NaN when there is nothing to resample (one seed and
        one flight). The mean equals ``errors.mean()`` (every seed has the same N frames).
    """
    e = np.asarray(errors, dtype=np.float64)
    e = e[None, :] if e.ndim == 1 else e
    g = np.asarray(groups).reshape(-1)
    if e.ndim != 2 or e.shape[1] != g.shape[0] or e.size == 0:
        raise ValueError(
            f"seed_flight_bootstrap: errors must be (S, N) with N = len(groups) = {g.shape[0]} "
            f"and S, N >= 1, got shape {np.shape(errors)}"
        )
    if not np.isfinite(e).all():
        raise ValueError("seed_flight_bootstrap: errors must be finite")
    if e.shape[0] == 1 and len(np.unique(g)) == 1:
        return float(e.mean()), math.nan, math.nan
    # The claims' paired bootstrap against an all-zero "model": the same resampling (flights,
    # then seeds) and the same random draws, so a cell and a claim built on it agree.
    return pooled_bootstrap(
        np.zeros((1, e.shape[1])), e, g, n_boot=n_boot, seed=seed, confidence=confidence
    )


def read_frames(paths: list[Path], metrics: tuple[str, ...] = FRAME_METRICS) -> pd.DataFrame:
    """Stack per-seed predictions CSVs of one split: columns ``seed_pos`` (0..S-1), ``index``,
    ``flight`` and the columns of the cells ``metrics`` (:func:`frame_columns`; ``log_likelihood``
    and ``uncertainty`` only where a head writes them). Raises ``ValueError`` when the files do not
    hold the same frames (same ``index`` values and flights), which a paired average over seeds
    needs."""
    wanted = {"index", "flight", *frame_columns(metrics)}
    frames, reference = [], None
    for pos, path in enumerate(paths):
        frame = pd.read_csv(path, usecols=lambda c: c in wanted).sort_values("index")
        frame = frame.reset_index(drop=True)
        if reference is None:
            reference = frame[["index", "flight"]]
        elif not frame[["index", "flight"]].equals(reference):
            raise ValueError(f"{path}: other frames than {paths[0]} (index or flight differ)")
        frames.append(frame.assign(seed_pos=pos))
    return pd.concat(frames, ignore_index=True)


def frame_interval(frames: pd.DataFrame, metrics: list[str]) -> dict[str, float | str]:
    """``<m>_lo``, ``<m>_hi`` of the flight (and seed) bootstrap for each cell metric whose columns
    are present, plus ``interval`` (its name) and ``n_flights``, from a :func:`read_frames`-like
    table: :func:`seed_flight_bootstrap` for means (errors, accuracies as the mean of the indicator
    δφ <= t, the log-likelihood), ``median_bootstrap`` for medians, ``spearman_bootstrap`` for
    ρ(uncertainty, δφ) (no bounds when a replicate's correlation is undefined). Every statistic
    uses the same flight and seed draws (generator seed 0)."""
    pos = frames["seed_pos"] if "seed_pos" in frames else pd.Series(0, index=frames.index)
    first = frames[pos == pos.iloc[0]]
    groups = first["flight"].to_numpy()
    out: dict[str, float | str] = {
        "interval": FLIGHT_BOOT, "n_flights": float(len(np.unique(groups)))
    }  # fmt: skip
    seeds = sorted(pos.unique())

    def per_seed(column: str) -> np.ndarray:  # (S, N)
        return np.stack([frames.loc[pos == p, column].to_numpy(np.float64) for p in seeds])

    one_of_one = len(seeds) == 1 and len(np.unique(groups)) == 1
    for m in metrics:
        if not all(c in frames for c in frame_columns([m])):
            continue
        if m in FRAME_METRICS or m == "loglik":
            values = per_seed(m if m in FRAME_METRICS else "log_likelihood")
            _, lo, hi = seed_flight_bootstrap(values, groups)
        elif m in ACCURACIES:
            _, lo, hi = seed_flight_bootstrap(per_seed("dphi_deg") <= ACCURACIES[m], groups)
        elif m in MEDIANS:
            columns = [per_seed(c) for c in MEDIANS[m]]
            values = columns[0] if len(columns) == 1 else np.hypot(*columns)
            _, lo, hi = median_bootstrap(values, groups, n_boot=N_BOOT)
        elif m == "spearman_unc_err":
            unc, err = per_seed("uncertainty"), per_seed("dphi_deg")
            _, lo, hi = spearman_bootstrap(unc, err, groups, n_boot=N_BOOT)
        else:
            continue
        # Nothing to resample (one seed, one flight): no interval, as for the means.
        out[f"{m}_lo"], out[f"{m}_hi"] = (math.nan, math.nan) if one_of_one else (lo, hi)
    return out


def prediction_paths(part: pd.DataFrame, workdir: Path) -> list[Path] | None:
    """The predictions CSVs of a table row's seeds (``part``: its results rows, one per seed,
    with ``unit``, ``split``, ``satellite``), or None when a row has no unit or a file is absent."""
    if "unit" not in part or part["unit"].isna().any():
        return None
    paths = []
    for r in part.itertuples():
        name = split_filename(eval_key(str(r.split), str(r.satellite))) + ".csv"
        path = Path(workdir) / "units" / str(r.unit) / "eval" / name
        if not path.is_file():
            return None
        paths.append(path)
    return paths


def cell_interval(
    part: pd.DataFrame,
    metrics: list[str],
    workdir: Path | None,
    constant_frames: Mapping[tuple[str, str], pd.DataFrame] | None = None,
) -> dict[str, float | str] | None:
    """Flight (and seed) bootstrap bounds for one table row, or None (keep the seed interval).

    ``part`` are the row's results (one per seed). Trained rows read their predictions CSVs from
    ``workdir``; constant-predictor rows (``satellite_input == "none"``) use
    ``constant_frames[(train_split, split)]`` (a predictions table with a ``flight`` column)."""
    wanted = [m for m in metrics if m in CELL_METRICS]
    if not wanted or part.empty:
        return None
    first = part.iloc[0]
    if first.get("satellite_input") == "none":
        frame = (constant_frames or {}).get((str(first["train_split"]), str(first["split"])))
        if frame is None or "flight" not in frame:
            return None
        return frame_interval(frame, wanted)
    if workdir is None:
        return None
    paths = prediction_paths(part, workdir)
    if paths is None:
        return None
    return frame_interval(read_frames(paths, tuple(wanted)), wanted)
