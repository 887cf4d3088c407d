"""Write a reproduction's reports: raw CSV, one Markdown file per table/figure, figures, Table 6
costs and the claim-by-claim summary ``README.md``.

``results.csv`` has one row per (table, model, sweep value, split, satellite mode, seed); the
column ``satellite`` says whether the row was measured with each pair's true satellite image
(``true``) or with another place's (``swap``, the satellite-swap probe); ``role`` is ``test`` or
``val`` (the unit's validation split, shown beside the test numbers); ``reference`` names the
non-learned reference of a reference row (``benchmark.runner.execute.reference_rows``; empty
elsewhere); see ``benchmark.runner.report.tables`` for the other columns. ``provenance.md`` /
``provenance.json`` (``benchmark.runner.report.provenance``) hold the digests to compare a rerun
with."""

from __future__ import annotations

import os
import platform
import time
from dataclasses import dataclass
from importlib.metadata import version as _version
from pathlib import Path

import numpy as np
import pandas as pd

from benchmark.evaluation.metrics import horizontal_metrics
from benchmark.progress import Progress
from benchmark.runner.claims.all_claims import evaluate_claims, render_claims
from benchmark.runner.claims.data_audit import heading_cue_audit_markdown, heading_cue_summary
from benchmark.runner.claims.earlier import MergedFrameStore, mark_earlier_claims
from benchmark.runner.claims.evidence import Claim
from benchmark.runner.claims.findings import findings_markdown
from benchmark.runner.claims.frame_errors import FrameStore
from benchmark.runner.claims.ranking import ranking_markdown
from benchmark.runner.claims.spread import prediction_paths
from benchmark.runner.execute.costs import CostRow
from benchmark.runner.execute.non_learned import NonLearnedFusion
from benchmark.runner.execute.reference_rows import (
    ReferenceResults,
    describe_references,
    reference_labels,
    reference_note,
    reference_rows,
)
from benchmark.runner.execute.worker import SATELLITE_MODES, UnitResult, eval_key
from benchmark.runner.plan.partial import (
    STALE_COLUMN,
    EarlierTable,
    MergePlan,
    in_spec_order,
    mark_earlier_files,
)
from benchmark.runner.plan.repro_profiles import ReproProfile
from benchmark.runner.plan.specs import TableSpec, default_spec_dir
from benchmark.runner.plan.units import CONFIRMS, Unit
from benchmark.runner.report.costs import cost_table
from benchmark.runner.report.intervals import row_interval
from benchmark.runner.report.logbook import Logbook
from benchmark.runner.report.provenance import (
    provenance_summary,
    write_provenance,
)
from benchmark.runner.report.sequence import sequence_report
from benchmark.runner.report.sweeps import sweep_figure, sweep_table
from benchmark.runner.report.tables import (
    CONSTANT_LABEL,
    extra_metrics_table,
    load_paper,
    markdown_table,
    summarize,
)
from benchmark.runner.report.training import relabel_note, shown_labels, table_protocol

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
    non-learned references' evaluations (``execute.reference_rows.evaluate_references``, the
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


def write_reports(
    specs: list[TableSpec],
    units: list[Unit],
    results: dict[str, UnitResult],
    profile: ReproProfile,
    data_root: Path,
    out: Path,
    logbook: Logbook | None,
    invocations: list[dict] | None = None,
    workdir: Path | None = None,
    quiet: bool = False,
    *,
    merge: MergePlan,
    inputs: ReportInputs,
) -> list[Path]:
    """Write every report file under ``out`` from the units' ``results`` and the ``inputs``
    computed before (:class:`ReportInputs`); return their paths.

    ``workdir`` (the reproduction's, holding ``units/<key>/``) gives the per-frame predictions
    for the flight x seed bootstrap intervals and the per-unit digests of ``provenance.md``, and
    holds the Table 6 cache (``costs/``, named in its note). Without it the cells
    keep the Student-t interval over seeds and the provenance records the dataset and software
    only (it says so).

    A reproduction of some tables only (``--only``) merges with what an earlier one wrote to
    ``out`` (``merge``, planned by :func:`~benchmark.runner.plan.partial.plan_merge` before any
    work): the other tables whose units are today's and whose predictions are in ``workdir`` are
    kept, rendered again from their rows and decided again with the re-run ones; the others, from
    an earlier run, are kept as written and marked in their files, ``results.csv`` (``stale_from``),
    the README and ``provenance.json``, their claims not re-decided (``stale="keep"``), or
    removed with their files (``"drop"``). Every file of ``out``, ``results.csv`` and the README
    then describe the same tables. A progress line (stderr, unless ``quiet``) names the table
    being written."""
    out.mkdir(parents=True, exist_ok=True)
    paper = load_paper(default_spec_dir().parent / "paper_tables.csv")
    frame = results_frame(units, results)
    baseline_rows, constant_frames = inputs.constant_rows, inputs.constant_frames
    # The non-learned references (issue 21): a failed frame has its table's constant pose.
    references = inputs.references
    ref_rows = pd.DataFrame(reference_rows(specs, references))
    plan = merge
    kept_specs, kept_units = plan.live, plan.live_units
    parts = (frame, pd.DataFrame(baseline_rows), ref_rows, plan.rows())
    everything = _as_written(
        with_horizontal_errors(
            _with_stale_column(
                pd.concat([x for x in parts if len(x)] or [frame], ignore_index=True)
            ),
            workdir,
            references,
        )
    )
    audit_rows = inputs.audit_rows
    audit_md = heading_cue_audit_markdown(audit_rows)
    written = [out / "results.csv"]
    everything.to_csv(written[0], index=False, float_format=RESULTS_FLOAT_FORMAT)
    metrics = [m for m in REPORT_METRICS if m in everything.columns]
    # Validation columns in every table once any model was measured on a validation split.
    show_val = bool(len(frame) and (frame["role"] == "val").any())
    summaries: dict[str, pd.DataFrame] = {}
    cost_cache = Path(workdir) / "costs" if workdir is not None else None

    def resolve(part: pd.DataFrame) -> dict | None:
        return row_interval(part, metrics, workdir, constant_frames, references)

    def summary_of(name: str) -> pd.DataFrame:
        part = everything[everything["table"] == name] if len(everything) else everything
        return summarize(part, metrics, resolve) if len(part) else pd.DataFrame()

    # The kept live tables are rendered again from their rows (a table of costs, which would be
    # measured again, is kept as it is), so every table file says what results.csv says.
    rendered = [*specs, *(s for s in kept_specs if s.kind != "cost")]
    bar = Progress(len(rendered) + 1, "report", unit="item", enabled=not quiet)
    with bar:
        for spec in rendered:
            bar.update(0, postfix=f"writing {spec.name}")
            part = everything[everything["table"] == spec.name] if len(everything) else everything
            summary = summaries[spec.name] = summary_of(spec.name)
            md_path = out / f"{spec.name}.md"
            paths = [md_path]
            planned = [*units, *plan.live_units]  # today's tables' and those kept live
            shown = shown_labels(spec.name, planned)  # rows shown by what they trained
            if spec.kind == "table":
                gone = frozenset(label for label, _ in failed_jobs(spec.name, units, results))
                gone -= set(part["label"]) if len(part) else set()  # some seeds of it did run
                text = markdown_table(spec, summary, paper, [CONSTANT_LABEL], show_val, gone,
                                      reference_labels(spec), shown)  # fmt: skip
                relabelled = relabel_note(spec.name, planned)
                text += f"\n{relabelled}\n" if relabelled else ""
                text += reference_note(spec, references)
                text += extra_metrics_table(spec, summary, EXTRA_METRICS, shown)
            elif spec.kind == "sequence":  # every head fused along its flights (issue 39)
                text, figures, _ = sequence_report(
                    spec, planned, workdir, out, inputs.non_learned.get(spec.name, [])
                )
                paths += figures
            elif spec.kind == "sweep":
                text = sweep_table(spec, summary, show_val)
                if len(summary):
                    png = out / f"{spec.name}.png"
                    sweep_figure(spec, summary, png, per_seed=part)
                    paths.append(png)
                    text += f"\n![{spec.name}]({png.name})\n"
            else:
                text = cost_table(spec, inputs.costs.get(spec.name, []), cost_cache)
            if spec.kind != "cost":
                text = _with_protocol(text, table_protocol(spec.name, planned, shown))
            md_path.write_text(text + failed_section(spec.name, units, results))
            written += paths
            if logbook is not None and spec in specs:
                logbook.log_table_outputs(spec.name, paths)
            bar.update(1, postfix=f"wrote {spec.name}")
        for spec in kept_specs:  # the earlier tables: their verdicts count too
            summaries[spec.name] = summary_of(spec.name)
        bar.status("deciding the claims (paired flight x seed bootstrap)")
        findings_md, claims_md, claims = _claims_section(
            summaries, [*units, *kept_units], data_root, workdir, plan
        )
        bar.update(1, postfix="claims decided")
    # Kept earlier tables open with a banner naming their run; dropped ones lose their files.
    touched = mark_earlier_files(out, plan)
    written += touched if plan.mode == "keep" else []
    for spec in rendered:  # which representation wins, in the ranked table's own section
        section = ranking_markdown(claims, spec.name)
        if section:
            md = out / f"{spec.name}.md"
            md.write_text(md.read_text() + section)
    (out / "heading_cue.md").write_text(audit_md)
    written.append(out / "heading_cue.md")
    record = dict(inputs.provenance)
    if plan.kept:  # where the tables kept from an earlier run come from, and their digests
        record["earlier_tables"] = {t.name: t.record() for t in plan.kept}
        record["earlier_units"] = plan.earlier_units
    written += write_provenance(record, out)
    readme = out / "README.md"
    audit = heading_cue_summary(audit_rows)
    listed = in_spec_order([*specs, *kept_specs])
    text = _readme(profile, listed, findings_md, claims_md, invocations or [], audit, plan.kept)
    text += plan.markdown()
    text += failed_section(None, units, results)
    readme.write_text(text + provenance_summary(record))
    written.append(readme)
    return written


def failed_jobs(
    table: str | None, units: list[Unit], results: dict[str, UnitResult]
) -> list[tuple[str, str]]:
    """``(row label with sweep value and seed, error's first line)`` of every row of ``table``
    (every table: None) whose unit's training failed in this reproduction."""
    out = []
    for unit in units:
        result = results.get(unit.key)
        if result is None or result.ok:
            continue
        error = (result.error.strip().splitlines() or ["(no message)"])[0][:300]
        for job in unit.jobs:
            if table is None or job.table == table:
                x = f" [{job.x}]" if job.x is not None else ""
                name = job.label if table is not None else f"{job.table}: {job.label}"
                out.append((name, f"{x} seed {unit.cfg.seed}: {error}"))
    return out


def failed_section(table: str | None, units: list[Unit], results: dict[str, UnitResult]) -> str:
    """A Markdown section listing the failed rows (empty when none failed)."""
    rows = failed_jobs(table, units, results)
    if not rows:
        return ""
    lines = ["", "## Failed training runs", "",
             f"{len(rows)} row(s) failed to train (cells read `failed` where no seed of the row "
             "ran); the rest of the reproduction went on. Run the same command again to retry "
             "them:", ""]  # fmt: skip
    lines += [f"- {name}{detail}" for name, detail in rows]
    return "\n".join(lines) + "\n"


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


def _with_protocol(text: str, sentence: str) -> str:
    """``text`` with ``sentence`` as a paragraph under its title line."""
    if not sentence:
        return text
    title, _, rest = text.partition("\n")
    return f"{title}\n\n{sentence}\n{rest}"


def _optim_text(o) -> str:
    return f"{o.epochs} epochs, {o.name} lr {o.lr:g} ({o.lr_schedule}), batch {o.batch_size}"


def profile_protocol(profile: ReproProfile) -> str:
    """How the profile's units train, in words: which encoder, end to end or heads on a frozen
    shared encoder, and with which loss (the report's README names the protocol, issue 21)."""
    googlenet = f"width {profile.width:g} GoogLeNet"
    shared = profile.shared_encoder
    if shared is None:
        encoder = googlenet if profile.encoder == "googlenet" else f"the {profile.encoder} encoder"
        return (
            f"{encoder}, {_optim_text(profile.optim)}; every unit trains end to end (the matching "
            "encoder with its own loss term, every other encoder by the heads' loss only, the "
            "paper's protocol)."
        )
    heads = shared.heads_optim or profile.optim
    return (
        f"rows that name no encoder use the {profile.encoder} encoder, trained once per seed end "
        f"to end on `{shared.train_split}` with {shared.attitude} and regression heads and the "
        f"encoder's own loss (the NLL of its pose volume at the true pose and the gravity "
        f"branch's error; {_optim_text(shared.optim)}); each such row then trains only its heads "
        f"on that encoder's frozen features ({_optim_text(heads)}). Rows that name the paper's "
        f"GoogLeNet (Fig. 9, the encoders table) train it end to end at {googlenet} by the heads' "
        f"loss only, the paper's protocol ({_optim_text(profile.optim)})."
    )


def _readme(
    profile: ReproProfile,
    specs: list[TableSpec],
    findings_md: str,
    claims_md: str,
    runs: list[dict],
    audit: str,
    earlier: list[EarlierTable] = (),
) -> str:
    cpu = platform.processor() or platform.machine()
    lines = [
        f"# uavbench reproduction: profile `{profile.name}`",
        "",
        f"Written {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())} on {platform.node()} "
        f"({cpu}, {os.cpu_count()} cores, torch {_version('torch')}).",
        "",
        "Invocations that produced these results (wall time: simulation, training and "
        "evaluation, before the reports):",
        "",
        "| started (UTC) | state | wall time | training runs executed | machine | git commit |",
        "|---|---|---|---|---|---|",
    ]
    for r in runs:  # benchmark.runner.plan.invocations.read_invocations
        failed = f", {r['failed']} failed" if r.get("failed") else ""
        wall = f"{r['wall_s'] / 60:.1f} min"
        state = r.get("state", "finished")
        if state not in ("finished", "failed", "interrupted"):
            wall += " (to its last finished run)"  # killed or still running: no end record
        lines.append(
            f"| {r['started']} | {state} | {wall} | {r['trained']} of {r['units']}{failed} | "
            f"{r['machine']} | `{r['git_commit']}` |"
        )
    lines += [
        "",
        f"Profile: {profile_protocol(profile)} Dataset profile "
        f"`{profile.dataset}` rendered by the uavbench simulator (not Google Earth imagery).",
        "",
        "## Findings",
        "",
        "Generated from the verdicts of the claims table below (numbers as printed there).",
        "",
        findings_md.rstrip(),
        "",
        "## Claims of the paper, checked",
        "",
        claims_md,
        "",
        audit,
        "",
        "## Tables and figures",
        "",
    ]
    entries = {s.name: f"- [{s.name}]({s.name}.md): {s.title}" for s in specs}
    for t in earlier:  # kept as written by an earlier run: said on the line itself
        entries[t.name] = (
            f"- [{t.name}]({t.name}.md): {t.title} (**from an earlier run {t.at}, not "
            "re-decided**: see *Partial rerun* below)"
        )
    lines += [entries[name] for name in sorted(entries)]
    with_refs = [s for s in specs if s.kind == "table" and s.references]
    if with_refs:
        names = list(dict.fromkeys(n for s in with_refs for n in s.references))
        lines += ["", "Non-learned rows beside the models in "
                  + ", ".join(f"[{s.name}]({s.name}.md)" for s in with_refs)
                  + ": the constant predictor (the training split's mean pose, no image) and "
                  "the references (issue 21), evaluated like the models and part of no claim "
                  "about the heads:", ""]  # fmt: skip
        lines += [f"- {line}." for line in describe_references(names)]
    lines += ["", "Raw numbers: [results.csv](results.csv) (one row per table, model, sweep value, "
              "split, satellite mode and seed; column `satellite`: `true` = each pair's own "
              "satellite image, `swap` = another place's, the satellite-swap probe; the `swap` "
              "rows hold the paired swap effect `swap_dpsi_diff_deg`, `swap_dphi_diff_deg` with "
              "that row's own 95% flight-bootstrap bounds `swap_*_boot_lo_deg`, "
              "`swap_*_boot_hi_deg` (the tables give the claims' flight x seed interval); "
              "column `satellite_input`: `blank` marks the UAV-only control; column `role`: "
              "`test`, or `val` for the validation split of the training data; column "
              "`reference`: the non-learned reference's name on its rows, empty on the models' "
              "and the constant predictor's (`satellite_input` `none`); column "
              "`stale_from`: empty for rows this report decides, else the git commit of the "
              "earlier run a kept table comes from)."]  # fmt: skip
    return "\n".join(lines) + "\n"
