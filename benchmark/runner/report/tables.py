"""Render results next to the paper's numbers: Markdown tables, CSV and figures.

Input is the long results table the runner writes (one row per table, spec row, sweep value, split,
satellite mode and seed; metric columns named as in ``reports/paper_tables.csv``: ``dE_m``,
``dtheta_deg``...). ``satellite`` is ``true`` (each pair's own satellite image) or ``swap`` (the
satellite-swap probe: another place's image); the ``swap`` rows of trained models also hold the
paired swap effect ``swap_<dpsi|dphi>_diff_deg`` with each seed's 95% flight-bootstrap interval
``swap_<e>_boot_lo_deg`` / ``_hi_deg`` (the tables show the claims' joint flight x seed interval
instead: ``claims.table_intervals``). ``satellite_input`` is ``image``, ``blank`` (the
UAV-only control) or ``none`` (the constant predictor); ``train_split`` the split a row was
trained on; ``role`` is ``test`` or ``val`` (the unit's validation split, on which choices are
made; the tables show it beside the test numbers).

A cell is the mean over seeds. Its 95% interval is the flight x seed bootstrap of
``benchmark.runner.claims.spread`` when the caller passes per-frame errors (``summarize(...,
resolve=)``), else the Student-t interval over seeds; with one seed and no per-frame errors, only
the value.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from benchmark.runner.claims.evidence import N_BOOT as CLAIMS_N_BOOT
from benchmark.runner.claims.satellite import MIN_RISE_DEG
from benchmark.runner.claims.table_intervals import SWAP_EFFECTS
from benchmark.runner.execute.reference_rows import CONSTANT_LABEL, fails_text, failure_percent
from benchmark.runner.plan.specs import TableSpec

METRIC_LABELS: dict[str, str] = {
    "dE_m": "δE (m)",
    "dN_m": "δN (m)",
    "dU_m": "δU (m)",
    "dtheta_deg": "δθ pitch (°)",
    "dgamma_deg": "δγ roll (°)",
    "dpsi_deg": "δψ yaw (°)",
    "dphi_deg": "δφ geodesic (°)",
    "median_dphi_deg": "median δφ (°)",
    "median_dpsi_deg": "median δψ (°)",
    "median_horizontal_m": "median horizontal error (m)",
    "acc5": "acc@5°",
    "acc10": "acc@10°",
    "acc30": "acc@30°",
    "loglik": "log-lik",
    "spearman_unc_err": "ρ(unc, err)",
    "size_MB": "size (MB)",
    "MFLOPs": "MFLOPs",
}
# Metrics shown on the validation split beside the test numbers (those of a spec's metrics).
VAL_METRICS = ("dpsi_deg", "dphi_deg", "dE_m", "dN_m")
NO_VAL = "–"  # a model whose training split has no validation split (the height splits)
ONE_FLIGHT = "one flight: no interval"
NO_INTERVAL = "no interval (no per-frame errors)"


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
    role: str = "test",
) -> pd.Series | None:
    """The summary row of (label, split, satellite mode[, train split], role), or None."""
    if summary.empty or "label" not in summary:
        return None
    rows = summary[(summary["label"] == label) & (summary["split"] == split)]
    if "satellite" in rows:
        rows = rows[rows["satellite"] == satellite]
    if train_split is not None and "train_split" in rows:
        rows = rows[rows["train_split"] == train_split]
    if "role" in rows:
        rows = rows[rows["role"].fillna("test") == role]
    return rows.iloc[0] if len(rows) else None


def pick_val(
    summary: pd.DataFrame, label: str, train_split: str, x: object = None
) -> pd.Series | None:
    """The validation row (true satellite image) of the model ``label`` trained on
    ``train_split`` (at sweep value ``x``), or None when there is none."""
    if summary.empty or "role" not in summary:
        return None
    rows = summary[
        (summary["role"] == "val") & (summary["label"] == label)
        & (summary["train_split"] == train_split) & (summary["satellite"] == "true")
    ]  # fmt: skip
    if x is not None:
        rows = rows[rows["x"].astype(str) == str(x)]
    return rows.iloc[0] if len(rows) else None


def has_val(summary: pd.DataFrame) -> bool:
    """Whether any validation rows were measured (older runs evaluated test splits only)."""
    return not summary.empty and "role" in summary and bool((summary["role"] == "val").any())


def val_metrics(spec: TableSpec, summary: pd.DataFrame, show: bool | None = None) -> list[str]:
    """The metrics shown on the validation split beside the test numbers: those of
    :data:`VAL_METRICS` in the spec when ``show`` (default: when the summary has validation rows;
    a reproduction that measured them elsewhere passes True so that a table whose models have no
    validation split shows ``–``)."""
    show = has_val(summary) if show is None else show
    return [m for m in spec.metrics if m in VAL_METRICS] if show else []


def val_cell(
    row: pd.Series | None,
    m: str,
    train_split: str,
    val_splits: dict[str, str],
    missing: str = "not run",
) -> str:
    """A validation cell: the value, ``–`` when ``train_split`` has no validation split."""
    if row is None:
        return missing if train_split in val_splits else NO_VAL
    return cell_text(row, m, missing)


def val_splits_of(summary: pd.DataFrame) -> dict[str, str]:
    """``train split -> its validation split`` as measured (``standard/train -> standard/val``)."""
    if not has_val(summary):
        return {}
    rows = summary[summary["role"] == "val"]
    return dict(zip(rows["train_split"], rows["split"], strict=True))


def uses_satellite(swap_row: pd.Series | None) -> str | None:
    """Verdict of the swap probe for one model. An error "rises" when the 95% flight-bootstrap
    interval of its per-frame difference (swapped minus true) lies above zero and the mean rise is
    at least ``MIN_RISE_DEG`` (a statistically clear rise of 0.01 deg is no use of the image).
    ``yes`` when the yaw and the geodesic errors both rise, ``yaw only`` / ``geodesic only`` when
    one does, ``no`` otherwise; ``one flight`` when the test set holds a single flight (no interval
    over flights); :data:`NO_INTERVAL` with the mean rises but no interval; None without the
    numbers."""
    if swap_row is None:
        return None
    if swap_row.get("swap_groups", 2) < 2:
        return ONE_FLIGHT
    keys = [(f"swap_{e}_boot_lo_deg", f"swap_{e}_diff_deg") for e, _ in SWAP_EFFECTS]
    values = [(swap_row.get(lo, math.nan), swap_row.get(d, math.nan)) for lo, d in keys]
    if not all(_finite(d) for _, d in values):
        return None
    if not all(_finite(lo) for lo, _ in values):
        return NO_INTERVAL
    yaw, geo = (lo > 0 and d >= MIN_RISE_DEG for lo, d in values)
    return {(True, True): "yes", (True, False): "yaw only", (False, True): "geodesic only"}.get(
        (yaw, geo), "no"
    )


def _finite(x: object) -> bool:
    return isinstance(x, float | int) and math.isfinite(x)


def failure_rate(row: pd.Series | None) -> float:
    """The fraction of frames on which a reference row's estimate failed (NaN for any other row:
    a model or the constant predictor always answers)."""
    if row is None:
        return math.nan
    rate = row.get("failure_rate", math.nan)
    return float(rate) if isinstance(rate, float | int) else math.nan


def fails_everywhere(row: pd.Series | None) -> bool:
    """Whether ``row`` is a reference that failed on every frame: its numbers are the constant
    row's, no estimate of its own, so its cells say so instead (:func:`cell_text`)."""
    return failure_rate(row) >= 1.0


def cell_text(row: pd.Series | None, m: str, missing: str = "not run") -> str:
    """``mean ± half-width`` of metric ``m`` in a summary row; ``missing`` without the row
    (``not run``, or ``failed`` for a row whose training failed); ``fails on 100 % of frames``
    for a reference that failed on every frame."""
    if row is None or m not in row:
        return missing
    if fails_everywhere(row):
        return fails_text(1.0)
    return format_value(row[m], row[f"{m}_lo"], row[f"{m}_hi"])


def row_name(label: str, row: pd.Series | None, swap: pd.Series | None = None) -> str:
    """A table row's model cell: ``label``, and for a reference that failed on some frames (not
    all: those rows say it in every cell) how many, with the swapped image's rate when it
    differs: ``label (fails on 12 % of frames; 30 % with the swapped image)``."""
    rate, swapped = failure_rate(row), failure_rate(swap)
    if not (0 < rate < 1 or 0 < swapped < 1):
        return label
    text = fails_text(rate if math.isfinite(rate) else swapped)
    if math.isfinite(rate) and math.isfinite(swapped) and swapped != rate:
        text += f"; {failure_percent(swapped)} with the swapped image"
    return f"{label} ({text})"


def table_rows(spec: TableSpec, split: str, extra_labels: list[str]) -> list[tuple[str, str, str]]:
    """``(label, paper model, train split)`` of every row evaluated on ``split``."""
    rows = [(j.label, j.paper_model, j.train_split) for j in spec.jobs() if split in j.eval_splits]
    rows += [(x, "", spec.train_split_for(split)) for x in extra_labels]
    return list(dict.fromkeys(rows))


@dataclass(frozen=True)
class TableLayout:
    """The columns of one rendered table: the paper's numbers beside ours (``paper``, with the
    constant predictor's beside them), the validation metrics ``vals``, the split column
    (``multi``), the training split column (``trained_on``) and the paper's row name
    (``paper_row``: some row is shown under another label than the paper model's) and each
    training split's validation split (``val_splits``)."""

    paper: bool
    vals: tuple[str, ...]
    multi: bool
    trained_on: bool
    paper_row: bool
    val_splits: Mapping[str, str] = field(default_factory=dict)  # train split -> its val split

    def header(self, spec: TableSpec) -> list[str]:
        """The header cells: per metric the paper's mean, the constant predictor's and ours
        (paper tables), else ours; the validation column; the swapped-image columns."""
        cells = (["split"] if self.multi else []) + ["model"]
        cells += ["paper's row"] if self.paper_row else []
        cells += ["trained on"] if self.trained_on else []
        for m in spec.metrics:
            label = METRIC_LABELS.get(m, m)
            if self.paper:
                cells += [
                    f"{label} paper (mean)",
                    f"{label} constant (mean)",
                    f"{label} ours (mean)",
                ]
            else:
                cells.append(label)
            cells += [f"{label} val"] if m in self.vals else []
        return cells + [f"{METRIC_LABELS.get(m, m)} swapped sat." for m in spec.swap_metrics]


def markdown_table(
    spec: TableSpec,
    summary: pd.DataFrame,
    paper: pd.DataFrame,
    extra_labels: list[str] = (),
    show_val: bool | None = None,
    failed: frozenset[str] = frozenset(),
    references: list[str] = (),
    shown: Mapping[str, str] | None = None,
) -> str:
    """A Markdown table of one table spec: per metric, the paper's number (paper tables only,
    the paper's means), the constant predictor's mean error beside it and our mean, and (see
    :func:`val_metrics`, ``show_val``) ours on the validation split; then each ``swap_metrics``
    entry measured with the swapped satellite image. Rows of the labels in ``failed`` (every
    training of that row failed) read ``failed``, other missing rows ``not run``.
    ``extra_labels`` (the constant predictor) and then ``references`` (the non-learned
    references' labels) follow the trained rows; the references are in the swap-probe table too
    and are not evaluated on validation splits (``–``). ``shown``: the label a row is shown under
    when its spec label names another model (``benchmark.runner.report.training.shown_labels``;
    the paper's row then gets a column of its own)."""
    shown = dict(shown or {})
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
    with_paper = spec.paper_table is not None
    layout = TableLayout(
        paper=with_paper, vals=tuple(vals), multi=len(spec.all_eval_splits()) > 1,
        trained_on=len(spec.train_splits()) > 1,
        paper_row=with_paper and any(j.label in shown for j in spec.jobs()),
        val_splits=val_splits,
    )  # fmt: skip
    header = layout.header(spec)
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    names = spec.paper_splits or (spec.paper_split,) * len(spec.eval_splits)
    paper_split = dict(zip(spec.eval_splits, names, strict=True))
    for split in spec.all_eval_splits():
        for label, paper_model, train in table_rows(spec, split, [*extra_labels, *references]):
            where = (split, train, paper_split.get(split))
            cells = _row_cells(spec, summary, paper, layout, label, paper_model, where, shown)
            cells = _no_val(cells, header) if label in references else cells
            cells = [("failed" if label in failed else c) if c == "not run" else c for c in cells]
            lines.append("| " + " | ".join(cells) + " |")
    if with_paper:
        lines += ["", constant_beside_paper(spec, summary, paper)]
    if spec.swap_metrics:
        lines += ["", swap_probe_table(spec, summary, failed, list(references), shown)]
    if spec.note:
        lines += ["", spec.note.strip()]
    return "\n".join(lines) + "\n"


def _row_cells(
    spec: TableSpec,
    summary: pd.DataFrame,
    paper: pd.DataFrame,
    layout: TableLayout,
    label: str,
    paper_model: str,
    where: tuple[str, str, str | None],
    shown: Mapping[str, str],
) -> list[str]:
    """The cells of one row (``where``: its split, training split and the paper's name of the
    split); missing numbers read ``not run``."""
    split, train, paper_split = where
    row = pick(summary, label, split, "true", train)
    swap = pick(summary, label, split, "swap", train)
    constant = pick(summary, CONSTANT_LABEL, split, "true", train)
    cells = ([f"`{split}`"] if layout.multi else []) + [
        row_name(shown.get(label, label), row, swap)
    ]
    cells += [paper_model or "–"] if layout.paper_row else []
    cells += [f"`{train}`"] if layout.trained_on else []
    for m in spec.metrics:
        if layout.paper:
            pv = paper_value(paper, spec.paper_table, paper_split, paper_model, m)
            cells += ["–" if not math.isfinite(pv) else f"{pv:.2f}", cell_text(constant, m, "–")]
        cells.append(cell_text(row, m))
        if m in layout.vals:
            val = pick_val(summary, label, train)
            cells.append(val_cell(val, m, train, dict(layout.val_splits)))
    return cells + [cell_text(swap, m) for m in spec.swap_metrics]


def _no_val(cells: list[str], header: list[str]) -> list[str]:
    """A reference row's cells with ``–`` in the validation columns (references are evaluated on
    no validation split: nothing is chosen on them)."""
    return [NO_VAL if h.endswith(" val") else c for c, h in zip(cells, header, strict=True)]


def constant_beside_paper(spec: TableSpec, summary: pd.DataFrame, paper: pd.DataFrame) -> str:
    """The sentence under a table with the paper's numbers: per metric the paper gives here, the
    range of the constant predictor's mean error over the table's splits, the range of the
    paper's numbers and how many of those are at or above the constant's on their split (an error
    the mean pose alone reaches on these data); ``""`` when the paper gives none."""
    names = spec.paper_splits or (spec.paper_split,) * len(spec.eval_splits)
    parts = []
    for m in spec.metrics:
        pairs = []  # (paper's number, the constant's mean on that split)
        for split, paper_split in zip(spec.eval_splits, names, strict=True):
            constant = pick(summary, CONSTANT_LABEL, split, "true", spec.train_split_for(split))
            for job in spec.jobs():
                pv = paper_value(paper, spec.paper_table, paper_split, job.paper_model, m)
                if math.isfinite(pv) and split in job.eval_splits:
                    pairs.append((pv, constant[m] if constant is not None else math.nan))
        consts = [c for _, c in pairs if math.isfinite(c)]
        if not pairs or not consts:
            continue
        ours = [p for p, _ in pairs]
        reached = sum(p >= c for p, c in pairs if math.isfinite(c))
        parts.append(
            f"{METRIC_LABELS.get(m, m)}: constant {_span(consts)}, paper {_span(ours)} "
            f"({reached} of {len(pairs)} paper numbers at or above the constant's on their split)"
        )
    if not parts:
        return ""
    return (
        "Columns *paper (mean)*, *ours (mean)*: the paper's mean errors and ours (mean over the "
        "frames, then over the seeds); every median is named so. Columns *constant (mean)*: the "
        "constant predictor (the training split's mean pose; it reads no image) on the same "
        "split, the error a model reaches by learning nothing, beside each paper number: "
        + "; ".join(parts)
        + "."
    )


def _span(values: list[float]) -> str:
    """``"76.37–98.83"`` (or one value)."""
    lo, hi = min(values), max(values)
    return f"{lo:.2f}" if lo == hi else f"{lo:.2f}–{hi:.2f}"


def swap_probe_table(
    spec: TableSpec,
    summary: pd.DataFrame,
    failed: frozenset[str] = frozenset(),
    references: list[str] = (),
    shown: Mapping[str, str] | None = None,
) -> str:
    """Per trained row, then per non-learned reference (labels ``references``): the paired
    per-frame effect of swapping the satellite image (rows of the labels in ``failed`` read
    ``failed``; ``shown``: labels shown instead, as in :func:`markdown_table`)."""
    shown = shown or {}
    lines = [
        "Satellite-swap probe: each pair's satellite image replaced by another place's (another "
        "centre of the same city; for `generalized/test` another city; for `towns/*` another "
        "town; rules in `benchmark/data/swap.py`), labels unchanged. Δ = swapped minus true "
        "error on the same frames, mean over the training seeds and 95% interval of the claims' "
        f"bootstrap: {CLAIMS_N_BOOT} replicates that resample whole flights and the seeds "
        "together, each seed's swapped and true errors paired on the same frames (so a claim "
        "about a model and this table give the same interval). A model uses the satellite "
        "image when both intervals lie above zero and both mean rises are at least "
        f"{MIN_RISE_DEG:g}°.",
        "",
        "| split | model | δψ true | δψ swapped | Δδψ [95% CI] | δφ true | δφ swapped "
        "| Δδφ [95% CI] | uses the satellite image |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for split in spec.all_eval_splits():
        for label, _, train in table_rows(spec, split, list(references)):
            row = pick(summary, label, split, "true", train)
            swap = pick(summary, label, split, "swap", train)
            cells = [f"`{split}`", row_name(shown.get(label, label), row, swap)]
            gone = "failed" if label in failed else "not run"
            # A reference with no estimate of its own under either image has no swap effect.
            blind = fails_text(1.0) if fails_everywhere(row) or fails_everywhere(swap) else None
            for e, _ in SWAP_EFFECTS:
                cells += [cell_text(row, f"{e}_deg", gone), cell_text(swap, f"{e}_deg", gone)]
                cells.append(blind or (_effect(swap, e) if swap is not None else gone))
            cells.append(blind or uses_satellite(swap) or gone)
            lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _effect(swap: pd.Series | None, e: str) -> str:
    """``+Δ [lo, hi]`` of one swap effect; ``+Δ (no interval)`` without bounds (one flight and
    one seed, or no per-frame errors: the verdict column says which)."""
    mean, lo, hi = (
        swap.get(f"swap_{e}_{k}_deg", math.nan) if swap is not None else math.nan
        for k in ("diff", "boot_lo", "boot_hi")
    )
    if not _finite(mean):
        return "not run"
    if not (_finite(lo) and _finite(hi)):
        return f"{mean:+.2f} (no interval)"
    return f"{mean:+.2f} [{lo:+.2f}, {hi:+.2f}]"


def extra_metrics_table(
    spec: TableSpec,
    summary: pd.DataFrame,
    metrics: list[str],
    shown: Mapping[str, str] | None = None,
) -> str:
    """Our metrics the paper does not report (medians, accuracies, uncertainty quality), those
    the spec's own columns do not already show (``""`` when none is left); ``shown``: labels
    shown instead, as in :func:`markdown_table`."""
    shown = shown or {}
    present = [
        m
        for m in metrics
        if m not in spec.metrics and m in summary.columns and summary[m].notna().any()
    ]
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
        cells = [f"`{r['split']}`", row_name(shown.get(str(r["label"]), str(r["label"])), r)]
        if fails_everywhere(r):
            cells += [fails_text(1.0)] * len(present)
        else:
            cells += [format_value(r[m], r[f"{m}_lo"], r[f"{m}_hi"], 3) for m in present]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def interval_note(summary: pd.DataFrame) -> str:
    """What a cell's number and its ± mean, from the summary's ``n_seeds`` and ``interval``."""
    if summary.empty or "n_seeds" not in summary:
        return "No results yet."
    n = int(summary["n_seeds"].max())
    kinds = set(summary["interval"].dropna()) if "interval" in summary else set()
    seeds = f"over {n} training seeds" if n > 1 else "of one training seed"
    parts = [f"Each cell: the mean {seeds} ± the half-width of its 95% interval."]
    if "flight×seed bootstrap" in kinds:
        parts.append(
            "Every per-frame metric (mean errors δE ... δφ, medians, acc@, log-lik, "
            "ρ(unc, err)): percentile interval of 2000 bootstrap replicates that resample the "
            "test flights (frames of a flight are correlated) and the seeds, both with "
            "replacement, the statistic recomputed on each replicate's frames; the constant "
            "predictor, which has no seed, resamples flights only. A test set of one flight "
            "gives no flight spread: with one seed no interval."
        )
    if n > 1 and "seed t" in kinds:
        parts.append(f"Rows without per-frame files: Student-t interval over the {n} seeds.")
    elif "flight×seed bootstrap" not in kinds:
        parts.append("One seed and no per-frame errors: single values, no interval.")
    return " ".join(parts)


def val_note(val_splits: dict[str, str]) -> str:
    """The table note on the *val* columns, naming each training split's validation split."""
    pairs = ", ".join(f"`{v}` for `{t}`" for t, v in val_splits.items())
    where = f" ({pairs})" if pairs else ""
    return (
        f"Columns *val*: the same model on the validation split of its training data{where}; "
        "profile settings, learning rates and loss terms are chosen on these numbers, never on the "
        f"test splits. `{NO_VAL}`: the training split has no validation split."
    )
