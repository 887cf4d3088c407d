"""Reproducibility digests of a reproduction: ``provenance.md`` and ``provenance.json``.

What a later machine needs to tell whether it reproduced these results bit for bit, and if not
where they first part: the dataset (its manifest's sha256, which holds the sha256 of every shard),
each unit's trained weights and predictions, and the software and CPU that computed them.

Checkpoint files are NOT byte-reproducible: ``checkpoint.pt`` stores the training history with
each epoch's wall time (``epoch_time_s``) and the config with the dataset's machine path
(``data.root``), so its sha256 differs on every run even when the weights are identical. It is
recorded (``checkpoint_file_sha256``, to identify the local file) but ignored by
:func:`compare_provenance`; the weights are compared through ``model_state_sha256``, a sha256 of
the model's state dict in a canonical order (see :func:`state_dict_sha256`). Predictions CSVs are
written with 10 significant digits and fixed line endings, so equal predictions give equal bytes.

A report that keeps tables from an earlier run (``uavbench reproduce --only``, ``--stale keep``,
``benchmark.runner.plan.partial``) records where they come from: ``earlier_tables`` (per table the
git commit, dataset manifest, date, machine and reason) and ``earlier_units`` (the earlier
report's digests of their units), so the digests of every number in the report stay in one
record.
"""

from __future__ import annotations

import fnmatch
import hashlib
import importlib.metadata
import json
import os
import platform
import sys
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from benchmark.runner.execute.worker import UnitResult
from benchmark.runner.plan.units import Unit
from benchmark.tracking import file_sha256, git_commit, manifest_sha256

PROVENANCE_VERSION = 1
# Distributions whose versions can change numbers (torch kernels, numpy/scipy maths, rendering,
# parquet I/O) or the tracking of them.
PACKAGES = (
    "torch", "numpy", "scipy", "pandas", "pyarrow", "numba", "opencv-python-headless",
    "opencv-python", "matplotlib", "mlflow",
)  # fmt: skip
# CPU flags that decide which vectorised kernels torch / MKL / oneDNN pick (and so the rounding).
KERNEL_FLAGS = (
    "sse4_2", "avx", "avx2", "fma", "f16c", "avx512f", "avx512dq", "avx512bw", "avx512vl",
    "avx512_vnni", "avx512_bf16", "avx512_fp16", "avx_vnni", "amx_tile", "amx_bf16", "amx_int8",
)  # fmt: skip
# Environment variables that change kernel choice or thread counts (MKL_CBWR pins MKL's code path).
ENV_VARS = (
    "OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS", "OPENBLAS_NUM_THREADS",
    "ATEN_CPU_CAPABILITY", "MKL_CBWR", "MKL_ENABLE_INSTRUCTIONS", "ONEDNN_MAX_CPU_ISA",
)  # fmt: skip
# Keys that differ between any two runs by construction: ignored by compare_provenance.
VOLATILE = ("written", "machine.hostname", "units.*.checkpoint_file_sha256")


def state_dict_sha256(state: Mapping[str, torch.Tensor]) -> str:
    """sha256 of a state dict, independent of how it was serialised: for each entry in sorted
    name order, the name, dtype, shape and the raw little-endian bytes of the contiguous CPU
    tensor (viewed as uint8, so every dtype, bfloat16 included, hashes its exact bits)."""
    digest = hashlib.sha256()
    for name in sorted(state):
        t = state[name]
        if not isinstance(t, torch.Tensor):
            kind = type(t).__name__
            raise TypeError(f"state_dict_sha256: entry {name!r} is a {kind}, expected a tensor")
        t = t.detach().cpu().contiguous()
        digest.update(f"{name}|{t.dtype}|{tuple(t.shape)}\n".encode())
        digest.update(t.reshape(-1).view(torch.uint8).numpy().tobytes())
    return digest.hexdigest()


def software() -> dict[str, str]:
    """Python, the packages of :data:`PACKAGES` (absent ones omitted) and torch's CPU kernels."""
    out = {"python": platform.python_version(), "implementation": sys.implementation.name}
    for name in PACKAGES:
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            continue
    out["torch_cpu_capability"] = str(torch.backends.cpu.get_cpu_capability())
    out.update(_torch_libraries())
    return out


def _torch_libraries() -> dict[str, str]:
    """MKL, oneDNN and the parallel backend as ``torch.__config__.parallel_info()`` names them."""
    out = {}
    for line in torch.__config__.parallel_info().splitlines():
        line = line.strip()
        if line.startswith("ATen parallel backend:"):
            out["torch_parallel_backend"] = line.split(":", 1)[1].strip()
        elif "Math Kernel Library Version" in line:
            out["mkl"] = line.split("Version", 1)[1].split("for")[0].strip()
        elif line.startswith("Intel(R) MKL-DNN"):
            out["onednn"] = line.removeprefix("Intel(R) MKL-DNN").split("(")[0].strip()
        elif line.startswith("at::get_num_threads()"):
            out["torch_threads_report_process"] = line.rsplit(":", 1)[1].strip()
    return out


def machine() -> dict[str, str]:
    """Platform, CPU model and signature (family, model, stepping, microcode, cache size),
    kernel-relevant CPU flags, core count and thread environment."""
    from benchmark.machine import cpu_model, cpu_signature
    from benchmark.models.precision_support import cpu_flags

    model, flags = cpu_model(), cpu_flags()
    out = {
        "hostname": platform.node(),
        "platform": platform.platform(),
        "cpu_model": model,
        "cpu_signature": cpu_signature(),
        "cpu_flags": " ".join(f for f in KERNEL_FLAGS if f in flags) if flags else "unknown",
        "cpu_count": str(os.cpu_count()),
    }
    out.update({f"env.{v}": os.environ.get(v, "unset") for v in ENV_VARS})
    return out


def unit_digests(unit: Unit, unit_dir: Path) -> dict[str, Any]:
    """Digests of one unit's files: its checkpoint (file and weights) and predictions CSVs."""
    from benchmark.models.checkpoint import load_checkpoint

    record: dict[str, Any] = {
        "title": unit.title, "seed": unit.cfg.seed, "train_split": unit.cfg.data.train_split,
        "threads": unit.cfg.threads,
    }  # fmt: skip
    checkpoint = unit_dir / "train" / "checkpoint.pt"
    if checkpoint.is_file():
        ckpt = load_checkpoint(checkpoint)
        record["epochs"] = ckpt.get("epoch")
        record["model_state_sha256"] = state_dict_sha256(ckpt["model"])
        record["checkpoint_file_sha256"] = file_sha256(checkpoint)
    else:
        record["model_state_sha256"] = "absent"
    files = sorted((unit_dir / "eval").glob("*.csv")) if (unit_dir / "eval").is_dir() else []
    record["predictions"] = {f.name: file_sha256(f) for f in files}
    lines = "".join(f"{n} {h}\n" for n, h in record["predictions"].items())
    record["predictions_sha256"] = hashlib.sha256(lines.encode()).hexdigest() if files else "absent"
    return record


def collect_provenance(
    units: list[Unit],
    results: Mapping[str, UnitResult],
    data_root: Path,
    workdir: Path | None,
    out: Path | None = None,
) -> dict[str, Any]:
    """The provenance record of a reproduction (JSON-serialisable; no machine paths as values
    that are compared). Units without a directory under ``workdir`` (results read from a tracking
    store only) are listed with ``absent`` digests; without ``workdir`` no unit is listed. The
    report's own directory ``out`` does not make the commit dirty (it is being written)."""
    record: dict[str, Any] = {
        "format": PROVENANCE_VERSION,
        "written": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "git_commit": git_commit(ignore=[out] if out is not None else []) or "unknown",
        "dataset": {"manifest_sha256": manifest_sha256(data_root)},
        "software": software(),
        "machine": machine(),
        "units": {},
    }
    if workdir is None:
        record["units_note"] = "no workdir given: per-unit digests not recorded"
        return record
    for unit in units:
        if unit.key in results and results[unit.key].ok:
            record["units"][unit.key] = unit_digests(unit, Path(workdir) / "units" / unit.key)
    return record


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
