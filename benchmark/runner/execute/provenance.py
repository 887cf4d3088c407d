"""The reproducibility digests of a reproduction, collected (``provenance.json``'s record): the
work half of ``benchmark.runner.report.provenance``, which writes them.

It reads every unit's checkpoint (its weights' digest) and predictions, the dataset's manifest,
the software and the machine, before the report is written (``benchmark.runner.reproduction``).
Checkpoint files are not byte-reproducible; the weights are compared through
``model_state_sha256``, a sha256 of the model's state dict in a canonical order
(:func:`state_dict_sha256`); the report module's docstring says why.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import os
import platform
import sys
import time
from collections.abc import Mapping
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
