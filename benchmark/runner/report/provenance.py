"""Reproducibility digests of a reproduction: ``provenance.md`` and ``provenance.json``.

What a later machine needs to tell whether it reproduced these results bit for bit, and if not
where they first part: the dataset (its manifest's sha256, which holds the sha256 of every shard),
each unit's trained weights and predictions, and the software and CPU that computed them.

Checkpoint files are NOT byte-reproducible: ``checkpoint.pt`` stores the training history with
each epoch's wall time (``epoch_time_s``) and the config with the dataset's machine path
(``data.root``), so its sha256 differs on every run even when the weights are identical. It is
recorded (``checkpoint_file_sha256``, to identify the local file) but ignored by
:func:`compare_provenance`; the weights are compared through ``model_state_sha256``, a sha256 of
the model's state dict in a canonical order
(``benchmark.runner.execute.provenance.state_dict_sha256``, with the rest of the collecting: this
module writes and compares the record). Predictions CSVs are
written with 10 significant digits and fixed line endings, so equal predictions give equal bytes.

A report that keeps tables from an earlier run (``uavbench reproduce --only``, ``--stale keep``,
``benchmark.runner.plan.partial``) records where they come from: ``earlier_tables`` (per table the
git commit, dataset manifest, date, machine and reason) and ``earlier_units`` (the earlier
report's digests of their units), so the digests of every number in the report stay in one
record.
"""

from __future__ import annotations

import fnmatch
import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

# Keys that differ between any two runs by construction: ignored by compare_provenance.
VOLATILE = ("written", "machine.hostname", "units.*.checkpoint_file_sha256")


def write_provenance(record: Mapping[str, Any], out: Path) -> list[Path]:
    """``provenance.json`` (sorted keys, byte-stable for equal records) and ``provenance.md``."""
    out = Path(out)
    json_path, md_path = out / "provenance.json", out / "provenance.md"
    json_path.write_text(json.dumps(record, indent=1, sort_keys=True) + "\n")
    md_path.write_text(provenance_markdown(record))
    return [md_path, json_path]


def provenance_markdown(record: Mapping[str, Any]) -> str:
    lines = [
        "# Provenance: digests to compare a rerun with",
        "",
        f"Written {record['written']} at git commit `{record['git_commit']}`. Compare two records "
        "with `benchmark.runner.report.provenance.compare_provenance(a_json, b_json)`, which lists "
        "every differing line (wall-clock fields ignored).",
        "",
        f"Dataset manifest sha256: `{record['dataset']['manifest_sha256']}` (the manifest lists "
        "the sha256 of every shard and parquet file).",
        "",
        "| software | version |", "|---|---|",
        *(f"| {k} | {v} |" for k, v in record["software"].items()),
        "",
        "| machine | value |", "|---|---|",
        *(f"| {k} | {v} |" for k, v in record["machine"].items()),
        "",
        "Per unit: `model_state_sha256` hashes the trained weights (state dict in sorted name "
        "order, dtype, shape, raw bytes); the checkpoint file's own sha256 is not reproducible (it "
        "holds epoch wall times and the dataset path) and is kept in `provenance.json` only. "
        "`predictions_sha256` hashes the list of the unit's predictions CSVs and their sha256 "
        "(per-file digests in `provenance.json`).",
        "",
        "| unit | run | model_state_sha256 | predictions_sha256 |", "|---|---|---|---|",
    ]  # fmt: skip
    for key, u in record["units"].items():
        lines.append(
            f"| `{key}` | {u['title']} | `{u['model_state_sha256']}` | "
            f"`{u['predictions_sha256']}` |"
        )
    if "units_note" in record:
        lines += ["", record["units_note"]]
    lines += earlier_markdown(record)
    return "\n".join(lines) + "\n"


def earlier_markdown(record: Mapping[str, Any]) -> list[str]:
    """Lines on the tables kept from an earlier run (none when there are none)."""
    earlier = record.get("earlier_tables") or {}
    if not earlier:
        return []
    lines = [
        "",
        "## Tables from an earlier run",
        "",
        "Kept as written by an earlier reproduction (not re-run, not re-decided); the digests of "
        f"their {len(record.get('earlier_units') or {})} unit(s) are those that run recorded "
        "(`earlier_units` in `provenance.json`).",
        "",
        "| table | git commit | dataset manifest sha256 | written | machine | why not re-run |",
        "|---|---|---|---|---|---|",
    ]
    for name, t in sorted(earlier.items()):
        lines.append(
            f"| `{name}` | `{t.get('git_commit', 'unknown')}` | "
            f"`{t.get('dataset_manifest') or 'unknown'}` | {t.get('written') or 'unknown'} | "
            f"{t.get('machine') or 'unknown'} | {t.get('why', '')} |"
        )
    return lines


def provenance_summary(record: Mapping[str, Any]) -> str:
    """The README's paragraph pointing at the digests."""
    sw = record["software"]
    return (
        "\n## Provenance\n\n"
        f"Dataset manifest sha256 `{record['dataset']['manifest_sha256'][:16]}...`; "
        f"{len(record['units'])} unit(s) with weight and prediction digests; torch "
        f"{sw.get('torch', '?')} ({sw.get('torch_cpu_capability', '?')} kernels), numpy "
        f"{sw.get('numpy', '?')}, on {record['machine']['cpu_model']}. Every digest: "
        "[provenance.md](provenance.md), machine-readable [provenance.json](provenance.json)"
        + _earlier_note(record)
        + ".\n"
    )


def _earlier_note(record: Mapping[str, Any]) -> str:
    earlier = record.get("earlier_tables") or {}
    if not earlier:
        return ""
    commits = sorted({str(t.get("git_commit", "unknown")) for t in earlier.values()})
    return (
        f"; {len(earlier)} table(s) kept from an earlier run (git commit "
        f"{', '.join(f'`{c}`' for c in commits)}) with that run's digests"
    )


def flatten(record: Mapping[str, Any], prefix: str = "") -> dict[str, str]:
    """``{"a.b.c": "value"}`` for every leaf of a nested record."""
    out: dict[str, str] = {}
    for key, value in record.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.update(flatten(value, name + "."))
        else:
            out[name] = json.dumps(value) if not isinstance(value, str) else value
    return out


@dataclass(frozen=True)
class Difference:
    """One differing leaf: ``a`` or ``b`` is None when the key exists on one side only."""

    key: str
    a: str | None
    b: str | None

    def __str__(self) -> str:
        return f"{self.key}: {self.a if self.a is not None else '(absent)'} -> " + (
            self.b if self.b is not None else "(absent)"
        )


def load_record(source: Mapping[str, Any] | str | Path) -> Mapping[str, Any]:
    if isinstance(source, Mapping):
        return source
    path = Path(source)
    if not path.is_file():
        raise FileNotFoundError(f"provenance record {path} does not exist (a provenance.json)")
    return json.loads(path.read_text())


def compare_provenance(
    a: Mapping[str, Any] | str | Path,
    b: Mapping[str, Any] | str | Path,
    ignore: tuple[str, ...] = VOLATILE,
) -> list[Difference]:
    """Every leaf that differs between two provenance records (dicts or ``provenance.json``
    paths), in sorted key order; keys matching an ``ignore`` pattern (``fnmatch``, e.g.
    ``units.*.checkpoint_file_sha256``) are skipped. An empty list: same data, weights,
    predictions, software and machine class."""
    fa, fb = flatten(load_record(a)), flatten(load_record(b))
    diffs = []
    for key in sorted(fa.keys() | fb.keys()):
        if any(fnmatch.fnmatchcase(key, pattern) for pattern in ignore):
            continue
        if fa.get(key) != fb.get(key):
            diffs.append(Difference(key, fa.get(key), fb.get(key)))
    return diffs
