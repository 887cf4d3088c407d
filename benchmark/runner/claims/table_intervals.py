"""The numbers of a table row with their intervals (:func:`summarize`): its cells and, on a
``swap`` row, the satellite-swap effect (:func:`row_interval`). Functions of results, computed
before the report is written (``benchmark.runner.claims.report_numbers``); the report renders
them.

Cells: the flight x seed bootstrap of ``benchmark.runner.claims.spread`` (a model's predictions
CSVs, the constant predictor's per-frame table, a reference's frames in its table).

The swap effect (swapped minus true error per frame) gets the interval the claims give it
(``benchmark.runner.claims.satellite.swap_rise``): each seed's swapped and true errors paired on
the same frames, then :data:`~benchmark.runner.claims.evidence.N_BOOT` replicates that resample
the flights and the seeds together (``spread.seed_flight_bootstrap`` of the per-seed rises, seed
0: the claims' draws). A table and a claim about the same model and split therefore print the
same interval; the seeds' own flight-bootstrap bounds (``results.csv``) are never averaged into
one (:func:`summarize`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

from benchmark.evaluation.metrics import seed_interval
from benchmark.evaluation.paired import SWAP_ERRORS
from benchmark.runner.claims.evidence import N_BOOT
from benchmark.runner.claims.spread import (
    CELL_METRICS,
    cell_interval,
    frame_interval,
    prediction_paths,
    read_frames,
    seed_flight_bootstrap,
)
from benchmark.runner.execute.reference_rows import ReferenceResults

GROUP_KEYS = [
    "table", "label", "paper_model", "x", "split", "satellite", "satellite_input", "train_split",
    "role",
]  # fmt: skip
# Rows of a table: one per group of results rows (the seeds of one model on one split).
SWAP_EFFECTS = (("dpsi", "δψ"), ("dphi", "δφ"))  # (error, its symbol in the tables)
# The swap effect's interval: the claims' joint flight x seed bootstrap, given by ``resolve``
# (:func:`row_interval`); the mean of the seeds' own bounds is none.
SWAP_BOUNDS = tuple(f"swap_{e}_boot_{end}_deg" for e, _ in SWAP_EFFECTS for end in ("lo", "hi"))


def swap_interval(true: pd.DataFrame, swap: pd.DataFrame) -> dict[str, float]:
    """The swap effect's bounds from the per-frame errors of the same frames with the true and
    the swapped satellite image (:func:`~benchmark.runner.claims.spread.read_frames`-like tables:
    ``index``, ``flight``, ``dpsi_deg``, ``dphi_deg`` and ``seed_pos`` when several seeds):
    ``swap_<e>_boot_lo_deg`` / ``_hi_deg`` for ``e`` in ``dpsi``, ``dphi`` (the claims' joint
    flight x seed bootstrap of the per-seed rises) and ``swap_groups`` (flights). Raises
    ValueError when the two tables hold other frames."""
    true, swap = _by_seed(true), _by_seed(swap)
    keys = ["seed_pos", "index", "flight"]
    if not true[keys].reset_index(drop=True).equals(swap[keys].reset_index(drop=True)):
        raise ValueError("swap_interval: the true and swapped evaluations hold other frames")
    seeds = sorted(true["seed_pos"].unique())
    flights = true.loc[true["seed_pos"] == seeds[0], "flight"].to_numpy()
    out = {"swap_groups": float(len(np.unique(flights)))}
    for column, short in SWAP_ERRORS:
        rise = np.stack(
            [
                swap.loc[swap["seed_pos"] == s, column].to_numpy(np.float64)
                - true.loc[true["seed_pos"] == s, column].to_numpy(np.float64)
                for s in seeds
            ]
        )
        _, lo, hi = seed_flight_bootstrap(rise, flights, n_boot=N_BOOT)
        out[f"swap_{short}_boot_lo_deg"], out[f"swap_{short}_boot_hi_deg"] = lo, hi
    return out


def _by_seed(frame: pd.DataFrame) -> pd.DataFrame:
    """``frame`` with ``seed_pos`` (0 for one seed) and sorted by seed, then frame ``index``."""
    if "seed_pos" not in frame:
        frame = frame.assign(seed_pos=0)
    return frame.sort_values(["seed_pos", "index"], kind="stable")


def model_swap_interval(part: pd.DataFrame, workdir: Path | None) -> dict[str, float] | None:
    """:func:`swap_interval` of a trained row's ``swap`` results (``part``: one per seed) from its
    predictions CSVs under ``workdir``, the seeds in seed order as the claims take them (None
    without them)."""
    if workdir is None or part.empty:
        return None
    part = part.sort_values("seed") if "seed" in part else part
    swapped = prediction_paths(part, workdir)
    true = prediction_paths(part.assign(satellite="true"), workdir)
    if swapped is None or true is None:
        return None
    columns = tuple(c for c, _ in SWAP_ERRORS)
    return swap_interval(read_frames(true, columns), read_frames(swapped, columns))


def reference_swap_interval(
    part: pd.DataFrame, references: ReferenceResults
) -> dict[str, float] | None:
    """:func:`swap_interval` of a reference row's ``swap`` result from its frames in its table
    (None without them)."""
    first = part.iloc[0]
    where = (str(first["label"]), str(first["split"]))
    train = str(first["train_split"])
    true = references.frame_of(*where, "true", train)
    swapped = references.frame_of(*where, "swap", train)
    if true is None or swapped is None:
        return None
    return swap_interval(true, swapped)


def reference_interval(
    part: pd.DataFrame, metrics: list[str], references: ReferenceResults
) -> dict | None:
    """The flight bootstrap bounds of a reference row (``part``: its one results row) from its
    per-frame table in its table, as a model's (None for any other row, or without the
    table)."""
    wanted = [m for m in metrics if m in CELL_METRICS]
    if part.empty or not wanted or not is_reference(part):
        return None
    first = part.iloc[0]
    frame = references.frame_of(
        str(first["label"]), str(first["split"]), str(first["satellite"]), str(first["train_split"])
    )
    if frame is None or "flight" not in frame:
        return None
    return frame_interval(frame, wanted)


def is_reference(part: pd.DataFrame) -> bool:
    """Whether the results rows ``part`` are a non-learned reference's (column ``reference``)."""
    if part.empty or "reference" not in part:
        return False
    name = part.iloc[0]["reference"]
    return isinstance(name, str) and bool(name)


def row_interval(
    part: pd.DataFrame,
    metrics: list[str],
    workdir: Path | None,
    constant_frames: dict[tuple[str, str], pd.DataFrame],
    references: ReferenceResults,
) -> dict | None:
    """Everything :func:`summarize` may replace for one table row
    (``part``: its results rows): the cells' bounds, and on a ``swap`` row the swap effect's
    (:func:`model_swap_interval`, :func:`reference_swap_interval`); None when neither has
    per-frame errors."""
    out = reference_interval(part, metrics, references) or cell_interval(
        part, metrics, workdir, constant_frames
    )
    if part.empty or part.iloc[0].get("satellite") != "swap":
        return out
    if is_reference(part):
        effect = reference_swap_interval(part, references)
    else:
        effect = model_swap_interval(part, workdir)
    return {**(out or {}), **effect} if effect else out


def interval95(values: np.ndarray) -> tuple[float, float, float]:
    """``(mean, low, high)`` over the finite values: Student-t 95% interval of the mean (NaN
    bounds for one value, all NaN for none)."""
    values = np.asarray(values, dtype=float)
    values = values[np.isfinite(values)]
    if len(values) == 0:
        return math.nan, math.nan, math.nan
    interval = seed_interval(values, 0.95)
    return interval.mean, interval.low, interval.high


Resolver = Callable[[pd.DataFrame], "dict[str, float | str] | None"]


def summarize(
    results: pd.DataFrame, metrics: list[str], resolve: Resolver | None = None
) -> pd.DataFrame:
    """One row per (table, label, x, split, satellite, ..., role): ``<m>`` (mean over seeds),
    ``<m>_lo``, ``<m>_hi`` (95% Student-t interval over seeds), ``n_seeds`` and ``interval``
    (``seed t`` or ``none``). ``resolve(part)``, given a row's results (one per seed), may return
    better bounds (``<m>_lo``/``<m>_hi``, ``interval``, ``n_flights``) that replace these, e.g.
    :func:`row_interval`. The swap effect's bounds
    (:data:`SWAP_BOUNDS`) of several seeds are left empty unless ``resolve`` gives them: a mean
    of the seeds' own interval bounds is no interval."""
    rows = []
    keys = [k for k in GROUP_KEYS if k in results.columns]
    for group, part in results.groupby(keys, dropna=False, sort=False):
        row = dict(zip(keys, group, strict=True))
        row["n_seeds"] = int(part["seed"].nunique()) if "seed" in part else len(part)
        for m in metrics:
            if m in part:
                row[m], row[f"{m}_lo"], row[f"{m}_hi"] = interval95(part[m].to_numpy())
        row["interval"] = "seed t" if row["n_seeds"] > 1 else "none"
        if row["n_seeds"] > 1:
            row.update({k: math.nan for k in SWAP_BOUNDS if k in row})
        better = resolve(part) if resolve is not None else None
        row.update(better or {})
        rows.append(row)
    return pd.DataFrame(rows)
