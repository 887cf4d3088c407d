"""The "no global heading cue" audit (issue 9): can image-wide UAV statistics read the heading?

A benchmark of UAV-to-satellite pose must not let a model read the UAV's yaw from the UAV image
alone through a cue shared by the whole dataset (one sun per city, one street grid per city). This
module fits a deliberately simple probe that sees no spatial layout and no satellite image:

* features per UAV image (:func:`image_features`): a magnitude-weighted histogram of the gradient
  orientation over the full circle ``[0, 2 pi)`` (it sees the light-to-dark direction, so a sun
  fixed in the world shows up as a fixed direction in the image that turns with the heading), the
  same histogram modulo ``pi`` (edge directions, e.g. a street grid), the log mean gradient
  magnitude, and the colour balance (mean and std of each channel, chromaticity). Nothing depends
  on where in the image a pixel is: shuffling the pixels' gradients keeps the features;
* a ridge regression (closed form) from the standardised features to ``(cos yaw, sin yaw)``, the
  regularisation chosen on the validation split only; the prediction is ``atan2`` of the output.

The audit compares the probe's mean absolute yaw error with the constant predictor's (the circular
mean of the training yaw). A ratio near 1 means the probe finds no global heading cue; the issue's
acceptance is ratio >= 0.85 on standard/test.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

N_BINS_FULL = 32  # full-circle orientation bins, 11.25 deg each
N_BINS_HALF = 32  # orientation modulo pi, 5.6 deg each
# Ridge strengths tried on the validation split, relative to the number of training samples
# (features are standardised, so lambda = n means a penalty of the order of the data term).
DEFAULT_RIDGES: tuple[float, ...] = tuple(10.0**k for k in range(-6, 4))
_LUMA = np.array([0.299, 0.587, 0.114])  # ITU-R BT.601 weights
_BATCH = 256  # images per feature batch (bounded memory on large splits)


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Angles (radians) wrapped to ``[-pi, pi)``."""
    return (np.asarray(a, dtype=np.float64) + math.pi) % (2.0 * math.pi) - math.pi


def yaw_error_deg(pred: np.ndarray, yaw: np.ndarray) -> float:
    """Mean absolute wrapped difference, degrees, of yaw arrays ``(n,)`` in radians."""
    pred, yaw = np.asarray(pred, np.float64), np.asarray(yaw, np.float64)
    if pred.shape != yaw.shape or pred.ndim != 1 or len(pred) == 0:
        raise ValueError(f"yaw_error_deg: need two equal 1-D arrays, got {pred.shape} {yaw.shape}")
    return float(np.degrees(np.abs(wrap_angle(pred - yaw)).mean()))


def circular_mean(yaw: np.ndarray) -> float:
    """The circular mean ``atan2(mean sin, mean cos)`` of angles ``(n,)``, radians."""
    yaw = np.asarray(yaw, np.float64)
    return float(math.atan2(np.sin(yaw).mean(), np.cos(yaw).mean()))


def soft_histogram(angle: np.ndarray, weight: np.ndarray, n_bins: int, period: float) -> np.ndarray:
    """Weighted circular histogram ``(..., n_bins)`` of ``angle`` (radians) modulo ``period``.

    ``angle`` and ``weight`` are ``(..., P)``. Bin ``k`` is centred at ``k * period / n_bins``;
    each sample splits its weight linearly between the two nearest centres, so the histogram is
    continuous in the angles (a rounding difference in an angle cannot move a whole sample to
    another bin) and shifting every angle by a whole number of bins rolls it exactly.
    """
    angle = np.asarray(angle, np.float64)
    weight = np.broadcast_to(np.asarray(weight, np.float64), angle.shape)
    lead = angle.shape[:-1]
    rows = int(np.prod(lead, dtype=np.int64))
    pos = np.mod(angle, period).reshape(rows, -1) * (n_bins / period)
    lo = np.floor(pos)
    frac = pos - lo
    lo = lo.astype(np.int64) % n_bins  # pos may round up to exactly n_bins
    w = weight.reshape(rows, -1)
    offset = np.arange(rows)[:, None] * n_bins  # one bincount for all rows
    size = rows * n_bins
    out = np.bincount((offset + lo).ravel(), (w * (1.0 - frac)).ravel(), minlength=size)
    out += np.bincount((offset + (lo + 1) % n_bins).ravel(), (w * frac).ravel(), minlength=size)
    return out.reshape(*lead, n_bins)


def gradients(gray: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Central-difference gradients of ``gray (n, H, W)`` on the interior ``(n, H-2, W-2)``.

    Returns ``(gx, gy)`` with ``gx`` along u (right) and ``gy`` along -v (up), so the angle
    ``atan2(gy, gx)`` is counter-clockwise as the image is seen. Only interior pixels are used:
    the stencil is then symmetric, and a 180 deg rotation of the image negates every gradient.
    """
    gx = 0.5 * (gray[:, 1:-1, 2:] - gray[:, 1:-1, :-2])
    gy = 0.5 * (gray[:, :-2, 1:-1] - gray[:, 2:, 1:-1])  # row index grows downwards
    return gx, gy


def feature_names(n_full: int = N_BINS_FULL, n_half: int = N_BINS_HALF) -> list[str]:
    """Names of the columns of :func:`image_features`, in order."""
    return (
        [f"ori360_{k}" for k in range(n_full)]
        + [f"ori180_{k}" for k in range(n_half)]
        + ["log_grad"]
        + [f"{s}_{c}" for s in ("mean", "std") for c in "rgb"]
        + ["chroma_r", "chroma_b"]
    )


def image_features(
    images: np.ndarray, n_full: int = N_BINS_FULL, n_half: int = N_BINS_HALF
) -> np.ndarray:
    """Image-wide features ``(n, F)`` of uint8 UAV images ``(n, H, W, 3)``, no spatial layout.

    Columns (see :func:`feature_names`): the full-circle orientation histogram (``n_full``
    bins over ``[0, 2 pi)``, magnitude-weighted, summing to 1), the orientation histogram modulo
    ``pi`` (``n_half`` bins, summing to 1), ``log(1e-3 + mean gradient magnitude)`` (gradients of
    the luma in [0, 1] per pixel), per-channel mean and std in [0, 1], and the chromaticity
    ``mean_r / (mean_r + mean_g + mean_b)`` and the same for blue. An image without gradient gets
    uniform histograms. Upper-vs-lower brightness is left out on purpose: it is spatial (it
    reads the horizon, i.e. pitch), and the audit is about cues that need no layout at all.
    """
    images = np.asarray(images)
    if images.ndim != 4 or images.shape[-1] != 3 or images.dtype != np.uint8:
        raise ValueError(
            f"image_features: images must be uint8 (n, H, W, 3), got {images.dtype} {images.shape}"
        )
    if min(images.shape[1:3]) < 3:
        raise ValueError(f"image_features: images must be at least 3 x 3, got {images.shape}")
    out = [
        _features_batch(images[s : s + _BATCH], n_full, n_half)
        for s in range(0, len(images), _BATCH)
    ]
    return np.concatenate(out) if out else np.zeros((0, len(feature_names(n_full, n_half))))


def _features_batch(images: np.ndarray, n_full: int, n_half: int) -> np.ndarray:
    rgb = images.astype(np.float64) / 255.0  # (n, H, W, 3)
    n = len(rgb)
    gx, gy = gradients(rgb @ _LUMA)
    mag = np.hypot(gx, gy).reshape(n, -1)
    theta = np.arctan2(gy, gx).reshape(n, -1)
    full = soft_histogram(theta, mag, n_full, 2.0 * math.pi)
    half = soft_histogram(theta, mag, n_half, math.pi)
    total = mag.sum(axis=1, keepdims=True)
    flat = total[:, 0] <= 0.0
    full = np.where(flat[:, None], 1.0 / n_full, full / np.where(flat, 1.0, total[:, 0])[:, None])
    half = np.where(flat[:, None], 1.0 / n_half, half / np.where(flat, 1.0, total[:, 0])[:, None])
    log_grad = np.log(1e-3 + mag.mean(axis=1, keepdims=True))
    pixels = rgb.reshape(n, -1, 3)
    mean = pixels.mean(axis=1)
    std = pixels.std(axis=1)
    chroma = mean / np.maximum(mean.sum(axis=1, keepdims=True), 1e-6)
    return np.concatenate([full, half, log_grad, mean, std, chroma[:, [0, 2]]], axis=1)


def fit_ridge(x: np.ndarray, y: np.ndarray, ridge: float) -> tuple[np.ndarray, np.ndarray]:
    """Ridge regression ``y ~ x w + b`` with an unpenalised intercept, closed form.

    ``x (n, F)``, ``y (n, K)``; minimises ``|y - x w - b|^2 + ridge |w|^2``. Returns
    ``w (F, K)``, ``b (K,)``. Solved as the normal equations on centred data in float64
    (``F`` is a few dozen, so ``x^T x`` is small and well conditioned once ``ridge > 0``).
    """
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    if x.ndim != 2 or y.ndim != 2 or len(x) != len(y) or len(x) == 0:
        raise ValueError(f"fit_ridge: need x (n, F) and y (n, K), got {x.shape} and {y.shape}")
    if not ridge >= 0.0:
        raise ValueError(f"fit_ridge: ridge must be >= 0, got {ridge}")
    xm, ym = x.mean(axis=0), y.mean(axis=0)
    xc = x - xm
    gram = xc.T @ xc + ridge * np.eye(x.shape[1])
    w = np.linalg.lstsq(gram, xc.T @ (y - ym), rcond=None)[0]  # lstsq: safe if ridge = 0
    return w, ym - xm @ w


@dataclass(frozen=True)
class HeadingProbe:
    """A fitted probe: standardise, ridge to (cos, sin) yaw, atan2."""

    mean: np.ndarray  # (F,) training feature mean
    scale: np.ndarray  # (F,) training feature std (1 where a feature is constant)
    weights: np.ndarray  # (F, 2) on standardised features
    bias: np.ndarray  # (2,)
    ridge: float  # the chosen regularisation (absolute, on standardised features)
    val_errors_deg: dict[float, float]  # ridge -> validation mean yaw error, degrees

    def predict(self, features: np.ndarray) -> np.ndarray:
        """Yaw ``(n,)`` radians in ``(-pi, pi]`` from features ``(n, F)``."""
        z = (np.asarray(features, np.float64) - self.mean) / self.scale
        cs = z @ self.weights + self.bias
        return np.arctan2(cs[:, 1], cs[:, 0])


def fit_heading_probe(
    train_features: np.ndarray,
    train_yaw: np.ndarray,
    val_features: np.ndarray,
    val_yaw: np.ndarray,
    ridges: Sequence[float] = DEFAULT_RIDGES,
) -> HeadingProbe:
    """Fit the probe on ``(n, F)`` features and yaw ``(n,)`` radians; pick the ridge on val.

    Each relative ridge ``r`` in ``ridges`` is used as ``lambda = r * n_train`` on standardised
    features; the one with the lowest validation mean yaw error wins (ties: the stronger one).
    The model is fitted on the training split only; the test split never enters.
    """
    xt, yt = np.asarray(train_features, np.float64), np.asarray(train_yaw, np.float64)
    xv, yv = np.asarray(val_features, np.float64), np.asarray(val_yaw, np.float64)
    if xt.ndim != 2 or yt.shape != (len(xt),) or len(xt) < 2:
        raise ValueError(
            f"fit_heading_probe: train needs (n>=2, F) and (n,), got {xt.shape} {yt.shape}"
        )
    if xv.ndim != 2 or xv.shape[1] != xt.shape[1] or yv.shape != (len(xv),) or len(xv) == 0:
        raise ValueError(
            f"fit_heading_probe: val needs (m, {xt.shape[1]}) and (m,), got {xv.shape} {yv.shape}"
        )
    if not ridges or min(ridges) <= 0:
        raise ValueError(f"fit_heading_probe: ridges must be positive, got {list(ridges)}")
    mean = xt.mean(axis=0)
    scale = xt.std(axis=0)
    scale = np.where(scale > 1e-12, scale, 1.0)
    zt, zv = (xt - mean) / scale, (xv - mean) / scale
    target = np.stack([np.cos(yt), np.sin(yt)], axis=1)
    best: tuple[float, float, np.ndarray, np.ndarray] | None = None
    errors: dict[float, float] = {}
    for r in sorted(ridges, reverse=True):
        lam = float(r) * len(xt)
        w, b = fit_ridge(zt, target, lam)
        cs = zv @ w + b
        err = yaw_error_deg(np.arctan2(cs[:, 1], cs[:, 0]), yv)
        errors[lam] = err
        if best is None or err < best[0]:
            best = (err, lam, w, b)
    assert best is not None
    return HeadingProbe(mean, scale, best[2], best[3], best[1], errors)


def ratio_interval(
    probe_err: np.ndarray,
    constant_err: np.ndarray,
    flights: np.ndarray,
    n_boot: int = 2000,
    seed: int = 0,
    confidence: float = 0.95,
) -> tuple[float, float]:
    """Percentile interval of ``mean(probe_err) / mean(constant_err)`` under a bootstrap that
    resamples whole flights (frames of a flight are correlated), both errors on the same frames.

    Args:
        probe_err, constant_err: ``(n,)`` per-frame errors (any unit); ``flights``: ``(n,)`` ids.
    Returns:
        ``(lo, hi)``: the ``(1 -+ confidence) / 2`` quantiles of the replicates' ratios (each
        replicate: the sums over its drawn flights' frames, divided).
    """
    p, c, f = (np.asarray(a).reshape(-1) for a in (probe_err, constant_err, flights))
    if not (p.shape == c.shape == f.shape) or p.size == 0:
        raise ValueError(
            f"ratio_interval: need equal non-empty lengths, got {p.size}, {c.size}, {f.size}"
        )
    _, inverse = np.unique(f, return_inverse=True)
    groups = int(inverse.max()) + 1
    sp = np.bincount(inverse, weights=p.astype(np.float64), minlength=groups)
    sc = np.bincount(inverse, weights=c.astype(np.float64), minlength=groups)
    draws = np.random.default_rng(seed).integers(0, groups, size=(int(n_boot), groups))
    ratios = sp[draws].sum(axis=1) / sc[draws].sum(axis=1)
    tail = (1.0 - confidence) / 2.0
    lo, hi = np.quantile(ratios, [tail, 1.0 - tail])
    return float(lo), float(hi)


def split_flights(dataset_root: str | Path, split: str) -> np.ndarray:
    """Flight id ``(n,)`` of every pair of ``split``, in the order of :func:`split_features`."""
    from benchmark.data import PairDataset

    return PairDataset(dataset_root, split, verify="size").poses["flight"].to_numpy()


def split_features(dataset_root: str | Path, split: str) -> tuple[np.ndarray, np.ndarray]:
    """Features ``(n, F)`` of the UAV images of ``split`` and their yaw ``(n,)``, radians."""
    from benchmark.data import PairDataset

    ds = PairDataset(dataset_root, split, verify="size")
    images = (ds.uav_image(i) for i in range(len(ds)))
    feats = [image_features(np.stack(chunk)) for chunk in _chunks(images, _BATCH)]
    n_feat = len(feature_names())
    x = np.concatenate(feats) if feats else np.zeros((0, n_feat))
    return x, ds.poses["yaw"].to_numpy(np.float64)


def _chunks(items: Iterable[np.ndarray], size: int) -> Iterable[list[np.ndarray]]:
    chunk: list[np.ndarray] = []
    for item in items:
        chunk.append(item)
        if len(chunk) == size:
            yield chunk
            chunk = []
    if chunk:
        yield chunk


def _split_summary(probe_err: np.ndarray, const_err: np.ndarray, flights: np.ndarray) -> dict:
    """``{"n", "probe_deg", "constant_deg", "ratio", "ratio_lo", "ratio_hi", "flights"}`` of
    per-frame errors ``(n,)`` in degrees and flight ids ``(n,)``."""
    probe_deg, const_deg = float(probe_err.mean()), float(const_err.mean())
    lo, hi = ratio_interval(probe_err, const_err, flights) if const_deg > 0 else (math.nan,) * 2
    return {
        "n": len(probe_err),
        "probe_deg": probe_deg,
        "constant_deg": const_deg,
        "ratio": probe_deg / const_deg if const_deg > 0 else math.nan,
        "ratio_lo": lo,
        "ratio_hi": hi,
        "flights": len(np.unique(flights)),
    }


def heading_cue_audit(
    dataset_root: str | Path,
    train: str = "standard/train",
    val: str = "standard/val",
    test: str | Sequence[str] = "standard/test",
    keep_frames: bool = False,
) -> dict[str, Any]:
    """Fit the probe on ``train`` (ridge chosen on ``val``) and score it on val and ``test``.

    ``test`` is one split name or several. Returns ``{"train", "val", "ridge", "n_features",
    "constant_yaw_deg", "splits": {split: {"n", "probe_deg", "constant_deg", "ratio"}}}`` with
    ``splits`` holding ``val`` first, then each test split; errors are mean absolute wrapped yaw
    errors in degrees, ``ratio = probe_deg / constant_deg`` (1: no cue; the acceptance asks
    >= 0.85 on standard/test), ``ratio_lo``/``ratio_hi`` its 95% flight-bootstrap interval
    (:func:`ratio_interval`) and ``flights``. With ``keep_frames`` also ``"frames": {split:
    (probe_err, constant_err, flights)}``, per-frame arrays ``(n,)`` (degrees; flight ids), which
    :func:`pooled_heading_cue_audit` pools. Unknown splits raise ``ValueError`` from
    ``PairDataset``.
    """
    tests = [test] if isinstance(test, str) else list(test)
    x_train, y_train = split_features(dataset_root, train)
    x_val, y_val = split_features(dataset_root, val)
    probe = fit_heading_probe(x_train, y_train, x_val, y_val)
    constant = circular_mean(y_train)
    result: dict[str, Any] = {
        "train": train,
        "val": val,
        "n_train": len(y_train),
        "ridge": probe.ridge,
        "n_features": x_train.shape[1],
        "constant_yaw_deg": math.degrees(constant),
        "splits": {},
    }
    frames = {}
    for name in [val, *tests]:
        x, y = (x_val, y_val) if name == val else split_features(dataset_root, name)
        probe_err = np.degrees(np.abs(wrap_angle(probe.predict(x) - y)))
        const_err = np.degrees(np.abs(wrap_angle(np.full_like(y, constant) - y)))
        flights = split_flights(dataset_root, name)
        result["splits"][name] = _split_summary(probe_err, const_err, flights)
        frames[name] = (probe_err, const_err, flights)
    if keep_frames:
        result["frames"] = frames
    return result


def pooled_heading_cue_audit(
    dataset_roots: Sequence[str | Path],
    train: str = "standard/train",
    val: str = "standard/val",
    test: str | Sequence[str] = "standard/test",
) -> dict[str, Any]:
    """The audit on several datasets of one profile (different seeds: different cities, suns,
    flights), each probe fitted on its own dataset's ``train``, and the errors pooled.

    One test split of a quick dataset (150 short flights; ~40 long ones before) is one draw: the
    constant predictor's error on it swings with how its flights' headings lie (seen: 86.9-96.9
    deg over five quick datasets, 88.8-101.3 with the longer flights, where a
    predictor that knows nothing averages 90); pooling independent datasets measures the
    simulator rather than one draw. A test split missing from a dataset is scored where present
    and pooled only over datasets that all hold it. Returns ``{"datasets": [heading_cue_audit
    result per root], "pooled": {split: summary as in heading_cue_audit}}``; the pooled ratio is
    the sum of probe errors over the sum of constant errors, its interval a bootstrap over the
    flights of all datasets (flight ids are made unique per dataset).
    """
    from benchmark.data import list_splits

    if not dataset_roots:
        raise ValueError("pooled_heading_cue_audit: need at least one dataset")
    tests = [test] if isinstance(test, str) else list(test)
    results = []
    for root in dataset_roots:  # a test split a dataset lacks is scored where it exists
        held = [t for t in tests if t in set(list_splits(root))]
        results.append(heading_cue_audit(root, train, val, held, keep_frames=True))
    pooled = {}
    for split in [s for s in results[0]["splits"] if all(s in r["splits"] for r in results)]:
        parts = [r["frames"][split] for r in results]
        probe = np.concatenate([p for p, _, _ in parts])
        const = np.concatenate([c for _, c, _ in parts])
        flights = np.concatenate([[f"{i}:{f}" for f in fl] for i, (_, _, fl) in enumerate(parts)])
        pooled[split] = _split_summary(probe, const, flights)
    for r in results:
        del r["frames"]
    return {"datasets": results, "pooled": pooled}
