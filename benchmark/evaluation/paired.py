"""Paired comparisons of two error columns on the same frames, with a flight (cluster) bootstrap.

Frames of one flight are strongly correlated (a 30 fps video sampled every half second), so an
interval that resamples frames as if independent is far too narrow. :func:`paired_bootstrap`
resamples whole groups (flights) with replacement and recomputes the frame-weighted mean of the
per-frame difference ``err_b - err_a``; the interval is the percentile interval of those means.

The satellite-swap probe (:func:`swap_effect`) uses it on the yaw and geodesic errors of a model
evaluated with the true and with a swapped satellite image: a model that uses the satellite image
gets worse when the image shows another place, so its difference is clearly above zero.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

# (error column of the predictions CSV, short name used in the metric names)
SWAP_ERRORS = (("dpsi_deg", "dpsi"), ("dphi_deg", "dphi"))


def paired_bootstrap(
    err_a: np.ndarray,
    err_b: np.ndarray,
    groups: np.ndarray,
    n_boot: int = 2000,
    seed: int = 0,
    confidence: float = 0.95,
) -> tuple[float, float, float]:
    """Mean of ``err_b - err_a`` and its percentile bootstrap interval over whole groups.

    Args:
        err_a, err_b: ``(N,)`` errors of the same N frames under conditions a and b (any unit).
        groups: ``(N,)`` group label of each frame (e.g. the flight id); groups are resampled with
            replacement, ``G`` draws of the ``G`` groups per replicate.
        n_boot: number of bootstrap replicates (>= 1).
        seed: seed of ``numpy.random.default_rng``: same inputs and seed, same interval.
        confidence: two-sided coverage of the interval, in (0, 1).
    Returns:
        ``(mean_diff, lo, hi)``: the frame-weighted mean of ``err_b - err_a`` over all frames and
        the ``(1 - confidence) / 2`` and ``(1 + confidence) / 2`` quantiles of the replicates'
        frame-weighted means (each replicate: the sum of its groups' differences over the sum of
        their frame counts, i.e. the plain mean over the concatenated frames of the drawn groups).
    """
    a = np.asarray(err_a, dtype=np.float64).reshape(-1)
    b = np.asarray(err_b, dtype=np.float64).reshape(-1)
    g = np.asarray(groups).reshape(-1)
    if not (a.shape == b.shape == g.shape):
        raise ValueError(
            f"paired_bootstrap: err_a, err_b and groups must have the same length, got "
            f"{a.shape[0]}, {b.shape[0]}, {g.shape[0]}"
        )
    if a.size == 0:
        raise ValueError("paired_bootstrap: no frames")
    if not (np.isfinite(a).all() and np.isfinite(b).all()):
        raise ValueError("paired_bootstrap: err_a and err_b must be finite")
    if int(n_boot) != n_boot or n_boot < 1:
        raise ValueError(f"paired_bootstrap: n_boot must be an integer >= 1, got {n_boot!r}")
    if not 0 < confidence < 1:
        raise ValueError(f"paired_bootstrap: confidence must be in (0, 1), got {confidence}")
    diff = b - a
    _, inverse = np.unique(g, return_inverse=True)
    n_groups = int(inverse.max()) + 1
    sums = np.bincount(inverse, weights=diff, minlength=n_groups)
    sizes = np.bincount(inverse, minlength=n_groups).astype(np.float64)
    rng = np.random.default_rng(seed)
    draws = rng.integers(0, n_groups, size=(int(n_boot), n_groups))
    # A replicate's mean over its concatenated frames = (sum of drawn group sums) / (frames drawn).
    means = sums[draws].sum(axis=1) / sizes[draws].sum(axis=1)
    tail = (1.0 - confidence) / 2.0
    lo, hi = np.quantile(means, [tail, 1.0 - tail])
    return float(diff.mean()), float(lo), float(hi)


def swap_effect(
    true_frame: pd.DataFrame,
    swap_frame: pd.DataFrame,
    group_column: str = "flight",
    n_boot: int = 2000,
    seed: int = 0,
) -> dict[str, float]:
    """How much worse a model gets with a swapped satellite image, per frame, by flight bootstrap.

    Args:
        true_frame, swap_frame: predictions tables (``benchmark.evaluation.metrics.
            predictions_frame``) of the same split with the true and the swapped satellite image;
            rows are matched on ``index``; ``group_column`` (the flight id) must be present.
    Returns:
        ``swap_<e>_diff_deg`` (mean of swapped minus true error), ``swap_<e>_boot_lo_deg`` and
        ``swap_<e>_boot_hi_deg`` (95% flight-bootstrap interval) for ``e`` in ``dpsi`` (yaw) and
        ``dphi`` (geodesic), and ``swap_groups`` (number of flights).
    """
    for name, frame in (("true_frame", true_frame), ("swap_frame", swap_frame)):
        missing = {"index", group_column, *(c for c, _ in SWAP_ERRORS)} - set(frame.columns)
        if missing:
            raise ValueError(f"swap_effect: {name} lacks columns {sorted(missing)}")
    a = true_frame.set_index("index").sort_index()
    b = swap_frame.set_index("index").sort_index()
    if not a.index.equals(b.index) or a.index.has_duplicates:
        raise ValueError("swap_effect: the two frames must hold the same unique 'index' values")
    if not np.array_equal(a[group_column].to_numpy(), b[group_column].to_numpy()):
        raise ValueError(f"swap_effect: column {group_column!r} differs between the two frames")
    groups = a[group_column].to_numpy()
    out: dict[str, float] = {"swap_groups": float(len(np.unique(groups)))}
    for column, short in SWAP_ERRORS:
        mean, lo, hi = paired_bootstrap(
            a[column].to_numpy(), b[column].to_numpy(), groups, n_boot=n_boot, seed=seed
        )
        out[f"swap_{short}_diff_deg"] = mean
        out[f"swap_{short}_boot_lo_deg"] = lo
        out[f"swap_{short}_boot_hi_deg"] = hi
    return out
