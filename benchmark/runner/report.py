"""Render results next to the paper's numbers: Markdown tables, CSV and figures.

Input is the long results table the runner writes (one row per table, variant, sweep value, split,
satellite mode and seed; metric columns named as in ``reports/paper_tables.csv``: ``dE_m``,
``dtheta_deg``...). ``satellite`` is ``true`` (each pair's own satellite image) or ``swap`` (the
satellite-swap probe: another place's image); the ``swap`` rows of trained models also hold the
paired swap effect ``swap_<dpsi|dphi>_diff_deg`` with its 95% flight-bootstrap interval
``swap_<e>_boot_lo_deg`` / ``_hi_deg``. ``satellite_input`` is ``image``, ``blank`` (the UAV-only
control) or ``none`` (the constant predictor); ``train_split`` the split a row was trained on.
Across seeds we report the mean and a 95% Student-t interval; with one seed only the value.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from benchmark.evaluation.metrics import seed_interval
from benchmark.runner.specs import TableSpec

METRIC_LABELS: dict[str, str] = {
    "dE_m": "δE (m)",
    "dN_m": "δN (m)",
    "dU_m": "δU (m)",
    "dtheta_deg": "δθ pitch (°)",
    "dgamma_deg": "δγ roll (°)",
    "dpsi_deg": "δψ yaw (°)",
    "dphi_deg": "δφ geodesic (°)",
    "median_dphi_deg": "median δφ (°)",
    "acc5": "acc@5°",
    "acc10": "acc@10°",
    "acc30": "acc@30°",
    "loglik": "log-lik",
    "spearman_unc_err": "ρ(unc, err)",
    "size_MB": "size (MB)",
    "MFLOPs": "MFLOPs",
}
GROUP_KEYS = [
    "table", "label", "paper_model", "x", "split", "satellite", "satellite_input", "train_split",
]  # fmt: skip
SWAP_EFFECTS = (("dpsi", "δψ"), ("dphi", "δφ"))
ONE_FLIGHT = "one flight: no interval"
MIN_RISE_DEG = 1.0  # smallest mean error rise under the swap that counts as using the image


def interval95(values: np.ndarray) -> tuple[float, float, float]:
    """``(mean, low, high)`` over the finite values: Student-t 95% interval of the mean (NaN
    bounds for one value, all NaN for none)."""
    values = np.asarray(values, dtype=float)
    values = values[np.isfinite(values)]
    if len(values) == 0:
        return math.nan, math.nan, math.nan
    interval = seed_interval(values, 0.95)
    return interval.mean, interval.low, interval.high


def summarize(results: pd.DataFrame, metrics: list[str]) -> pd.DataFrame:
    """One row per (table, label, x, split): ``<m>``, ``<m>_lo``, ``<m>_hi``, ``n_seeds``."""
    rows = []
    keys = [k for k in GROUP_KEYS if k in results.columns]
    for group, part in results.groupby(keys, dropna=False, sort=False):
        row = dict(zip(keys, group, strict=True))
        row["n_seeds"] = int(part["seed"].nunique()) if "seed" in part else len(part)
        for m in metrics:
            if m in part:
                row[m], row[f"{m}_lo"], row[f"{m}_hi"] = interval95(part[m].to_numpy())
        rows.append(row)
    return pd.DataFrame(rows)


def format_value(mean: float, lo: float, hi: float, digits: int = 2) -> str:
    if not math.isfinite(mean):
        return "–"
    if math.isfinite(lo) and math.isfinite(hi):
        return f"{mean:.{digits}f} ± {(hi - lo) / 2:.{digits}f}"
    return f"{mean:.{digits}f}"


def paper_value(
    paper: pd.DataFrame, table: int | None, split: str | None, model: str, metric: str
) -> float:
    """The published number, NaN if the paper does not give it."""
    if table is None or metric not in paper.columns:
        return math.nan
    rows = paper[(paper["table"] == table) & (paper["model"] == model)]
    if split is not None and "split" in rows:
        rows = rows[rows["split"].fillna("") == split]
    values = rows[metric].dropna()
    return float(values.iloc[0]) if len(values) else math.nan


def load_paper(path: str | Path) -> pd.DataFrame:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(
            f"paper numbers not found at {path} (expected reports/paper_tables.csv)"
        )
    return pd.read_csv(path)


def pick(
    summary: pd.DataFrame,
    label: str,
    split: str,
    satellite: str = "true",
    train_split: str | None = None,
) -> pd.Series | None:
    """The summary row of (label, split, satellite mode[, train split]), or None."""
    if summary.empty or "label" not in summary:
        return None
    rows = summary[(summary["label"] == label) & (summary["split"] == split)]
    if "satellite" in rows:
        rows = rows[rows["satellite"] == satellite]
    if train_split is not None and "train_split" in rows:
        rows = rows[rows["train_split"] == train_split]
    return rows.iloc[0] if len(rows) else None


def uses_satellite(swap_row: pd.Series | None) -> str | None:
    """Verdict of the swap probe for one model. An error "rises" when the 95% flight-bootstrap
    interval of its per-frame difference (swapped minus true) lies above zero and the mean rise is
    at least ``MIN_RISE_DEG`` (a statistically clear rise of 0.01 deg is no use of the image).
    ``yes`` when the yaw and the geodesic errors both rise, ``yaw only`` / ``geodesic only`` when
    one does, ``no`` otherwise; ``one flight`` when the test set holds a single flight (no interval
    over flights); None without the numbers."""
    if swap_row is None:
        return None
    if swap_row.get("swap_groups", 2) < 2:
        return ONE_FLIGHT
    keys = [(f"swap_{e}_boot_lo_deg", f"swap_{e}_diff_deg") for e, _ in SWAP_EFFECTS]
    values = [(swap_row.get(lo, math.nan), swap_row.get(d, math.nan)) for lo, d in keys]
    if not all(isinstance(x, float | int) and math.isfinite(x) for v in values for x in v):
        return None
    yaw, geo = (lo > 0 and d >= MIN_RISE_DEG for lo, d in values)
    return {(True, True): "yes", (True, False): "yaw only", (False, True): "geodesic only"}.get(
        (yaw, geo), "no"
    )


def _cell(row: pd.Series | None, m: str) -> str:
    if row is None or m not in row:
        return "not run"
    return format_value(row[m], row[f"{m}_lo"], row[f"{m}_hi"])


def table_rows(spec: TableSpec, split: str, extra_labels: list[str]) -> list[tuple[str, str, str]]:
    """``(label, paper model, train split)`` of every row evaluated on ``split``."""
    rows = [(j.label, j.paper_model, j.train_split) for j in spec.jobs() if split in j.eval_splits]
    rows += [(x, "", spec.train_split_for(split)) for x in extra_labels]
    return list(dict.fromkeys(rows))


def markdown_table(
    spec: TableSpec, summary: pd.DataFrame, paper: pd.DataFrame, extra_labels: list[str] = ()
) -> str:
    """A Markdown table of one table spec: per metric, the paper's number (paper tables only) and
    ours; then each ``swap_metrics`` entry measured with the swapped satellite image."""
    lines = [
        f"## {spec.title}",
        "",
        f"Source spec: `{spec.source.name}`. {_seed_note(summary)}",
        "",
    ]
    splits = spec.all_eval_splits()
    names = spec.paper_splits or (spec.paper_split,) * len(spec.eval_splits)
    paper_split = dict(zip(spec.eval_splits, names, strict=True))
    with_paper = spec.paper_table is not None
    multi = len(splits) > 1
    trained_on = len(spec.train_splits()) > 1
    header = (["split"] if multi else []) + ["model"] + (["trained on"] if trained_on else [])
    for m in spec.metrics:
        label = METRIC_LABELS.get(m, m)
        header += [f"{label} paper", f"{label} ours"] if with_paper else [label]
    header += [f"{METRIC_LABELS.get(m, m)} swapped sat." for m in spec.swap_metrics]
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for split in splits:
        for label, paper_model, train in table_rows(spec, split, list(extra_labels)):
            row = pick(summary, label, split, "true", train)
            swap = pick(summary, label, split, "swap", train)
            cells = ([f"`{split}`"] if multi else []) + [label]
            cells += [f"`{train}`"] if trained_on else []
            for m in spec.metrics:
                if with_paper:
                    ps = paper_split.get(split)
                    pv = paper_value(paper, spec.paper_table, ps, paper_model, m)
                    cells.append("–" if not math.isfinite(pv) else f"{pv:.2f}")
                cells.append(_cell(row, m))
            cells += [_cell(swap, m) for m in spec.swap_metrics]
            lines.append("| " + " | ".join(cells) + " |")
    if spec.swap_metrics:
        lines += ["", swap_probe_table(spec, summary)]
    if spec.note:
        lines += ["", spec.note.strip()]
    return "\n".join(lines) + "\n"


def swap_probe_table(spec: TableSpec, summary: pd.DataFrame) -> str:
    """Per trained row: the paired per-frame effect of swapping the satellite image."""
    lines = [
        "Satellite-swap probe: each pair's satellite image replaced by another place's (another "
        "centre of the same city; for `generalized/test` another city; for `towns/*` another "
        "town; rules in `benchmark/data/swap.py`), labels unchanged. Δ = swapped minus true "
        "error on the same frames, mean and 95% interval from 2000 bootstrap resamples of whole "
        "flights. A model uses the satellite image when both intervals lie above zero and both "
        f"mean rises are at least {MIN_RISE_DEG:g}°.",
        "",
        "| split | model | δψ true | δψ swapped | Δδψ [95% CI] | δφ true | δφ swapped "
        "| Δδφ [95% CI] | uses the satellite image |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for split in spec.all_eval_splits():
        for label, _, train in table_rows(spec, split, []):
            row = pick(summary, label, split, "true", train)
            swap = pick(summary, label, split, "swap", train)
            cells = [f"`{split}`", label]
            for e, _ in SWAP_EFFECTS:
                cells += [_cell(row, f"{e}_deg"), _cell(swap, f"{e}_deg"), _effect(swap, e)]
            cells.append(uses_satellite(swap) or "not run")
            lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _effect(swap: pd.Series | None, e: str) -> str:
    keys = [f"swap_{e}_diff_deg", f"swap_{e}_boot_lo_deg", f"swap_{e}_boot_hi_deg"]
    if swap is None or not all(k in swap and math.isfinite(swap[k]) for k in keys):
        return "not run"
    mean, lo, hi = (float(swap[k]) for k in keys)
    return f"{mean:+.2f} [{lo:+.2f}, {hi:+.2f}]"


def extra_metrics_table(spec: TableSpec, summary: pd.DataFrame, metrics: list[str]) -> str:
    """Our metrics the paper does not report (medians, accuracies, uncertainty quality)."""
    present = [m for m in metrics if m in summary.columns and summary[m].notna().any()]
    if not present:
        return ""
    header = ["split", "model", *(METRIC_LABELS.get(m, m) for m in present)]
    if "satellite" in summary:
        summary = summary[summary["satellite"] == "true"]
    lines = [
        "",
        "Further metrics (ours only, true satellite image):",
        "",
        "| " + " | ".join(header) + " |",
        "|" + "---|" * len(header),
    ]
    for _, r in summary.iterrows():
        cells = [f"`{r['split']}`", str(r["label"])]
        cells += [format_value(r[m], r[f"{m}_lo"], r[f"{m}_hi"], 3) for m in present]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def sweep_table(spec: TableSpec, summary: pd.DataFrame) -> str:
    """Markdown for a figure: one row per (split, variant, x)."""
    lines = [
        f"## {spec.title}",
        "",
        f"Source spec: `{spec.source.name}`. {_seed_note(summary)}",
        "",
    ]
    header = ["split", "model", spec.sweep or "x", *(METRIC_LABELS.get(m, m) for m in spec.metrics)]
    header += [f"{METRIC_LABELS.get(m, m)} swapped sat." for m in spec.swap_metrics]
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    true = summary[summary["satellite"] == "true"] if "satellite" in summary else summary
    for _, r in true.iterrows():
        cells = [f"`{r['split']}`", str(r["label"]), str(r["x"])]
        cells += [
            format_value(r[m], r[f"{m}_lo"], r[f"{m}_hi"]) if m in r else "–" for m in spec.metrics
        ]
        if spec.swap_metrics:
            swap = summary[
                (summary["label"] == r["label"]) & (summary["split"] == r["split"])
                & (summary["x"].astype(str) == str(r["x"])) & (summary["satellite"] == "swap")
            ]  # fmt: skip
            cells += [_cell(swap.iloc[0] if len(swap) else None, m) for m in spec.swap_metrics]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def sweep_figure(spec: TableSpec, summary: pd.DataFrame, path: Path) -> None:
    """One panel per metric: error against the sweep value, a line per (variant, split)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    metrics = [m for m in spec.metrics if m in summary.columns]
    if "satellite" in summary:
        summary = summary[summary["satellite"] == "true"]
    cols = min(4, len(metrics))
    rows = math.ceil(len(metrics) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4 * cols, 3.2 * rows), squeeze=False)
    order = {str(x): i for i, x in enumerate(spec.sweep_values)}
    # A line per variant and evaluated split; when the split itself follows the sweep value
    # (Fig. 5's height{x}/test, Fig. 6's pitch{x}/test) a line per variant.
    split_follows_x = any("{x}" in s for s in spec.eval_splits)
    template = next((s for s in spec.eval_splits if "{x}" in s), "")
    series = summary.assign(series=template if split_follows_x else summary["split"])
    for ax, m in zip(axes.flat, metrics, strict=False):
        for (label, split), part in series.groupby(["label", "series"], sort=False):
            part = part.assign(_pos=part["x"].astype(str).map(order)).sort_values("_pos")
            xs = part["_pos"].to_numpy()
            ys = part[m].to_numpy(dtype=float)
            lo, hi = part[f"{m}_lo"].to_numpy(dtype=float), part[f"{m}_hi"].to_numpy(dtype=float)
            line = ax.plot(xs, ys, marker="o", label=f"{label} [{split}]")[0]
            if np.isfinite(lo).any():
                ax.fill_between(xs, lo, hi, color=line.get_color(), alpha=0.2)
        ax.set_xticks(
            range(len(spec.sweep_values)), [str(x) for x in spec.sweep_values], rotation=30
        )
        ax.set_xlabel(spec.sweep or "x")
        ax.set_title(METRIC_LABELS.get(m, m))
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(metrics) :]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7)
    fig.suptitle(f"Paper Fig. {spec.paper_figure}: {spec.title}", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _seed_note(summary: pd.DataFrame) -> str:
    if summary.empty or "n_seeds" not in summary:
        return "No results yet."
    n = int(summary["n_seeds"].max())
    if n <= 1:
        return "One seed: single values, no interval."
    return f"Mean ± half-width of the 95% Student-t interval over {n} seeds."
