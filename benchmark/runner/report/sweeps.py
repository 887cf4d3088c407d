"""The sweep figures (paper Figs. 5, 6, 7, 9): their Markdown table and their plot.

A row per (split, spec row, sweep value) with the mean over seeds and its 95% interval (see
``benchmark.runner.report.tables.interval_note``), the validation split's numbers beside the test
ones and, in the plot, each seed's own value beside the band of the interval.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pandas as pd

from benchmark.runner.plan.specs import TableSpec
from benchmark.runner.report.tables import (
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

# Axis labels of the sweep variables (``sweep:`` in a spec); others by :func:`sweep_label`'s rule.
SWEEP_LABELS: dict[str, str] = {
    "sat_height_m": "satellite image height above ground (m)",
    "pitch_bin_deg": "UAV pitch bin (°; satellite camera at -90°)",
    "kappa": "vMF concentration κ",
    "variant": "encoder variant",
}
# Fig. 9's encoder variants, spelled out on the ticks.
VARIANT_NAMES: dict[str, str] = {"/": "plain", "a": "attention", "f": "fusion", "a-f": "AGTFM"}
UNITS: dict[str, str] = {"m": "m", "deg": "°", "s": "s", "px": "px"}
_RANGE = re.compile(r"(-?\d+(?:\.\d+)?)to(-?\d+(?:\.\d+)?)")


def sweep_label(sweep: str | None) -> str:
    """A readable axis label for the sweep variable: :data:`SWEEP_LABELS`, else the column name
    with underscores as spaces and a unit suffix (``_m``, ``_deg``, ...) in brackets
    (``tilt_deg -> 'tilt (°)'``)."""
    if not sweep:
        return "sweep value"
    if sweep in SWEEP_LABELS:
        return SWEEP_LABELS[sweep]
    stem, _, suffix = sweep.rpartition("_")
    if stem and suffix in UNITS:
        return f"{stem.replace('_', ' ')} ({UNITS[suffix]})"
    return sweep.replace("_", " ")


def sweep_tick(sweep: str | None, value: object) -> str:
    """A readable sweep value: a bin ``0to-10`` of a ``*_deg`` sweep reads ``0 to -10°``, an
    encoder variant ``a-f`` reads ``a-f (AGTFM)``; anything else as written in the spec."""
    text = str(value)
    if sweep == "variant" and text in VARIANT_NAMES:
        return f"{text} ({VARIANT_NAMES[text]})"
    match = _RANGE.fullmatch(text.replace(" ", ""))
    if match:
        suffix = (sweep or "").rpartition("_")[2]
        unit = UNITS.get(suffix, "")
        unit = unit if unit == "°" or not unit else f" {unit}"
        return f"{match[1]} to {match[2]}{unit}"
    return text


def series_label(label: str, split: str, split_follows_x: bool) -> str:
    """The legend entry of one line: the model, and the test split when it does not change
    along the sweep (``Pd/Re-Net on standard/test``); a split that follows the sweep value
    (Fig. 5's ``height{x}/test``) is the x axis itself, so the legend names the model only."""
    return label if split_follows_x else f"{label} on {split}"


def sweep_table(spec: TableSpec, summary: pd.DataFrame, show_val: bool | None = None) -> str:
    """Markdown for a figure: one row per (split, spec row, x), with validation columns as in
    ``benchmark.runner.report.tables.markdown_table``."""
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
    header = ["split", "model", sweep_label(spec.sweep)]
    for m in spec.metrics:
        header += [METRIC_LABELS.get(m, m)] + ([f"{METRIC_LABELS.get(m, m)} val"] * (m in vals))
    header += [f"{METRIC_LABELS.get(m, m)} swapped sat." for m in spec.swap_metrics]
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    true = summary[summary["satellite"] == "true"] if "satellite" in summary else summary
    if "role" in true:
        true = true[true["role"].fillna("test") == "test"]
    for _, r in true.iterrows():
        cells = [f"`{r['split']}`", str(r["label"]), sweep_tick(spec.sweep, r["x"])]
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
    """One panel per metric: error against the sweep value, a line per (spec row, split) through
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
    # A line per spec row and evaluated split; when the split itself follows the sweep value
    # (Fig. 5's height{x}/test, Fig. 6's pitch{x}/test) a line per spec row.
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
            name = series_label(str(label), str(split), split_follows_x)
            line = ax.plot(xs, ys, marker="o", label=name)[0]
            if np.isfinite(lo).any():
                ax.fill_between(xs, lo, hi, color=line.get_color(), alpha=0.2)
            if seed_series is not None and m in seed_series:
                own = seed_series[
                    (seed_series["label"] == label) & (seed_series["series"] == split)
                ]
                ax.scatter(own["_pos"], own[m], s=9, color=line.get_color(), alpha=0.6, zorder=3)
        ticks = [sweep_tick(spec.sweep, x) for x in spec.sweep_values]
        turn = max(map(len, ticks)) > 5  # long labels would overlap: turn them, anchored right
        ax.set_xticks(
            range(len(ticks)), ticks, rotation=25 if turn else 0, ha="right" if turn else "center"
        )
        ax.set_xlabel(sweep_label(spec.sweep), fontsize=8)
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
