"""Write a reproduction's reports: raw CSV, one Markdown file per table/figure, figures, Table 6
costs and the claim-by-claim summary ``README.md``, from numbers computed before
(``benchmark.runner.claims.report_numbers``, whose docstring describes ``results.csv``).
``provenance.md`` / ``provenance.json`` (``benchmark.runner.report.provenance``) hold the
digests to compare a rerun with."""

from __future__ import annotations

import os
import platform
import time
from importlib.metadata import version as _version
from pathlib import Path

import pandas as pd

from benchmark.progress import Progress
from benchmark.runner.claims.data_audit import heading_cue_audit_markdown, heading_cue_summary
from benchmark.runner.claims.ranking import ranking_markdown
from benchmark.runner.claims.report_numbers import (
    EXTRA_METRICS,
    RESULTS_FLOAT_FORMAT,
    ReportInputs,
    ReportNumbers,
)
from benchmark.runner.execute.reference_rows import (
    describe_references,
    reference_labels,
    reference_note,
)
from benchmark.runner.execute.worker import UnitResult
from benchmark.runner.plan.partial import (
    EarlierTable,
    MergePlan,
    in_spec_order,
    mark_earlier_files,
)
from benchmark.runner.plan.repro_profiles import ReproProfile
from benchmark.runner.plan.specs import TableSpec, default_spec_dir
from benchmark.runner.plan.units import Unit
from benchmark.runner.report.costs import cost_table
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
)
from benchmark.runner.report.training import relabel_note, shown_labels, table_protocol


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
    numbers: ReportNumbers,
) -> list[Path]:
    """Write every report file under ``out``; return their paths. Every number is computed
    before: ``inputs`` (:class:`~benchmark.runner.claims.report_numbers.ReportInputs`, the
    execute room's work) and ``numbers`` (``claims.report_numbers.report_numbers``: the rows of
    ``results.csv``, the tables' intervals and the claims); this function renders them.
    ``units`` and ``results`` name the rows shown and the failed runs; ``workdir`` holds the
    Table 6 cache (``costs/``, named in its note).

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
    references = inputs.references
    plan = merge
    kept_specs = plan.live
    everything, show_val, summaries = numbers.everything, numbers.show_val, numbers.summaries
    audit_rows = inputs.audit_rows
    audit_md = heading_cue_audit_markdown(audit_rows)
    written = [out / "results.csv"]
    everything.to_csv(written[0], index=False, float_format=RESULTS_FLOAT_FORMAT)
    cost_cache = Path(workdir) / "costs" if workdir is not None else None

    # The kept live tables are rendered again from their rows (a table of costs, which would be
    # measured again, is kept as it is), so every table file says what results.csv says.
    rendered = [*specs, *(s for s in kept_specs if s.kind != "cost")]
    bar = Progress(len(rendered), "report", unit="item", enabled=not quiet)
    with bar:
        for spec in rendered:
            bar.update(0, postfix=f"writing {spec.name}")
            part = everything[everything["table"] == spec.name] if len(everything) else everything
            summary = summaries.get(spec.name, pd.DataFrame())
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
                text, figures = sequence_report(spec, numbers.sequences[spec.name], out)
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
        findings_md, claims_md, claims = numbers.findings_md, numbers.claims_md, numbers.claims
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
    text = _readme(profile, listed, findings_md, claims_md, invocations or [], audit, plan.kept,
                   precision_text(units))  # fmt: skip
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


def precision_text(units: list[Unit]) -> str:
    """The precision the units of a report trained and evaluated in, in words (issue 40: a report
    says which precision produced it), from the units' own configs (``precision`` resolved at
    planning: ``auto`` is never left in a unit's config)."""
    counts: dict[str, int] = {}
    for unit in units:
        counts[unit.cfg.precision] = counts.get(unit.cfg.precision, 0) + 1
    if not counts:
        return ""
    if len(counts) == 1:
        (name,) = counts
        return f"Precision: every unit trained and evaluated in {name}."
    parts = ", ".join(f"{n} in {name}" for name, n in sorted(counts.items()))
    return f"Precision: mixed, {parts} (units)."


def _readme(
    profile: ReproProfile,
    specs: list[TableSpec],
    findings_md: str,
    claims_md: str,
    runs: list[dict],
    audit: str,
    earlier: list[EarlierTable] = (),
    precision: str = "",
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
        f"`{profile.dataset}` rendered by the uavbench simulator (not Google Earth imagery)."
        + (f" {precision}" if precision else ""),
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
