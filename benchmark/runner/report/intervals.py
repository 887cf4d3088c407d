"""The intervals of a table row: its cells and, on a ``swap`` row, the satellite-swap effect.

Cells: the flight x seed bootstrap of ``benchmark.runner.claims.spread`` (a model's predictions
CSVs, the constant predictor's per-frame table, a reference's frames in its table).

The swap effect (swapped minus true error per frame) gets the interval the claims give it
(``benchmark.runner.claims.satellite.swap_rise``): each seed's swapped and true errors paired on
the same frames, then :data:`~benchmark.runner.claims.evidence.N_BOOT` replicates that resample
the flights and the seeds together (``spread.seed_flight_bootstrap`` of the per-seed rises, seed
0: the claims' draws). A table and a claim about the same model and split therefore print the
same interval; the seeds' own flight-bootstrap bounds (``results.csv``) are never averaged into
one (``benchmark.runner.report.tables.summarize``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

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
    """Everything :func:`~benchmark.runner.report.tables.summarize` may replace for one table row
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
