"""Every number a reproduction's report prints, computed before the first report file is written
(issue 41: the report is a writer): the rows of ``results.csv``, each table's cells with their
flight x seed intervals (``claims.table_intervals.summarize``), the sequence tables
(``claims.sequence_errors``) and the claims with their findings. The intervals are independent
work items (one per table, one per split of a sequence table) run in a spawn pool of ``workers``
processes (``execute.work_pool``): the numbers are the same with any number of workers.

``results.csv`` has one row per (table, model, sweep value, split, satellite mode, seed); the
column ``satellite`` says whether the row was measured with each pair's true satellite image
(``true``) or with another place's (``swap``, the satellite-swap probe); ``role`` is ``test`` or
``val`` (the unit's validation split, shown beside the test numbers); ``reference`` names the
non-learned reference of a reference row (``benchmark.runner.execute.reference_rows``; empty
elsewhere); see ``benchmark.runner.report.tables`` for the other columns.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from benchmark.evaluation.metrics import horizontal_metrics
from benchmark.runner.claims.all_claims import evaluate_claims, render_claims
from benchmark.runner.claims.earlier import MergedFrameStore, mark_earlier_claims
from benchmark.runner.claims.evidence import Claim
from benchmark.runner.claims.findings import findings_markdown
from benchmark.runner.claims.frame_errors import FrameStore
from benchmark.runner.claims.sequence_errors import (
    SequenceTable,
    pitch_roll_choices,
    sequence_numbers,
)
from benchmark.runner.claims.spread import prediction_paths
from benchmark.runner.claims.table_intervals import row_interval, summarize
from benchmark.runner.execute.costs import CostRow
from benchmark.runner.execute.non_learned import NonLearnedFusion
from benchmark.runner.execute.reference_rows import ReferenceResults, reference_rows
from benchmark.runner.execute.work_pool import map_work
from benchmark.runner.execute.worker import SATELLITE_MODES, UnitResult, eval_key
from benchmark.runner.plan.partial import STALE_COLUMN, MergePlan
from benchmark.runner.plan.specs import TableSpec
from benchmark.runner.plan.units import CONFIRMS, Unit

# Our metrics the paper does not report, shown under each table; summarised with the rest, so a
# metric added here also gets its interval.
EXTRA_METRICS = [
    "median_dpsi_deg",
    "median_dphi_deg",
    "median_horizontal_m",
    "acc10",
    "acc30",
    "loglik",
    "spearman_unc_err",
]
REPORT_METRICS = [
    "dE_m", "dN_m", "dU_m", "dtheta_deg", "dgamma_deg", "dpsi_deg", "dphi_deg", "acc5",
    *EXTRA_METRICS,
    "swap_dpsi_diff_deg", "swap_dpsi_boot_lo_deg", "swap_dpsi_boot_hi_deg",
    "swap_dphi_diff_deg", "swap_dphi_boot_lo_deg", "swap_dphi_boot_hi_deg", "swap_groups",
    "failure_rate",  # a reference's: its cells say when it failed (tables.row_name, cell_text)
]  # fmt: skip


def results_frame(units: list[Unit], results: dict[str, UnitResult]) -> pd.DataFrame:
    """One row per (job, split, satellite mode) of every finished unit. ``role`` is ``test`` for
    the job's evaluation splits and ``val`` for the unit's validation split
    (``unit.cfg.data.val_split``, when the unit was evaluated on it): choices are made on those."""
    rows = []
    for unit in units:
        result = results.get(unit.key)
        if result is None or not result.ok:
            continue
        val = unit.cfg.data.val_split
        for job in unit.jobs:
            splits = [(split, "test") for split in job.eval_splits]
            if val is not None and val not in job.eval_splits:
                splits.append((val, "val"))
            for split, role in splits:
                for satellite in SATELLITE_MODES:
                    metrics = result.metrics.get(eval_key(split, satellite))
                    if metrics is None:
                        continue
                    rows.append(
                        {"table": job.table, "label": job.label, "paper_model": job.paper_model,
                         "x": job.x, "split": split, "satellite": satellite,
                         "satellite_input": job.row.get("satellite_input"),
                         "train_split": job.train_split, "role": role, "seed": unit.cfg.seed,
                         "unit": unit.key, "train_seconds": result.seconds, **metrics}
                    )  # fmt: skip
    return pd.DataFrame(rows)


# Six significant digits: what results.csv stores and what every table is rendered from.
RESULTS_FLOAT_FORMAT = "%.6g"


@dataclass(frozen=True)
class ReportInputs:
    """What the report reads besides the units' results, all computed by the reproduction before
    the first file is written (``benchmark.runner.reproduction``), so that writing computes
    nothing: the constant predictor's rows and per-frame tables
    (``execute.reference_rows.constant_rows``), the
    non-learned references' evaluations (``execute.reference_rows.plan_references``: work items, the
    constant's frames included), the heading-cue audit's rows (``execute.audit``), the
    non-learned rows fused along the flights per sequence spec (``execute.non_learned``), the
    provenance record (``execute.provenance``: the units' weight and prediction digests) and
    Table 6's measurements (``execute.costs``)."""

    constant_rows: list[dict]
    constant_frames: dict[tuple[str, str], pd.DataFrame]
    references: ReferenceResults
    audit_rows: list[dict]
    non_learned: dict[str, list[NonLearnedFusion]]
    provenance: dict  # execute.provenance.collect_provenance of today's and the kept live units
    costs: dict[str, list[CostRow]]  # per cost spec: execute.costs.measure_costs's rows


def validation_splits(frame: pd.DataFrame) -> dict[str, str]:
    """``{training split: its validation split}`` of the units measured on one
    (:func:`results_frame`'s ``role == "val"`` rows): the constant predictor gets validation
    rows only where trained models have them too."""
    val = frame[frame["role"] == "val"] if len(frame) else frame
    return dict(zip(val.get("train_split", []), val.get("split", []), strict=True))


def _claims_section(
    summaries: dict[str, pd.DataFrame],
    units: list[Unit],
    data_root: Path,
    workdir: Path | None,
    plan: MergePlan | None = None,
) -> tuple[str, str, list[Claim]]:
    """The findings (generated from the verdicts, so prose cannot drift from the numbers) and the
    claims table, decided on per-frame errors (``FrameStore`` over ``workdir``). Without a
    workdir there are no per-frame errors and both say so. A claim that needs a table kept from
    an earlier run (``plan.kept``) is not decided: it reads
    :data:`~benchmark.runner.plan.partial.EARLIER` (``MergedFrameStore``)."""
    if workdir is None:
        missing = (
            "Claims not evaluated: verdicts are decided on per-frame errors, and no work "
            "directory with the units' predictions was given."
        )
        return missing, missing, []
    kept = plan.kept if plan is not None else []
    if kept:
        store = MergedFrameStore(workdir, data_root, units, kept, plan.earlier_specs)
    else:
        store = FrameStore(workdir, data_root, units)
    claims = evaluate_claims(summaries, store, CONFIRMS)
    if kept:
        mark_earlier_claims(claims, plan)
    earlier = {t.name: t.commit for t in kept}
    return findings_markdown(claims, earlier), render_claims(claims), claims


def with_horizontal_errors(
    frame: pd.DataFrame, workdir: Path | None, references: ReferenceResults | None
) -> pd.DataFrame:
    """``frame`` with ``horizontal_m`` and ``median_horizontal_m`` filled where a row lacks
    them, from its per-frame errors: a model's predictions in ``workdir`` (rows with ``unit``), a
    reference's frames in its table (rows with ``reference``,
    :meth:`~benchmark.runner.execute.reference_rows.ReferenceResults.table_frame`).

    Units trained before these metrics existed (read back from the tracking store or an earlier
    ``results.csv``) then show them too; rows of tables kept from an earlier run, whose
    predictions are elsewhere, stay empty."""
    columns = ("horizontal_m", "median_horizontal_m")
    frame = frame.copy()
    for column in columns:
        if column not in frame:
            frame[column] = np.nan
    missing = frame["median_horizontal_m"].isna()
    for i in frame.index[missing]:
        row = frame.loc[i]
        errors = None
        reference = row.get("reference")
        if isinstance(reference, str) and reference and references is not None:
            errors = references.table_frame(
                reference, row["split"], row["satellite"], row["train_split"]
            )
        elif workdir is not None and (paths := prediction_paths(frame.loc[[i]], workdir)):
            errors = pd.read_csv(paths[0], usecols=["dE_m", "dN_m"])
        if errors is not None:
            for column, value in horizontal_metrics(errors).items():
                frame.at[i, column] = value
    return frame


def _as_written(frame: pd.DataFrame) -> pd.DataFrame:
    """``frame`` with every float rounded as ``results.csv`` stores it
    (:data:`RESULTS_FLOAT_FORMAT`).

    The tables are rendered from these values, so a table rendered today and the same table
    rendered again from ``results.csv`` by a later partial rerun say the same digits: a value
    such as 94.17450x would print 94.175 from the full float and 94.174 from its stored 94.1745
    (the binary double of 94.1745 lies just below it)."""
    frame = frame.copy()
    for column in frame.columns:
        if pd.api.types.is_float_dtype(frame[column]):
            frame[column] = [float(RESULTS_FLOAT_FORMAT % v) for v in frame[column]]
    return frame


def _with_stale_column(frame: pd.DataFrame) -> pd.DataFrame:
    """``frame`` with the column ``stale_from`` (``""`` for rows this report decides) right
    after ``unit``."""
    frame = frame.copy()
    frame[STALE_COLUMN] = frame[STALE_COLUMN].fillna("") if STALE_COLUMN in frame else ""
    columns = [c for c in frame.columns if c != STALE_COLUMN]
    at = columns.index("unit") + 1 if "unit" in columns else len(columns)
    return frame[[*columns[:at], STALE_COLUMN, *columns[at:]]]


@dataclass(frozen=True)
class ReportNumbers:
    """What :func:`report_numbers` computed: ``everything`` (the rows of ``results.csv``, as
    written), ``show_val`` (a model was measured on a validation split: every table shows its
    columns), ``summaries`` (per table of today's and the kept live specs but the sequence
    tables: its cells with their intervals, ``summarize``), ``sequences`` (per ``kind:
    sequence`` spec: its own numbers) and the claims with the findings and the claims table
    generated from them."""

    everything: pd.DataFrame
    show_val: bool
    summaries: dict[str, pd.DataFrame]
    sequences: dict[str, SequenceTable]
    findings_md: str
    claims_md: str
    claims: list[Claim]


# The state every work item of a process reads, set once per process (``_set_state``).
_STATE: dict = {}


def _set_state(state: dict) -> None:
    _STATE.clear()
    _STATE.update(state)


def _summary(name: str) -> pd.DataFrame:
    everything, metrics = _STATE["everything"], _STATE["metrics"]
    part = everything[everything["table"] == name] if len(everything) else everything
    if not len(part):
        return pd.DataFrame()
    workdir, frames, references = _STATE["workdir"], _STATE["frames"], _STATE["references"]
    return summarize(
        part, metrics, lambda rows: row_interval(rows, metrics, workdir, frames, references)
    )


def _sequence(name: str, split: str) -> SequenceTable:
    spec, choices = _STATE["specs"][name], _STATE["choices"][name]
    non_learned = _STATE["non_learned"].get(name, [])
    return sequence_numbers(
        spec, _STATE["units"], _STATE["workdir"], non_learned, (split,), choices
    )


def _item(item: tuple[str, str, str]) -> pd.DataFrame | SequenceTable:
    """One work item: ``("summary", table, "")`` or ``("sequence", table, split)``."""
    kind, name, split = item
    return _summary(name) if kind == "summary" else _sequence(name, split)


def report_numbers(
    specs: list[TableSpec],
    units: list[Unit],
    results: dict[str, UnitResult],
    data_root: Path,
    workdir: Path | None,
    *,
    merge: MergePlan,
    inputs: ReportInputs,
    workers: int = 1,
    quiet: bool = False,
) -> ReportNumbers:
    """Every number of the report of ``specs`` (and of the tables ``merge`` keeps live) from
    the units' ``results``, their per-frame predictions under ``workdir`` (without it the cells
    keep the Student-t interval over seeds and no claim is decided) and ``inputs``. The tables'
    intervals run as work items in ``workers`` processes; the claims after them, in this process
    (decided on the per-frame errors; the summaries are passed along for context)."""
    frame = results_frame(units, results)
    references = inputs.references
    parts = (frame, pd.DataFrame(inputs.constant_rows),
             pd.DataFrame(reference_rows(specs, references)), merge.rows())  # fmt: skip
    everything = _as_written(
        with_horizontal_errors(
            _with_stale_column(
                pd.concat([x for x in parts if len(x)] or [frame], ignore_index=True)
            ),
            workdir,
            references,
        )
    )
    metrics = [m for m in REPORT_METRICS if m in everything.columns]
    every_spec = {s.name: s for s in [*specs, *merge.live]}
    planned = [*units, *merge.live_units]
    sequence_items = [
        ("sequence", spec.name, split)
        for spec in every_spec.values()
        if spec.kind == "sequence" and workdir is not None
        for split in spec.all_eval_splits()
    ]
    # A sequence table prints its own numbers (the sequence items), not a summary of its rows;
    # the sequence splits first: the longest items, so the pool ends together.
    summary_items = [("summary", n, "") for n, s in every_spec.items() if s.kind != "sequence"]
    items = [*sequence_items, *summary_items]
    choices = {  # made once: every split of a sequence table reads the same
        name: pitch_roll_choices(spec, planned, workdir)
        for name, spec in every_spec.items()
        if spec.kind == "sequence" and workdir is not None
    }
    state = {
        "everything": everything, "metrics": metrics, "workdir": workdir,
        "frames": inputs.constant_frames, "references": references, "specs": every_spec,
        "units": planned, "non_learned": inputs.non_learned, "choices": choices,
    }  # fmt: skip
    done = map_work(
        _item, items, workers, label="intervals", name=lambda i: " ".join(i[1:]).strip(),
        quiet=quiet, initializer=_set_state, initargs=(state,),
    )  # fmt: skip
    summaries: dict[str, pd.DataFrame] = {}
    pieces: dict[str, list[SequenceTable]] = {}
    for (kind, name, _), value in zip(items, done, strict=True):
        if kind == "summary":
            summaries[name] = value
        else:
            pieces.setdefault(name, []).append(value)
    sequences = {
        name: SequenceTable(
            [i for p in parts for i in p.items],
            pd.concat([p.rows for p in parts], ignore_index=True),
        )
        for name, parts in pieces.items()
    }
    for name, spec in every_spec.items():  # a sequence table without a work directory
        if spec.kind == "sequence" and name not in sequences:
            sequences[name] = SequenceTable([], pd.DataFrame())
    findings_md, claims_md, claims = _claims_section(summaries, planned, data_root, workdir, merge)
    show_val = bool(len(frame) and (frame["role"] == "val").any())
    return ReportNumbers(everything, show_val, summaries, sequences, findings_md, claims_md, claims)
