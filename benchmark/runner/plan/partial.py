"""Partial reruns (``uavbench reproduce --only table1,fig7``): one report that never disagrees
with itself.

An ``--only`` reproduction re-runs some tables into a report directory that may hold an earlier
reproduction's other tables. Each of those other tables is, after :func:`plan_merge`:

- **live**: every trained row's unit is one this dataset, profile and code plan today (the same
  unit key) and its predictions are still under ``<workdir>/units/<key>/eval``. Its rows of
  ``results.csv`` are kept, its Markdown (and figure) is rendered again from them, and the claims
  are decided again on it together with the re-run tables, from the per-frame predictions.
- **from an earlier run** otherwise (other dataset, profile or code, predictions gone, spec gone,
  or a file without rows). ``--stale keep`` (the default) keeps it exactly as written then, marked
  as such in its own ``.md`` (a banner naming the commit), in ``results.csv`` (column
  ``stale_from``: that run's git commit; empty for rows this report decides), in the report's
  README (table list, a *Partial rerun* section, and the findings: every claim that uses it reads
  "from an earlier run, not re-decided" instead of a verdict decided from mixed data) and in
  ``provenance.json`` (``earlier_tables``). ``--stale drop`` removes it: its rows, its ``.md``,
  its figure and every README line about it (its claims then read "not run").

Keep is the default because an ``--only`` run should change only what it was asked to: deleting
tables that took hours to compute (in a directory that may not be under version control) is not
undone by rerunning one table, and a kept table carries its provenance in every place it appears,
so none of its numbers can be read as today's and no verdict mixes two runs.

The block :meth:`MergePlan.describe` says which tables are kept, marked or removed, and why; the
reproduction prints it before training starts and records it (:meth:`MergePlan.markdown`) in the
README.
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from benchmark.runner.plan.repro_profiles import ReproProfile
from benchmark.runner.plan.specs import TableSpec, default_spec_dir, load_specs
from benchmark.runner.plan.units import Unit, plan_units

STALE_MODES = ("keep", "drop")
DEFAULT_STALE = "keep"
STALE_COLUMN = "stale_from"  # results.csv: git commit of the run that wrote a kept row, or ""
EARLIER = "from an earlier run, not re-decided"  # verdict of a claim that uses such a table
NOT_REDECIDED = "not re-decided"  # first words of such a claim's evidence
# Files of the report directory that are not tables (always rewritten by a reproduction).
REPORT_FILES = ("README", "provenance", "heading_cue")
BANNER_BEGIN = "<!-- uavbench: from an earlier run; the next reproduce rewrites this block -->"
BANNER_END = "<!-- uavbench: end of the earlier-run block -->"
_HEX = re.compile(r"^[0-9a-f]{40}(-dirty)?$")


def short_commit(commit: str) -> str:
    """``1fe0c26`` (``1fe0c26-dirty``) for a full git hash, anything else unchanged."""
    if _HEX.match(commit):
        return commit[:7] + ("-dirty" if commit.endswith("-dirty") else "")
    return commit


@dataclass(frozen=True)
class EarlierTable:
    """A table of an earlier reproduction that this one neither re-runs nor can keep live.

    ``commit``, ``dataset`` (manifest sha256), ``written`` and ``machine`` (its CPU: model,
    signature and kernel flags, :func:`machine_text`) describe the run that computed it
    (``"unknown"`` / ``""`` when that report recorded none); ``why`` says why it is not live."""

    name: str
    title: str
    why: str
    commit: str = "unknown"
    dataset: str = ""
    written: str = ""
    machine: str = ""

    @property
    def at(self) -> str:
        """``at `1fe0c26``` (Markdown)."""
        return f"at `{short_commit(self.commit)}`"

    def files(self, out: Path) -> list[Path]:
        """Its files in the report directory: ``<name>.md`` and a sweep's ``<name>.png``."""
        return [p for p in (out / f"{self.name}.md", out / f"{self.name}.png") if p.is_file()]

    def record(self) -> dict[str, str]:
        """Its entry in ``provenance.json`` (``earlier_tables``)."""
        return {"git_commit": self.commit, "dataset_manifest": self.dataset,
                "written": self.written, "machine": self.machine, "why": self.why}  # fmt: skip


@dataclass
class MergePlan:
    """What a reproduction of ``run`` does with what an earlier one left in its report directory.

    ``live``: the other tables kept and decided again (``live_rows`` of ``results.csv``, their
    ``live_units``); ``earlier``: the tables from an earlier run, kept and marked (``mode`` keep,
    ``earlier_rows`` with ``stale_from`` set) or removed (``mode`` drop); ``earlier_units``: the
    earlier report's provenance digests of their units (kept with them)."""

    run: list[TableSpec]
    mode: str = DEFAULT_STALE
    live: list[TableSpec] = field(default_factory=list)
    live_rows: pd.DataFrame = field(default_factory=pd.DataFrame)
    live_units: list[Unit] = field(default_factory=list)
    earlier: list[EarlierTable] = field(default_factory=list)
    earlier_rows: pd.DataFrame = field(default_factory=pd.DataFrame)
    earlier_units: dict[str, dict] = field(default_factory=dict)
    earlier_specs: dict[str, TableSpec] = field(default_factory=dict)

    @property
    def kept(self) -> list[EarlierTable]:
        """The earlier tables that stay in the report (none when ``mode`` is drop)."""
        return self.earlier if self.mode == "keep" else []

    @property
    def removed(self) -> list[EarlierTable]:
        return self.earlier if self.mode == "drop" else []

    def rows(self) -> pd.DataFrame:
        """The earlier ``results.csv`` rows this report keeps: live ones (``stale_from`` empty),
        then the marked ones (mode keep)."""
        parts = [self.live_rows] + ([self.earlier_rows] if self.mode == "keep" else [])
        parts = [p for p in parts if len(p)]
        return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()

    def _names(self, tables: Sequence[EarlierTable | TableSpec]) -> str:
        return ", ".join(t.name for t in tables)

    def describe(self) -> str:
        """The plain-text block printed before training (``""`` when nothing earlier is kept,
        marked or removed)."""
        if not (self.live or self.earlier):
            return ""
        lines = [
            f"Partial rerun of {self._names(self.run)}: the report directory holds other "
            "tables of an earlier reproduction."
        ]
        if self.live:
            lines.append(
                f"  kept and decided again (today's units, predictions in the work directory): "
                f"{self._names(self.live)}"
            )
        if self.earlier:
            what = (
                "kept as written then, marked 'from an earlier run' in their files, results.csv "
                "and the README; their claims are not re-decided"
                if self.mode == "keep"
                else "removed with their rows, files and README lines"
            )
            lines.append(f"  from an earlier run, {what} (--stale {self.mode}):")
            for why, group in _by_reason(self.earlier).items():
                names = ", ".join(t.name for t in group)
                commits = sorted({short_commit(t.commit) for t in group})
                lines.append(f"    {names} (run at {', '.join(commits)}): {why}")
            other = "drop" if self.mode == "keep" else "keep"
            lines.append(
                f"  to refresh them: {self.refresh_command()}; --stale {other} to "
                f"{'remove' if other == 'drop' else 'keep'} them instead"
            )
        return "\n".join(lines)

    def refresh_command(self) -> str:
        """The command that re-runs the tables of this invocation and the earlier ones (without
        ``--only`` when that is every table)."""
        names = sorted({*self.run_names(), *self.earlier_names()})
        every = {s.name for s in load_specs(self.run[0].source.parent)} if self.run else set()
        if every and every <= set(names):
            return "uavbench reproduce"
        return f"uavbench reproduce --only {','.join(names)}"

    def run_names(self) -> list[str]:
        return [s.name for s in self.run]

    def earlier_names(self) -> list[str]:
        return [t.name for t in self.earlier]

    def markdown(self) -> str:
        """The README's *Partial rerun* section (``""`` when there is nothing to say)."""
        if not (self.live or self.earlier):
            return ""
        ran = ", ".join(f"`{n}`" for n in self.run_names())
        lines = ["", "## Partial rerun", "", f"The last invocation re-ran {ran}."]
        if self.live:
            lines += [
                "",
                "Kept from an earlier invocation and decided again (their units are those this "
                "dataset, profile and code plan, and their predictions are in the work "
                "directory; their rows of `results.csv` are kept and their files rendered "
                "again): " + ", ".join(f"`{s.name}`" for s in self.live) + ".",
            ]
        if self.kept:
            lines += [
                "",
                "**From an earlier run, not re-decided** (kept as written then, `--stale keep`; "
                "their files open with the same note, their rows of `results.csv` carry the "
                "commit in `stale_from`, and every claim that uses one reads *from an earlier "
                "run, not re-decided* instead of a verdict drawn from two runs):",
                "",
            ]
            for why, group in _by_reason(self.kept).items():
                names = ", ".join(f"`{t.name}`" for t in group)
                lines.append(f"- {names} {group[0].at}: {why}")
        if self.removed:
            lines += [
                "",
                "Removed, with their rows, files and findings (`--stale drop`), because they "
                "came from an earlier run: "
                + "; ".join(f"`{t.name}` {t.at} ({t.why})" for t in self.removed)
                + ".",
            ]
        if self.earlier:
            lines += ["", f"Refresh them with `{self.refresh_command()}`."]
        return "\n".join(lines) + "\n"


def _by_reason(tables: list[EarlierTable]) -> dict[str, list[EarlierTable]]:
    """The tables grouped by (commit, reason), keyed by the reason."""
    groups: dict[tuple[str, str], list[EarlierTable]] = {}
    for t in tables:
        groups.setdefault((t.commit, t.why), []).append(t)
    return {why: group for (_, why), group in groups.items()}


def read_earlier_provenance(out: Path) -> dict:
    """``out/provenance.json`` of the earlier report (``{}`` when absent or unreadable)."""
    path = Path(out) / "provenance.json"
    try:
        record = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return record if isinstance(record, dict) else {}


def read_earlier_results(out: Path) -> pd.DataFrame:
    """``out/results.csv`` (empty without it or without the columns ``table`` and ``unit``).
    Sweep values stay strings (``"600"``, not 600.0): they name models and splits."""
    path = Path(out) / "results.csv"
    if not path.is_file():
        return pd.DataFrame()
    text_columns = ("x", "label", "split", "table", STALE_COLUMN)
    previous = pd.read_csv(path, dtype=dict.fromkeys(text_columns, str))
    if "table" not in previous or "unit" not in previous:
        return pd.DataFrame()
    if STALE_COLUMN not in previous:
        previous[STALE_COLUMN] = ""
    previous[STALE_COLUMN] = previous[STALE_COLUMN].fillna("")
    return previous


def _table_files(out: Path) -> set[str]:
    """Names of the table/figure Markdown files in ``out`` (not the README, provenance, audit)."""
    if not Path(out).is_dir():
        return set()
    return {p.stem for p in Path(out).glob("*.md") if p.stem not in REPORT_FILES}


def plan_merge(
    out: Path,
    specs: list[TableSpec],
    profile: ReproProfile,
    data_root: Path,
    workdir: Path | None,
    manifest: str | None = None,
    mode: str = DEFAULT_STALE,
) -> MergePlan:
    """Sort what an earlier reproduction left in ``out`` for tables other than ``specs``.

    A table there (rows in ``results.csv``, or ``<name>.md`` of a known spec) is live when its
    spec still exists, every trained row's unit is one that this dataset (``manifest``, its
    sha256; default: computed from ``data_root``), ``profile`` and the rows' seeds plan today,
    and, given ``workdir``, every such unit's predictions are under ``workdir/units/<key>/eval``
    (a table of costs, which trains nothing, is live when the earlier report's dataset is this
    one). Every other one is from an earlier run, with the reason, the earlier run's commit and
    dataset (from the earlier ``provenance.json``, or the ``stale_from`` column for rows that
    were already marked). ``mode``: ``keep`` or ``drop`` (see the module docstring)."""
    if mode not in STALE_MODES:
        raise ValueError(f"stale mode {mode!r}: expected one of {list(STALE_MODES)}")
    out = Path(out)
    plan = MergePlan(run=list(specs), mode=mode)
    selected = {s.name for s in specs}
    previous = read_earlier_results(out)
    others = previous[~previous["table"].isin(selected)] if len(previous) else previous
    spec_dir = specs[0].source.parent if specs else default_spec_dir()
    known = {s.name: s for s in load_specs(spec_dir, None)}
    with_rows = list(dict.fromkeys(others["table"])) if len(others) else []
    files = sorted(n for n in _table_files(out) - selected - set(with_rows) if n in known)
    if not with_rows and not files:
        return plan
    if manifest is None:
        from benchmark.tracking import manifest_sha256

        manifest = manifest_sha256(data_root)
    prov = read_earlier_provenance(out)
    before = prov.get("dataset", {}).get("manifest_sha256", "")
    marked = prov.get("earlier_tables", {})

    why: dict[str, str] = {t: "its spec is gone" for t in with_rows if t not in known}
    candidates = [known[t] for t in with_rows if t in known]
    trained = others[others["unit"].notna() & others["table"].isin([s.name for s in candidates])]
    planned = _why_not_live(why, candidates, trained, profile, data_root, workdir, manifest, before)
    for name in files:  # a file without rows: costs, or a table whose rows were never written
        if name in marked:
            why[name] = marked[name].get("why", "kept from an earlier run")
        elif known[name].kind == "cost" and before == manifest:
            plan.live.append(known[name])
        elif known[name].kind == "cost":
            measured = _other_dataset(before, manifest, "it was measured")
            why[name] = measured or "it was measured by an earlier run that recorded no dataset"
        else:
            why[name] = "the earlier results.csv has no rows of it"

    plan.live = [*(s for s in candidates if s.name not in why), *plan.live]
    live_names = {s.name for s in plan.live}
    rows = others[others["table"].isin(live_names)].copy()
    if len(rows):
        rows["paper_model"] = rows["paper_model"].fillna("") if "paper_model" in rows else ""
        rows[STALE_COLUMN] = ""
    plan.live_rows = rows
    live_keys = set(rows["unit"].dropna()) if len(rows) else set()
    plan.live_units = [u for u in planned if u.key in live_keys]

    for name in [*with_rows, *files]:
        if name in why:
            part = others[others["table"] == name] if len(others) else others
            title = known[name].title if name in known else name
            plan.earlier.append(_earlier_table(name, title, why[name], part, prov))
            if name in known:
                plan.earlier_specs[name] = known[name]
    plan.earlier.sort(key=lambda t: t.name)
    commits = {t.name: t.commit for t in plan.earlier}
    stale = others[others["table"].isin(commits)].copy() if len(others) else others
    if len(stale):
        stale["paper_model"] = stale["paper_model"].fillna("") if "paper_model" in stale else ""
        stale[STALE_COLUMN] = stale["table"].map(commits)
    plan.earlier_rows = stale
    units = {**prov.get("units", {}), **prov.get("earlier_units", {})}
    stale_keys = set(stale["unit"].dropna()) if len(stale) else set()
    plan.earlier_units = {k: v for k, v in units.items() if k in stale_keys}
    return plan


def _why_not_live(
    why: dict[str, str],
    candidates: list[TableSpec],
    trained: pd.DataFrame,
    profile: ReproProfile,
    data_root: Path,
    workdir: Path | None,
    manifest: str,
    before: str,
) -> list[Unit]:
    """Fill ``why`` (table -> reason) for the ``candidates`` (earlier tables with rows and a
    spec) that cannot stay live; return the units planned today for them. ``trained``: their
    earlier rows of trained models; ``before``: the earlier report's dataset manifest."""
    other_data = _other_dataset(before, manifest)
    if other_data:  # unit keys hold the dataset's digest: none of them can be today's
        why.update({s.name: other_data for s in candidates})
        return []
    seeds = sorted({int(x) for x in trained["seed"]}) if len(trained) else [0]
    try:
        from benchmark.data import list_splits

        planned = plan_units(candidates, profile, seeds, data_root, list_splits(data_root),
                             manifest)  # fmt: skip
    except (ValueError, FileNotFoundError, KeyError) as err:
        why.update({s.name: f"its units cannot be planned on this dataset ({err})"
                    for s in candidates})  # fmt: skip
        return []
    today = {u.key for u in planned}
    for spec in candidates:
        keys = set(trained.loc[trained["table"] == spec.name, "unit"])
        if spec.name in why:
            continue
        if not keys <= today:
            why[spec.name] = (
                "its units are not those this dataset, profile and code plan today (another "
                "profile, seeds or head versions)"
            )
        elif workdir is not None and any(
            not (Path(workdir) / "units" / k / "eval").is_dir() for k in keys
        ):
            why[spec.name] = f"its predictions are gone from {workdir}/units"
    return planned


def _earlier_table(name: str, title: str, why: str, rows: pd.DataFrame, prov: dict) -> EarlierTable:
    """The record of an earlier table: that run's commit, dataset and date from the earlier
    ``provenance.json`` (``prov``), or, for a table that report had already kept from an even
    earlier run, the record it kept (``earlier_tables``) or its rows' ``stale_from``."""
    entry = prov.get("earlier_tables", {}).get(name, {})
    stamped = sorted(set(rows[STALE_COLUMN]) - {""}) if len(rows) else []
    if entry or stamped:
        commit = entry.get("git_commit") or (stamped[0] if stamped else "") or "unknown"
        dataset, written = entry.get("dataset_manifest", ""), entry.get("written", "")
        machine = entry.get("machine", "")
        return EarlierTable(name, title, entry.get("why", why), commit, dataset, written, machine)
    dataset = prov.get("dataset", {}).get("manifest_sha256", "")
    commit = prov.get("git_commit") or "unknown"
    machine = machine_text(prov.get("machine", {}))
    return EarlierTable(name, title, why, commit, dataset, prov.get("written", ""), machine)


def machine_text(record: dict) -> str:
    """The machine a report recorded (``provenance.json``'s ``machine``, ``benchmark.runner.report.
    provenance.machine``) in words: its CPU model, then its signature and the kernel-relevant CPU
    flags, e.g. ``AMD EPYC (cpu family 26, model 2, ...; CPU flags avx2 fma avx512f ...)``;
    ``""`` when it recorded no CPU model."""
    model = record.get("cpu_model", "") if isinstance(record, dict) else ""
    if not model:
        return ""
    known = [(k, record.get(k, "")) for k in ("cpu_signature", "cpu_flags")]
    details = [v if k == "cpu_signature" else f"CPU flags {v}" for k, v in known
               if v and v != "unknown"]  # fmt: skip
    return model + (f" ({'; '.join(details)})" if details else "")


def _other_dataset(before: str, now: str, what: str = "its units were trained") -> str:
    """The reason for a table of another dataset (``""`` when the datasets agree or the earlier
    report recorded none)."""
    if not before or before == now:
        return ""
    return f"{what} on another dataset (manifest sha256 {before[:12]}...)"


def earlier_results(
    out: Path,
    specs: list[TableSpec],
    profile: ReproProfile,
    data_root: Path,
    workdir: Path | None,
) -> tuple[pd.DataFrame, list[TableSpec], list[Unit]]:
    """The live part of :func:`plan_merge`: ``(rows, their specs, their units)`` of the other
    tables an earlier reproduction wrote to ``out/results.csv`` that this one keeps and decides
    again (nothing without the file)."""
    plan = plan_merge(out, specs, profile, data_root, workdir)
    return plan.live_rows, plan.live, plan.live_units


def in_spec_order(specs: list[TableSpec]) -> list[TableSpec]:
    """Specs by name order (as ``load_specs`` lists them), each once."""
    return sorted({s.name: s for s in specs}.values(), key=lambda s: s.name)


# ---------------------------------------------------------------------- marking the files


def banner(table: EarlierTable, run: list[str]) -> str:
    """The block a kept earlier table's Markdown opens with."""
    dataset = f" on dataset `{table.dataset[:12]}...`" if table.dataset else ""
    written = f", written {table.written}" if table.written else ""
    machine = f" on {table.machine}" if table.machine else " (that report names no machine)"
    ran = ", ".join(f"`{n}`" for n in run)
    return (
        f"{BANNER_BEGIN}\n"
        f"> **From an earlier run {table.at}, not re-decided.** This table was computed by the "
        f"reproduction at git commit `{table.commit}`{dataset}{written}{machine}. The last "
        f"invocation re-ran {ran} only and could not keep it live: {table.why}. Its numbers "
        "(and figure) are kept as written then; its rows of `results.csv` carry that commit in "
        "`stale_from`, and the README's claims that use it are not re-decided. Refresh it with "
        f"`uavbench reproduce --only {table.name}`.\n"
        f"{BANNER_END}\n\n"
    )


def strip_banner(text: str) -> str:
    """``text`` without a leading earlier-run block."""
    if text.startswith(BANNER_BEGIN) and BANNER_END in text:
        return text.split(BANNER_END, 1)[1].lstrip("\n")
    return text


def mark_earlier_files(out: Path, plan: MergePlan) -> list[Path]:
    """Mode keep: put the banner at the top of every kept earlier table's Markdown (replacing
    an older one); mode drop: delete their files. Returns the files kept (keep) or removed."""
    touched = []
    for table in plan.earlier:
        for path in table.files(out):
            if plan.mode == "drop":
                path.unlink()
            elif path.suffix == ".md":
                path.write_text(banner(table, plan.run_names()) + strip_banner(path.read_text()))
            touched.append(path)
    return touched
