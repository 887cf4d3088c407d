"""The ``sequence`` table and figure (issue 39): every head fused along its flights, rendered from
the numbers of ``benchmark.runner.claims.sequence_errors`` (computed before the report).

The table: a section per split, a row per (head, mode). The figure: mean δψ of the causal filter
against seconds of flight fused, a line per head on each long split, a panel row per odometry
(the dataset's, then the stress odometry at 4x its noise).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from benchmark.runner.claims.sequence_errors import SequenceErrors, SequenceTable
from benchmark.runner.plan.specs import TableSpec

if TYPE_CHECKING:  # matplotlib is imported where a figure is drawn, not on import
    from matplotlib.figure import Figure

MODE_NAMES = {"frame": "per frame", "filter": "filtered", "smooth": "smoothed"}


def _fmt(x: float, digits: int = 1) -> str:
    return "–" if not math.isfinite(x) else f"{x:.{digits}f}"


def _interval(point: float, lo: float, hi: float) -> str:
    return f"{point:+.2f} [{lo:+.2f}, {hi:+.2f}]"


def sequence_markdown(spec: TableSpec, table: pd.DataFrame, figure: str | None) -> str:
    """The rendered table: a section per split, a row per (head, mode)."""
    lines = [f"# {spec.title}", ""]
    if spec.note:
        lines += [spec.note.strip(), ""]
    if not len(table):
        return "\n".join([*lines, "No sequence results yet (no unit wrote its fusion files).", ""])
    head = ("| head | estimate | mean δψ (°) | median δψ (°) | mean δφ (°) | acc@10° (δφ) | "
            "acc@10° (δφ) with the true yaw | median horizontal (m) [95 %] | "
            "Δ mean δφ vs per frame (°) [95 %] |")  # fmt: skip
    for split, part in table.groupby("split", sort=False):
        flights, seeds = int(part["flights"].iloc[0]), int(part["seeds"].max())
        lines += [f"## {split}", "", f"{flights} flights, {seeds} seed(s).", "", head,
                  "|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
        for _, r in part.iterrows():
            gain = (
                _interval(r["gain_dphi_deg"], r["gain_dphi_deg_lo"], r["gain_dphi_deg_hi"])
                if r["mode"] != "frame" and math.isfinite(r.get("gain_dphi_deg", math.nan))
                else "–"
            )
            horizontal = (f"{_fmt(r['median_horizontal_m'])} [{_fmt(r['median_horizontal_lo'])}, "
                          f"{_fmt(r['median_horizontal_hi'])}]")  # fmt: skip
            if bool(r.get("position_given", False)):
                horizontal = "given (true position)"
            exact = r.get("acc10_exact_yaw", math.nan)  # the same for every mode: shown once
            shown = r["mode"] == "frame" and math.isfinite(exact)
            ceiling = f"{100 * exact:.0f} %" if shown else "–"
            lines.append(
                f"| {r['label']} | {MODE_NAMES[r['mode']]} | {_fmt(r['mean_dpsi_deg'])} | "
                f"{_fmt(r['median_dpsi_deg'])} | {_fmt(r['mean_dphi_deg'])} | "
                f"{100 * r['acc10']:.0f} % | {ceiling} | {horizontal} | {gain} |"
            )
        lines.append("")
        distance = oracle_distance(part)
        if distance:
            lines += [distance, ""]
    if figure:
        lines += [f"![{spec.name}]({figure})", ""]
    return "\n".join(lines)


ORACLE_PREFIX = "Geometry oracle"


def oracle_distance(part: pd.DataFrame, mode: str = "smooth") -> str:
    """One sentence per split: how far the best fused learned row (mean δψ, ``mode``; a head's
    or the pose volume's, the UAV-only control left out) is from the fused geometry oracle
    (given the true position, pitch and roll: what the pixels allow at this heading search), ""
    without either."""
    fused = part[part["mode"] == mode]
    keep = fused["learned"].astype(bool) if "learned" in fused else fused["label"].isna()
    if "control" in fused:
        keep &= ~fused["control"].astype("boolean").fillna(False).astype(bool)
    learned = fused[keep]
    oracle = fused[fused["label"].str.startswith(ORACLE_PREFIX)]
    if not len(learned) or not len(oracle):
        return ""
    best = learned.loc[learned["mean_dpsi_deg"].idxmin()]
    ref = float(oracle["mean_dpsi_deg"].iloc[0])
    gap = float(best["mean_dpsi_deg"]) - ref
    return (
        f"Distance to the fused geometry oracle ({MODE_NAMES[mode]}, mean δψ): the best learned "
        f"row, {best['label']}, {_fmt(float(best['mean_dpsi_deg']))}° against the oracle's "
        f"{_fmt(ref)}°, {gap:+.1f}° ({'above' if gap > 0 else 'at or below'} it)."
    )


def _curve(item: SequenceErrors, odometry: str) -> tuple[np.ndarray, np.ndarray] | None:
    """``(seconds, mean δψ of the causal filter)`` of one row under ``odometry``, averaged over
    its seeds and flights at each second fused; None without a filtered run."""
    e = item.errors.get(odometry, {}).get("filter")
    if e is None:
        return None
    err = e["dpsi_deg"].mean(axis=0)
    t = np.round(item.t_s, 6)
    times = np.unique(t)
    return times, np.array([err[t == x].mean() for x in times])


# 20 colours, then the same 20 dash-dotted: every row of the figure its own line style
_STYLES = ("-", "-.", ":")


def sequence_axes(items: list[SequenceErrors]) -> Figure | None:
    """The figure of :func:`sequence_figure`, not saved: a column per long split (every split
    when there is none), a row per odometry (the dataset's, then each stress odometry), a line
    per row of the table (its own colour and style, the same in every panel), one legend below.
    None when there is nothing to draw."""
    long = [i for i in items if i.split.startswith("long/")] or items
    splits = list(dict.fromkeys(i.split for i in long))
    if not splits:
        return None
    odometries = list(dict.fromkeys(o for i in long for o in i.errors if o == "data"))
    odometries += sorted({o for i in long for o in i.errors if o != "data"})
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = list(dict.fromkeys(i.label for i in long))
    palette = plt.get_cmap("tab20").colors
    style = {lab: (palette[n % 20], _STYLES[(n // 20) % 3]) for n, lab in enumerate(labels)}
    rows, cols = len(odometries), len(splits)
    legend_h = 0.17 * math.ceil(len(labels) / 2) + 0.15  # inches: 2 columns of 7 pt entries
    height = 3.2 * rows + legend_h
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols, height), squeeze=False, sharex=True)
    handles = {}
    for r, odo in enumerate(odometries):
        for c, split in enumerate(splits):
            ax = axes[r, c]
            for item in (i for i in long if i.split == split):
                curve = _curve(item, odo)
                if curve is None:
                    continue
                colour, dash = style[item.label]
                (line,) = ax.plot(*curve, dash, color=colour, lw=1.2, label=item.label)
                handles.setdefault(item.label, line)
            name = "the dataset's odometry" if odo == "data" else f"{odo} its noise"
            ax.set_title(f"{split}, {name}", fontsize=9)
            ax.set_ylabel("mean δψ (°), causal filter")
            ax.grid(alpha=0.3)
            if r == rows - 1:
                ax.set_xlabel("seconds of flight fused")
    fig.legend([handles[lab] for lab in labels if lab in handles],
               [lab for lab in labels if lab in handles], loc="lower center", ncol=2,
               fontsize=7, frameon=False)  # fmt: skip
    fig.tight_layout(rect=(0, legend_h / height, 1, 1))
    return fig


def sequence_figure(items: list[SequenceErrors], path: Path) -> bool:
    """Mean δψ of the causal filter against seconds fused, per row, on each long split (or every
    split when there is none), one panel row per odometry (:func:`sequence_axes`), saved to
    ``path``. False when there is nothing to draw."""
    fig = sequence_axes(items)
    if fig is None:
        return False
    import matplotlib.pyplot as plt

    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


def sequence_report(spec: TableSpec, numbers: SequenceTable, out: Path) -> tuple[str, list[Path]]:
    """``(markdown, [figure path])`` of a ``kind: sequence`` spec from its ``numbers``
    (:func:`~benchmark.runner.claims.sequence_errors.sequence_numbers`); the non-learned rows
    are in the table and not in the figure."""
    png = out / f"{spec.name}.png"
    learned = [i for i in numbers.items if i.learned]
    drawn = sequence_figure(learned, png) if learned else False
    text = sequence_markdown(spec, numbers.rows, png.name if drawn else None)
    return text, [png] if drawn else []
