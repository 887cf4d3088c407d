"""``uavbench bench isa``: the dataset's manifest digest with each library's SIMD level forced
down, one render per setting, side by side (issue 20, "same data on every CPU").

numpy, OpenBLAS, numba, torch, OpenCV, Arrow and libjpeg-turbo choose kernels from the CPU at
run time. Each row renders the profile's dataset in a fresh process with one of them forced to its
baseline (environment variables below) and fresh city caches (cities are rebuilt under the same
setting); the last row forces all at once. Equal digests everywhere mean the bytes do not depend
on the instruction set the libraries find: on an AVX-512 machine the default row runs the AVX-512
kernels and the forced rows the baseline ones, which is the comparison issue 20 is about.

The column ``in effect`` is what a probe process reports under the same environment (numpy's
dispatched SIMD targets, OpenBLAS core, numba CPU, ATen capability, OpenCV dispatch, Arrow SIMD
level), so a variable that a library ignores shows up instead of passing silently.

    uavbench bench isa [--profile smoke] [--workers 2] [--only NAME ...] [--strict]
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from benchmark.errors import UsageError
from benchmark.machine import cpu_model

# One library per setting; the values that switch its run-time dispatch off.
_PROBE = r"""
import json, os
out = {}
import numpy as np
from numpy._core import _multiarray_umath as m
out["numpy"] = "+".join(f for f in m.__cpu_dispatch__ if m.__cpu_features__.get(f)) or "baseline"
try:
    from threadpoolctl import threadpool_info
    out["openblas"] = ",".join(
        str(i.get("architecture")) for i in threadpool_info() if i.get("internal_api") == "openblas"
    ) or "?"
except ImportError:
    out["openblas"] = "?"
import numba, llvmlite.binding as ll
out["numba"] = (numba.config.CPU_NAME or ll.get_host_cpu_name()) + (
    " svml" if numba.config.USING_SVML else "")
import cv2
out["opencv"] = "+".join(
    t[1:] for t in cv2.getCPUFeaturesLine().split() if t.startswith("*") and not t.endswith("?")
) or "baseline"
import pyarrow
out["arrow"] = pyarrow.runtime_info().simd_level
import torch
out["aten"] = torch.backends.cpu.get_cpu_capability()
print(json.dumps(out))
"""


def numpy_dispatch_found() -> list[str]:
    """numpy's dispatch targets this CPU runs (e.g. ``['X86_V3']`` on AVX2, more on AVX-512)."""
    from numpy._core import _multiarray_umath as m

    return [f for f in m.__cpu_dispatch__ if m.__cpu_features__.get(f)]


def opencv_dispatch_found() -> list[str]:
    """OpenCV's dispatched features this CPU has, in OpenCV's names (``AVX2``, ``AVX512-SKX``)."""
    import cv2

    line = cv2.getCPUFeaturesLine().split()
    return [t[1:] for t in line if t.startswith("*") and not t.endswith("?")]


def lower_isa_settings() -> dict[str, dict[str, str]]:
    """``{name: environment}``: each library forced to its baseline instruction set, one per row.

    NPY_DISABLE_CPU_FEATURES names only the targets this CPU has (numpy refuses baseline and
    unknown names; numpy 2.4 names them X86_V3/X86_V4/AVX512_*, not the numpy 1.x AVX2/FMA3);
    OpenCV's list likewise. OpenBLAS Prescott is its SSE3 core (no AVX, no FMA)."""
    npy = numpy_dispatch_found()
    cv = opencv_dispatch_found()
    settings: dict[str, dict[str, str]] = {
        "numpy": {"NPY_DISABLE_CPU_FEATURES": " ".join(npy)} if npy else {},
        "openblas": {"OPENBLAS_CORETYPE": "Prescott"},
        "numba": {"NUMBA_CPU_NAME": "generic"},
        "torch": {"ATEN_CPU_CAPABILITY": "default"},
        "opencv": {"OPENCV_CPU_DISABLE": ",".join(cv)} if cv else {},
        "arrow": {"ARROW_USER_SIMD_LEVEL": "NONE"},
        "libjpeg": {"JSIMD_FORCENONE": "1"},
    }
    return {name: env for name, env in settings.items() if env}


def lower_isa_env() -> dict[str, str]:
    """Every setting of :func:`lower_isa_settings` at once."""
    env: dict[str, str] = {}
    for setting in lower_isa_settings().values():
        env.update(setting)
    return env


def probe(env: dict[str, str]) -> dict[str, str]:
    """What each library runs under ``env`` (a fresh interpreter): see the module docstring."""
    run = subprocess.run(
        [sys.executable, "-c", _PROBE],
        env={**os.environ, **env},
        capture_output=True,
        text=True,
        check=False,
    )
    if run.returncode != 0:
        raise RuntimeError(f"bench isa: the probe failed under {env}: {run.stderr.strip()[-400:]}")
    return json.loads(run.stdout.strip().splitlines()[-1])


def render_manifest(
    out: Path, env: dict[str, str], *, profile: str, workers: int, seed: int, size: int | None
) -> tuple[dict, str]:
    """Render the dataset into ``out`` (fresh city cache beside it) in a subprocess under ``env``;
    returns (manifest, manifest sha256). RuntimeError with the tail of stderr if it fails."""
    cmd = [sys.executable, "-m", "benchmark", "simulate", "--profile", profile, "--out", str(out)]
    cmd += ["--workers", str(workers), "--seed", str(seed), "--quiet"]
    cmd += ["--city-cache", str(out.parent / f"{out.name}-cities")]
    if size is not None:
        cmd += ["--size", str(size)]
    run = subprocess.run(
        cmd, env={**os.environ, **env}, capture_output=True, text=True, check=False
    )
    if run.returncode != 0:
        raise RuntimeError(
            f"bench isa: simulate failed under {env or 'the default environment'} (exit "
            f"{run.returncode}): {run.stderr.strip()[-800:]}"
        )
    data = (out / "manifest.json").read_bytes()
    return json.loads(data), hashlib.sha256(data).hexdigest()


@dataclass(frozen=True)
class IsaBenchConfig:
    """``bench isa``: render ``profile`` (``size`` standard pairs, None: the profile's; dataset
    ``seed``) with ``workers`` processes once per setting (``only``: these besides default;
    None: every one); ``strict``: exit 1 when a digest differs."""

    profile: str = "smoke"
    size: int | None = None
    workers: int = 2
    seed: int = 0
    only: tuple[str, ...] | None = None
    strict: bool = False


def bench_isa(config: IsaBenchConfig) -> int:
    """Render and compare (printing a row per setting); exit code 0, or 1 with ``strict`` and a
    differing digest. UsageError: an unknown profile or setting, no workers."""
    from benchmark.data.profiles import DATA_PROFILES

    if config.profile not in DATA_PROFILES:
        raise UsageError(
            f"bench isa: unknown --profile {config.profile!r}; one of {sorted(DATA_PROFILES)}"
        )
    if config.workers < 1:
        raise UsageError(f"bench isa: --workers must be >= 1, got {config.workers}")
    settings = lower_isa_settings()
    rows = {"default": {}, **settings, "all": lower_isa_env()}
    if config.only is not None:
        unknown = sorted(set(config.only) - set(rows))
        if unknown:
            raise UsageError(f"bench isa: unknown --only {unknown}; expected some of {list(rows)}")
        rows = {k: v for k, v in rows.items() if k == "default" or k in config.only}
    cpu = cpu_model()
    print(
        f"uavbench bench isa: profile {config.profile}, {config.workers} workers; CPU {cpu}; "
        f"glibc {platform.libc_ver()[1]}"
    )
    results: dict[str, tuple[dict, str]] = {}
    with tempfile.TemporaryDirectory(prefix="uavbench-isa-") as tmp:
        for name, env in rows.items():
            effect = probe(env)
            t0 = time.perf_counter()
            results[name] = render_manifest(
                Path(tmp) / name,
                env,
                profile=config.profile,
                workers=config.workers,
                seed=config.seed,
                size=config.size,
            )
            wall = time.perf_counter() - t0
            same = "same" if results[name][1] == results["default"][1] else "DIFFERS"
            forced = " ".join(f"{k}={v}" for k, v in env.items()) or "(none)"
            print(f"{name:9s} {results[name][1][:16]}  {same:7s} {wall:5.1f} s  {forced}")
            print(f"{'':9s} in effect: " + ", ".join(f"{k} {v}" for k, v in effect.items()))
    base = results["default"][0]["files"]
    differ = False
    for name, (manifest, _) in results.items():
        files = [
            f for f, e in manifest["files"].items() if base.get(f, {}).get("sha256") != e["sha256"]
        ]
        if files:
            differ = True
            print(f"{name}: files differing from default: {', '.join(sorted(files))}")
    print("all digests equal" if not differ else "digests differ: the bytes depend on the CPU")
    return 1 if differ and config.strict else 0
