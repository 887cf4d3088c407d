"""Paired comparisons of two error columns on the same frames, with a flight (cluster) bootstrap.

Frames of one flight are strongly correlated (a 30 fps video sampled every half second), so an
interval that resamples frames as if independent is far too narrow. :func:`paired_bootstrap`
resamples whole groups (flights) with replacement and recomputes the frame-weighted mean of the
per-frame difference ``err_b - err_a``; the interval is the percentile interval of those means.

The satellite-swap probe (:func:`swap_effect`) uses it on the yaw and geodesic errors of a model
evaluated with the true and with a swapped satellite image: a model that uses the satellite image
gets worse when the image shows another place, so its difference is clearly above zero.

With several training seeds, :func:`pooled_bootstrap` resamples seeds as well as flights: a
replicate draws the flights with replacement and, independently for each model, its seeds with
replacement, and compares the two models' seed-mean errors on the drawn frames. The interval then
covers both the test-set sampling (which flights) and the training noise (which seed), the two
sources a rerun on another machine changes. When the two models' seed-s runs share what seed s
trained (heads on the same frozen encoder of seed s, or one model with and without a probe),
``paired_seeds=True`` draws one set of seeds for both, as the flights are drawn once for both:
what seed s's shared part does to both models cancels in the difference instead of entering the
interval twice. :func:`spearman_bootstrap` does the same for a rank
correlation (a head's uncertainty against its error), :func:`median_bootstrap` for a median (the
median horizontal error, the median yaw error).
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


def _as_seed_matrix(x: np.ndarray, name: str) -> np.ndarray:
    """``(N,)`` or ``(S, N)`` -> ``(S, N)`` float64, checked finite and non-empty."""
    m = np.asarray(x, dtype=np.float64)
    m = m[None, :] if m.ndim == 1 else m
    if m.ndim != 2 or m.shape[0] < 1 or m.shape[1] < 1:
        raise ValueError(f"{name} must have shape (N,) or (S, N) with S, N >= 1, got {m.shape}")
    if not np.isfinite(m).all():
        raise ValueError(f"{name} must be finite")
    return m


def _check_boot(n_boot: int, confidence: float, caller: str) -> None:
    if int(n_boot) != n_boot or n_boot < 1:
        raise ValueError(f"{caller}: n_boot must be an integer >= 1, got {n_boot!r}")
    if not 0 < confidence < 1:
        raise ValueError(f"{caller}: confidence must be in (0, 1), got {confidence}")


def pooled_replicates(
    err_a: np.ndarray,
    err_b: np.ndarray,
    groups: np.ndarray,
    n_boot: int = 2000,
    seed: int = 0,
    paired_seeds: bool = False,
) -> tuple[float, np.ndarray]:
    """The point estimate and the bootstrap replicates behind :func:`pooled_bootstrap`.

    Args:
        err_a, err_b: ``(S_a, N)`` and ``(S_b, N)`` errors of models a and b on the same N frames,
            one row per training seed (``(N,)`` = one seed; the seed counts may differ, e.g. the
            constant predictor has one).
        groups: ``(N,)`` flight id of each frame.
        n_boot: number of replicates (>= 1).
        seed: seed of ``numpy.random.default_rng``.
        paired_seeds: row s of ``err_a`` and of ``err_b`` come from one training seed's shared
            run (``S_a == S_b`` required): the seeds are drawn once per replicate for both models
            (the second generator call, ``integers(0, S, (n_boot, S))``), not independently.
    Returns:
        ``(mean_diff, replicates (n_boot,))``: ``mean_diff`` = mean over all frames of
        ``mean_s err_b[s] - mean_s err_a[s]``. Replicate r draws G of the G flights with
        replacement (first generator call, ``integers(0, G, (n_boot, G))``, the same draws as
        :func:`paired_bootstrap`), then ``S_a`` seeds of a and ``S_b`` seeds of b with replacement;
        its value is the mean over the drawn flights' frames of (mean over b's drawn seeds minus
        mean over a's drawn seeds). With one seed each it equals :func:`paired_bootstrap`; with
        ``paired_seeds`` it is :func:`paired_bootstrap`'s replicate of the per-seed differences
        ``err_b[s] - err_a[s]`` averaged over the drawn seeds.
    """
    a = _as_seed_matrix(err_a, "err_a")
    b = _as_seed_matrix(err_b, "err_b")
    g = np.asarray(groups).reshape(-1)
    if not a.shape[1] == b.shape[1] == g.shape[0]:
        raise ValueError(
            f"pooled_bootstrap: err_a, err_b and groups must hold the same frames, got N = "
            f"{a.shape[1]}, {b.shape[1]}, {g.shape[0]}"
        )
    _check_boot(n_boot, 0.5, "pooled_bootstrap")
    if paired_seeds and a.shape[0] != b.shape[0]:
        raise ValueError(
            f"pooled_bootstrap: paired_seeds needs the same seeds for both models, got "
            f"{a.shape[0]} and {b.shape[0]}"
        )
    _, inverse = np.unique(g, return_inverse=True)
    n_groups = int(inverse.max()) + 1
    sizes = np.bincount(inverse, minlength=n_groups).astype(np.float64)

    def group_sums(m: np.ndarray) -> np.ndarray:  # (S, N) -> (S, G) per-seed sums per flight
        return np.stack([np.bincount(inverse, weights=row, minlength=n_groups) for row in m])

    sums_a, sums_b = group_sums(a), group_sums(b)
    rng = np.random.default_rng(seed)
    draws = rng.integers(0, n_groups, size=(int(n_boot), n_groups))
    seeds_a = rng.integers(0, a.shape[0], size=(int(n_boot), a.shape[0]))
    seeds_b = seeds_a if paired_seeds else rng.integers(0, b.shape[0], (int(n_boot), b.shape[0]))
    # Linear in everything: the drawn frames' mean of (seed-mean b - seed-mean a) is
    # sum_g c_g (w_b . sums_b[:, g] - w_a . sums_a[:, g]) / sum_g c_g size_g, with c_g the times
    # flight g was drawn and w the seed-draw frequencies (counts / S).
    counts = _row_counts(draws, n_groups)

    def freq(d: np.ndarray, s: int) -> np.ndarray:
        return _row_counts(d, s) / s

    per_group = freq(seeds_b, b.shape[0]) @ sums_b - freq(seeds_a, a.shape[0]) @ sums_a
    replicates = (counts * per_group).sum(axis=1) / (counts @ sizes)
    return float((b.mean(axis=0) - a.mean(axis=0)).mean()), replicates


def _row_counts(draws: np.ndarray, k: int) -> np.ndarray:
    """``(R, m)`` ints in [0, k) -> ``(R, k)`` float64 counts of each value per row."""
    rows = draws.shape[0]
    flat = (draws + k * np.arange(rows)[:, None]).ravel()
    return np.bincount(flat, minlength=rows * k).reshape(rows, k).astype(np.float64)


def percentile_interval(replicates: np.ndarray, confidence: float = 0.95) -> tuple[float, float]:
    """The ``(1 - confidence) / 2`` and ``(1 + confidence) / 2`` quantiles of ``replicates``."""
    _check_boot(1, confidence, "percentile_interval")
    tail = (1.0 - confidence) / 2.0
    lo, hi = np.quantile(np.asarray(replicates, dtype=np.float64), [tail, 1.0 - tail])
    return float(lo), float(hi)


def pooled_bootstrap(
    err_a: np.ndarray,
    err_b: np.ndarray,
    groups: np.ndarray,
    n_boot: int = 2000,
    seed: int = 0,
    confidence: float = 0.95,
    paired_seeds: bool = False,
) -> tuple[float, float, float]:
    """Mean paired difference b - a over frames and seeds with its flight-and-seed bootstrap
    percentile interval (see :func:`pooled_replicates` for shapes, the resampling and
    ``paired_seeds``).

    Returns:
        ``(mean_diff, lo, hi)`` in the unit of the errors.
    """
    _check_boot(n_boot, confidence, "pooled_bootstrap")
    mean, replicates = pooled_replicates(
        err_a, err_b, groups, n_boot=n_boot, seed=seed, paired_seeds=paired_seeds
    )
    return (mean, *percentile_interval(replicates, confidence))


def median_replicates(
    values: np.ndarray,
    groups: np.ndarray,
    n_boot: int = 2000,
    seed: int = 0,
) -> tuple[float, np.ndarray]:
    """Median of per-frame values per seed, averaged over seeds, and its flight-and-seed bootstrap
    replicates (a table cell such as the median horizontal error).

    Args:
        values: ``(S, N)`` (or ``(N,)``) per-frame values of S seeds on the same N frames.
        groups: ``(N,)`` flight id of each frame.
        n_boot: replicates (>= 1); seed: of ``numpy.random.default_rng``.
    Returns:
        ``(median, replicates (n_boot,))``: ``median`` = mean over seeds of ``np.median(values[s])``
        on all frames (what the per-seed summaries average). A replicate draws the flights as
        :func:`pooled_replicates` does (first generator call), then S seeds with replacement, and
        averages the drawn seeds' medians of the multiset holding each frame as often as its
        flight was drawn (``np.median`` of the concatenated frames: the middle element, or the
        mean of the two middle ones for an even count).

    The multiset median needs no expanded copy: with a seed's values sorted once, the k-th
    element of a replicate's multiset is the first sorted value whose cumulative multiplicity
    exceeds k, so a replicate costs O(N) and memory stays (block, N).
    """
    v = _as_seed_matrix(values, "values")
    g = np.asarray(groups).reshape(-1)
    if v.shape[1] != g.shape[0]:
        raise ValueError(
            f"median_bootstrap: values {v.shape} and groups {g.shape} must hold the same frames"
        )
    _check_boot(n_boot, 0.5, "median_bootstrap")
    n_seeds = v.shape[0]
    point = float(np.median(v, axis=1).mean())
    labels, inverse = np.unique(g, return_inverse=True)
    rng = np.random.default_rng(seed)
    draws = rng.integers(0, len(labels), size=(int(n_boot), len(labels)))
    seed_draws = rng.integers(0, n_seeds, size=(int(n_boot), n_seeds))
    counts = _row_counts(draws, len(labels))  # (n_boot, G) times each flight was drawn
    orders = [np.argsort(v[s], kind="stable") for s in range(n_seeds)]
    per_seed = np.empty((int(n_boot), n_seeds))
    for start in range(0, int(n_boot), 256):  # blocks bound the (block, N) temporaries
        weights = counts[start : start + 256][:, inverse]  # (block, N) frame multiplicities
        for s, order in enumerate(orders):
            cumulative = np.cumsum(weights[:, order], axis=1)
            per_seed[start : start + 256, s] = _multiset_median(v[s, order], cumulative)
    replicates = np.take_along_axis(per_seed, seed_draws, axis=1).mean(axis=1)
    return point, replicates


def _multiset_median(sorted_values: np.ndarray, cumulative: np.ndarray) -> np.ndarray:
    """Median of the multisets holding ``sorted_values[n]`` as often as the rows of
    ``cumulative (R, N)`` (cumulative multiplicities, last column the size W >= 1) say: ``(R,)``,
    the element at 0-based position ``(W - 1) // 2`` averaged with the one at ``W // 2``."""
    total = cumulative[:, -1]

    def element(k: np.ndarray) -> np.ndarray:  # k-th element: first cumulative count above k
        return sorted_values[(cumulative <= k[:, None]).sum(axis=1)]

    return 0.5 * (element((total - 1) // 2) + element(total // 2))


def median_bootstrap(
    values: np.ndarray,
    groups: np.ndarray,
    n_boot: int = 2000,
    seed: int = 0,
    confidence: float = 0.95,
) -> tuple[float, float, float]:
    """``(median, lo, hi)``: :func:`median_replicates`' point estimate and percentile interval."""
    _check_boot(n_boot, confidence, "median_bootstrap")
    point, replicates = median_replicates(values, groups, n_boot=n_boot, seed=seed)
    return (point, *percentile_interval(replicates, confidence))


def spearman_replicates(
    x: np.ndarray,
    y: np.ndarray,
    groups: np.ndarray,
    n_boot: int = 2000,
    seed: int = 0,
) -> tuple[float, np.ndarray]:
    """Spearman correlation of x and y per seed, averaged over seeds, and its flight-and-seed
    bootstrap replicates.

    Args:
        x, y: ``(S, N)`` (or ``(N,)``) paired values per seed and frame (e.g. a head's predicted
            uncertainty and its geodesic error).
        groups: ``(N,)`` flight id of each frame.
    Returns:
        ``(rho, replicates (n_boot,))``: ``rho`` = mean over seeds of ``spearmanr(x[s], y[s])`` on
        all frames (what the per-seed summaries average); a replicate draws the flights as
        :func:`pooled_replicates` does, then S seeds with replacement, and averages the drawn
        seeds' Spearman correlations over the drawn flights' frames (ties get average ranks).
        NaN where a correlation is undefined (a constant input).
    """
    xs, ys = _as_seed_matrix(x, "x"), _as_seed_matrix(y, "y")
    g = np.asarray(groups).reshape(-1)
    if xs.shape != ys.shape or xs.shape[1] != g.shape[0]:
        raise ValueError(
            f"spearman_bootstrap: x {xs.shape}, y {ys.shape} and groups {g.shape} must agree"
        )
    _check_boot(n_boot, 0.5, "spearman_bootstrap")
    n_seeds = xs.shape[0]
    ones = np.ones((1, xs.shape[1]))
    point = float(np.mean([_weighted_spearman(xs[s], ys[s], ones)[0] for s in range(n_seeds)]))
    labels, inverse = np.unique(g, return_inverse=True)
    rng = np.random.default_rng(seed)
    draws = rng.integers(0, len(labels), size=(int(n_boot), len(labels)))
    seed_draws = rng.integers(0, n_seeds, size=(int(n_boot), n_seeds))
    # A replicate's frames are the drawn flights' frames, each as often as its flight was drawn:
    # frame weights = flight counts, and Spearman on that multiset is a weighted rank correlation.
    weights = _row_counts(draws, len(labels))[:, inverse]  # (n_boot, N)
    per_seed = np.empty((int(n_boot), n_seeds))
    for start in range(0, int(n_boot), 256):  # blocks bound the (block, N) temporaries
        w = weights[start : start + 256]
        for s in range(n_seeds):
            per_seed[start : start + 256, s] = _weighted_spearman(xs[s], ys[s], w)
    replicates = np.take_along_axis(per_seed, seed_draws, axis=1).mean(axis=1)
    return point, replicates


def _average_ranks(u: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Average ranks (1-based, ties averaged) of ``u (N,)`` in the multiset holding frame n
    ``w[r, n]`` times, for each row r of ``w (R, N)``: ``(R, N)``. Equals ``rankdata`` of the
    expanded array (frames of weight 0 get a rank that carries no weight)."""
    order = np.argsort(u, kind="stable")
    su = u[order]
    starts = np.flatnonzero(np.r_[True, su[1:] != su[:-1]])  # tie groups of u
    group = np.cumsum(np.r_[True, su[1:] != su[:-1]]) - 1  # (N,) group of each sorted position
    sums = np.add.reduceat(w[:, order], starts, axis=1)  # (R, T) copies per tie group
    avg = np.cumsum(sums, axis=1) - sums + (sums + 1.0) / 2.0
    ranks = np.empty_like(w, dtype=np.float64)
    ranks[:, order] = avg[:, group]
    return ranks


def _weighted_spearman(u: np.ndarray, v: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Spearman correlation of ``u, v (N,)`` on the multisets given by the rows of ``w (R, N)``
    (Pearson correlation of the average ranks, weighted by multiplicity): ``(R,)``, NaN where a
    variable is constant on the multiset."""
    ru, rv = _average_ranks(u, w), _average_ranks(v, w)
    total = w.sum(axis=1, keepdims=True)
    du = ru - (w * ru).sum(axis=1, keepdims=True) / total
    dv = rv - (w * rv).sum(axis=1, keepdims=True) / total
    cov, var_u, var_v = ((w * a * b).sum(axis=1) for a, b in ((du, dv), (du, du), (dv, dv)))
    with np.errstate(divide="ignore", invalid="ignore"):
        out = cov / np.sqrt(var_u * var_v)
    tiny = 1e-12 * np.maximum(1.0, total[:, 0] ** 3)  # a constant variable: zero variance
    return np.where((var_u > tiny) & (var_v > tiny), out, np.nan)


def spearman_bootstrap(
    x: np.ndarray,
    y: np.ndarray,
    groups: np.ndarray,
    n_boot: int = 2000,
    seed: int = 0,
    confidence: float = 0.95,
) -> tuple[float, float, float]:
    """``(rho, lo, hi)``: :func:`spearman_replicates`' point estimate and percentile interval
    (NaN bounds when some replicate's correlation is undefined)."""
    _check_boot(n_boot, confidence, "spearman_bootstrap")
    point, replicates = spearman_replicates(x, y, groups, n_boot=n_boot, seed=seed)
    if not np.isfinite(replicates).all():
        return point, np.nan, np.nan
    return (point, *percentile_interval(replicates, confidence))
