"""Partial reruns (``uavbench reproduce --only table1,fig7``): keep the other tables' results.

An ``--only`` reproduction re-runs some tables; ``results.csv`` and the summary ``README.md`` of
its report directory must still cover every table an earlier invocation wrote there, or the
other tables' verdicts would vanish. :func:`earlier_results` finds the rows to keep and the units
behind them (so the claims are decided again, on every table, from the per-frame predictions);
:func:`merge_note` says in the README which tables the last invocation re-ran.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pandas as pd

from benchmark.runner.plan import Unit, plan_units
from benchmark.runner.profiles import ReproProfile
from benchmark.runner.specs import TableSpec, default_spec_dir, load_specs


def earlier_results(
    out: Path,
    specs: list[TableSpec],
    profile: ReproProfile,
    data_root: Path,
    workdir: Path | None,
) -> tuple[pd.DataFrame, list[TableSpec], list[Unit]]:
    """What an earlier reproduction wrote to ``out/results.csv`` for tables other than ``specs``:
    ``(rows, their specs, their units)``. A table is kept when its spec still exists (in the
    directory of ``specs``), every trained row's unit is one that this dataset, profile and the
    rows' seeds plan today (same code, data and settings: the same unit key) and, given
    ``workdir``, the unit's predictions are still under ``workdir/units/<key>/eval``; otherwise
    it is dropped (a note on stderr says which and why). Nothing is kept without the file."""
    empty = (pd.DataFrame(), [], [])
    path = Path(out) / "results.csv"
    if not path.is_file():
        return empty
    # Sweep values stay strings ("600", not 600.0): they name models and splits.
    previous = pd.read_csv(path, dtype={"x": str, "label": str, "split": str, "table": str})
    if "table" not in previous or "unit" not in previous:
        return empty
    selected = {s.name for s in specs}
    others = previous[~previous["table"].isin(selected)]
    if others.empty:
        return empty
    spec_dir = specs[0].source.parent if specs else default_spec_dir()
    known = {s.name: s for s in load_specs(spec_dir, None)}
    kept_specs = [known[t] for t in dict.fromkeys(others["table"]) if t in known]
    dropped = {t: "its spec is gone" for t in set(others["table"]) - set(known)}
    trained = others[others["unit"].notna() & others["table"].isin([s.name for s in kept_specs])]
    seeds = sorted({int(x) for x in trained["seed"]}) if len(trained) else [0]
    try:
        from benchmark.data import list_splits
        from benchmark.tracking import manifest_sha256

        planned = plan_units(
            kept_specs, profile, seeds, data_root, list_splits(data_root),
            manifest_sha256(data_root),
        )  # fmt: skip
    except (ValueError, FileNotFoundError, KeyError) as err:
        planned, dropped = [], {**dropped, **{s.name: str(err) for s in kept_specs}}
    by_key = {u.key: u for u in planned}
    for spec in kept_specs:
        keys = set(trained.loc[trained["table"] == spec.name, "unit"])
        if spec.name in dropped:
            continue
        if not keys <= set(by_key):
            dropped[spec.name] = "its units are not those of this dataset, profile and code"
        elif workdir is not None and any(
            not (Path(workdir) / "units" / k / "eval").is_dir() for k in keys
        ):
            dropped[spec.name] = f"predictions missing under {workdir}/units"
    for name, why in sorted(dropped.items()):
        print(f"results.csv: not keeping {name} of an earlier run: {why}", file=sys.stderr)
    kept_specs = [s for s in kept_specs if s.name not in dropped]
    names = {s.name for s in kept_specs}
    rows = others[others["table"].isin(names)].copy()
    rows["paper_model"] = rows["paper_model"].fillna("") if "paper_model" in rows else ""
    keys = set(rows["unit"].dropna())
    return rows, kept_specs, [u for u in planned if u.key in keys]


def in_spec_order(specs: list[TableSpec]) -> list[TableSpec]:
    """Specs by name order (as ``load_specs`` lists them), each once."""
    return sorted({s.name: s for s in specs}.values(), key=lambda s: s.name)


def merge_note(run: list[TableSpec], kept: list[TableSpec]) -> str:
    """How a partial rerun's README was made (empty when every table was re-run)."""
    if not kept:
        return ""
    return (
        "\n**Partial rerun.** The last invocation re-ran "
        + ", ".join(f"`{s.name}`" for s in run)
        + "; "
        + ", ".join(f"`{s.name}`" for s in kept)
        + " come from an earlier invocation (their rows of `results.csv` and their Markdown "
        "files are kept as written then). The findings and every claim above are decided again "
        "on all of them, from the per-frame predictions in the work directory.\n"
    )
