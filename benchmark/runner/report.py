"""Render results next to the paper's numbers: Markdown tables, CSV and figures.

Input is the long results table the runner writes (one row per table, variant, sweep value, split
and seed; metric columns named as in ``reports/paper_tables.csv``: ``dE_m``, ``dtheta_deg``...).
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
GROUP_KEYS = ["table", "label", "paper_model", "x", "split"]


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


def markdown_table(
    spec: TableSpec, summary: pd.DataFrame, paper: pd.DataFrame, extra_labels: list[str] = ()
) -> str:
    """A Markdown table of one paper table: per metric, the paper's number and ours."""
    lines = [
        f"## {spec.title}",
        "",
        f"Source spec: `{spec.source.name}`. {_seed_note(summary)}",
        "",
    ]
    split_names = spec.paper_splits or (spec.paper_split,) * len(spec.eval_splits)
    multi = len(spec.eval_splits) > 1
    header = (["split"] if multi else []) + ["model"]
    for m in spec.metrics:
        label = METRIC_LABELS.get(m, m)
        header += [f"{label} paper", f"{label} ours"]
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    rows = [(v.label, v.paper_model) for v in spec.variants] + [(x, "") for x in extra_labels]
    for split, paper_split in zip(spec.eval_splits, split_names, strict=True):
        for label, paper_model in rows:
            if summary.empty:
                row = summary
            else:
                row = summary[(summary["label"] == label) & (summary["split"] == split)]
            cells = ([f"`{split}`"] if multi else []) + [label]
            for m in spec.metrics:
                pv = paper_value(paper, spec.paper_table, paper_split, paper_model, m)
                cells.append("–" if not math.isfinite(pv) else f"{pv:.2f}")
                if len(row) and m in row:
                    r = row.iloc[0]
                    cells.append(format_value(r[m], r[f"{m}_lo"], r[f"{m}_hi"]))
                else:
                    cells.append("not run")
            lines.append("| " + " | ".join(cells) + " |")
    if spec.note:
        lines += ["", spec.note.strip()]
    return "\n".join(lines) + "\n"


def extra_metrics_table(spec: TableSpec, summary: pd.DataFrame, metrics: list[str]) -> str:
    """Our metrics the paper does not report (medians, accuracies, uncertainty quality)."""
    present = [m for m in metrics if m in summary.columns and summary[m].notna().any()]
    if not present:
        return ""
    header = ["split", "model", *(METRIC_LABELS.get(m, m) for m in present)]
    lines = [
        "",
        "Further metrics (ours only):",
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
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for _, r in summary.iterrows():
        cells = [f"`{r['split']}`", str(r["label"]), str(r["x"])]
        cells += [
            format_value(r[m], r[f"{m}_lo"], r[f"{m}_hi"]) if m in r else "–" for m in spec.metrics
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def sweep_figure(spec: TableSpec, summary: pd.DataFrame, path: Path) -> None:
    """One panel per metric: error against the sweep value, a line per (variant, split)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    metrics = [m for m in spec.metrics if m in summary.columns]
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
