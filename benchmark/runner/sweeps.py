"""The sweep figures (paper Figs. 5, 6, 7, 9): their Markdown table and their plot.

A row per (split, variant, sweep value) with the mean over seeds and its 95% interval (see
``benchmark.runner.report.interval_note``), the validation split's numbers beside the test ones
and, in the plot, each seed's own value beside the band of the interval.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from benchmark.runner.report import (
    METRIC_LABELS,
    cell_text,
    format_value,
    interval_note,
    pick_val,
    val_cell,
    val_metrics,
    val_note,
    val_splits_of,
)
from benchmark.runner.specs import TableSpec


def sweep_table(spec: TableSpec, summary: pd.DataFrame, show_val: bool | None = None) -> str:
    """Markdown for a figure: one row per (split, variant, x), with validation columns as in
    ``benchmark.runner.report.markdown_table``."""
    lines = [
        f"## {spec.title}",
        "",
        f"Source spec: `{spec.source.name}`. {interval_note(summary)}",
        "",
    ]
    vals = val_metrics(spec, summary, show_val)
    val_splits = val_splits_of(summary)
    if vals:
        lines += [val_note(val_splits), ""]
    header = ["split", "model", spec.sweep or "x"]
    for m in spec.metrics:
        header += [METRIC_LABELS.get(m, m)] + ([f"{METRIC_LABELS.get(m, m)} val"] * (m in vals))
    header += [f"{METRIC_LABELS.get(m, m)} swapped sat." for m in spec.swap_metrics]
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    true = summary[summary["satellite"] == "true"] if "satellite" in summary else summary
    if "role" in true:
        true = true[true["role"].fillna("test") == "test"]
    for _, r in true.iterrows():
        cells = [f"`{r['split']}`", str(r["label"]), str(r["x"])]
        train = str(r.get("train_split"))
        val = pick_val(summary, str(r["label"]), train, r["x"]) if vals else None
        for m in spec.metrics:
            cells.append(format_value(r[m], r[f"{m}_lo"], r[f"{m}_hi"]) if m in r else "–")
            if m in vals:
                cells.append(val_cell(val, m, train, val_splits))
        if spec.swap_metrics:
            swap = summary[
                (summary["label"] == r["label"]) & (summary["split"] == r["split"])
                & (summary["x"].astype(str) == str(r["x"])) & (summary["satellite"] == "swap")
            ]  # fmt: skip
            cells += [cell_text(swap.iloc[0] if len(swap) else None, m) for m in spec.swap_metrics]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def sweep_figure(
    spec: TableSpec, summary: pd.DataFrame, path: Path, per_seed: pd.DataFrame | None = None
) -> None:
    """One panel per metric: error against the sweep value, a line per (variant, split) through
    the means over seeds, a band for the 95% interval of the table cells and, given ``per_seed``
    (the results rows, one per seed), each seed's own value as a small dot: the seed spread."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    metrics = [m for m in spec.metrics if m in summary.columns]
    summary = _test_true(summary)
    seeds = _test_true(per_seed) if per_seed is not None and len(per_seed) else None
    cols = min(4, len(metrics))
    rows = math.ceil(len(metrics) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4 * cols, 3.2 * rows), squeeze=False)
    order = {str(x): i for i, x in enumerate(spec.sweep_values)}
    # A line per variant and evaluated split; when the split itself follows the sweep value
    # (Fig. 5's height{x}/test, Fig. 6's pitch{x}/test) a line per variant.
    split_follows_x = any("{x}" in s for s in spec.eval_splits)
    template = next((s for s in spec.eval_splits if "{x}" in s), "")

    def series_of(frame: pd.DataFrame) -> pd.DataFrame:
        frame = frame.assign(series=template if split_follows_x else frame["split"])
        return frame.assign(_pos=frame["x"].astype(str).map(order)).sort_values("_pos")

    series = series_of(summary)
    seed_series = series_of(seeds) if seeds is not None else None
    for ax, m in zip(axes.flat, metrics, strict=False):
        for (label, split), part in series.groupby(["label", "series"], sort=False):
            xs = part["_pos"].to_numpy()
            ys = part[m].to_numpy(dtype=float)
            lo, hi = part[f"{m}_lo"].to_numpy(dtype=float), part[f"{m}_hi"].to_numpy(dtype=float)
            line = ax.plot(xs, ys, marker="o", label=f"{label} [{split}]")[0]
            if np.isfinite(lo).any():
                ax.fill_between(xs, lo, hi, color=line.get_color(), alpha=0.2)
            if seed_series is not None and m in seed_series:
                own = seed_series[
                    (seed_series["label"] == label) & (seed_series["series"] == split)
                ]
                ax.scatter(own["_pos"], own[m], s=9, color=line.get_color(), alpha=0.6, zorder=3)
        ax.set_xticks(
            range(len(spec.sweep_values)), [str(x) for x in spec.sweep_values], rotation=30
        )
        ax.set_xlabel(spec.sweep or "x")
        ax.set_title(METRIC_LABELS.get(m, m))
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(metrics) :]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7)
    n = int(summary["n_seeds"].max()) if "n_seeds" in summary and len(summary) else 1
    kinds = set(summary["interval"].dropna()) if "interval" in summary else set()
    band = "flight×seed bootstrap" if "flight×seed bootstrap" in kinds else "Student-t over seeds"
    fig.suptitle(
        f"Paper Fig. {spec.paper_figure}: {spec.title}\nline: mean over {n} seed(s); dots: "
        f"each seed; band: 95% interval ({band})",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _test_true(frame: pd.DataFrame) -> pd.DataFrame:
    """Rows measured on test splits with the true satellite image."""
    if "satellite" in frame:
        frame = frame[frame["satellite"] == "true"]
    if "role" in frame:
        frame = frame[frame["role"].fillna("test") == "test"]
    return frame
