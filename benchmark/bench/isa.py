"""``uavbench bench isa``: the dataset's manifest digest with each library's SIMD level forced
down, one render per setting, side by side (issue 20, "same data on every CPU").

numpy, OpenBLAS, numba, torch, OpenCV, Arrow and libjpeg-turbo choose kernels from the CPU at
run time. Each row renders the profile's dataset in a fresh interpreter
(``benchmark.bench.fresh_process``: the library function, not the command line) with one of them
forced to its baseline (environment variables below) and fresh city caches (cities are rebuilt
under the same setting); the last row forces all at once. Equal digests everywhere mean the bytes
do not depend on the instruction set the libraries find: on an AVX-512 machine the default row
runs the AVX-512 kernels and the forced rows the baseline ones, which is the comparison issue 20
is about.

The column ``in effect`` is what a probe (:func:`in_effect`, in a fresh interpreter) reports
under the same environment (numpy's dispatched SIMD targets, OpenBLAS core, numba CPU, ATen
capability, OpenCV dispatch, Arrow SIMD level), so a variable that a library ignores shows up
instead of passing silently.

    uavbench bench isa [--profile smoke] [--workers 2] [--only NAME ...] [--strict]

:func:`bench_isa` returns the rows and whether every digest equals the default's; the command
prints them (and exits 1 with ``--strict`` when one differs).
"""

from __future__ import annotations

import hashlib
import json
import platform
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from benchmark.bench.fresh_process import FreshProcessError, run_fresh
from benchmark.errors import InputError
from benchmark.machine import cpu_model


def in_effect() -> dict[str, str]:
    """What each library runs in this process (the probe, run in a fresh one under a setting's
    environment): numpy's dispatched SIMD targets, the OpenBLAS core, numba's CPU, OpenCV's
    dispatch, Arrow's SIMD level, ATen's capability."""
    import llvmlite.binding as ll
    import numba
    import pyarrow
    import torch

    out = {"numpy": "+".join(numpy_dispatch_found()) or "baseline"}
    try:
        from threadpoolctl import threadpool_info

        cores = [str(i.get("architecture")) for i in threadpool_info()
                 if i.get("internal_api") == "openblas"]  # fmt: skip
        out["openblas"] = ",".join(cores) or "?"
    except ImportError:
        out["openblas"] = "?"
    out["numba"] = (numba.config.CPU_NAME or ll.get_host_cpu_name()) + (
        " svml" if numba.config.USING_SVML else ""
    )
    out["opencv"] = "+".join(opencv_dispatch_found()) or "baseline"
    out["arrow"] = pyarrow.runtime_info().simd_level
    out["aten"] = torch.backends.cpu.get_cpu_capability()
    return out


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
    """What each library runs under ``env``: :func:`in_effect` in a fresh interpreter."""
    try:
        return run_fresh(in_effect, env=env)
    except FreshProcessError as err:
        raise RuntimeError(f"bench isa: the probe failed under {env}: {err}") from err


def _render(profile: str, size: int | None, seed: int, out: Path, workers: int) -> object:
    """The child of :func:`render_manifest`: render the sized profile into ``out`` with a fresh
    city cache beside it."""
    from benchmark.data.profiles import get_data_profile
    from benchmark.data.simulate import SimulateConfig, simulate

    cache = out.parent / f"{out.name}-cities"
    return simulate(SimulateConfig(get_data_profile(profile, size), seed, out, workers,
                                   city_cache=cache, progress=False))  # fmt: skip


def render_manifest(
    out: Path, env: dict[str, str], *, profile: str, workers: int, seed: int, size: int | None
) -> tuple[dict, str]:
    """Render the dataset into ``out`` (fresh city cache beside it) in a fresh interpreter under
    ``env`` (its output in ``out``'s sibling ``<name>.log``); returns (manifest, manifest
    sha256). RuntimeError with the failure and the log's tail if it fails."""
    log = out.parent / f"{out.name}.log"
    try:
        run_fresh(_render, profile, size, seed, out, workers, env=env, log=log)
    except FreshProcessError as err:
        raise RuntimeError(
            f"bench isa: simulate failed under {env or 'the default environment'}: {err}"
        ) from err
    data = (out / "manifest.json").read_bytes()
    return json.loads(data), hashlib.sha256(data).hexdigest()


def isa_rows() -> dict[str, dict[str, str]]:
    """``{row: environment}`` of a full run, in order: ``default`` (nothing forced), one row per
    :func:`lower_isa_settings` entry, and ``all`` (:func:`lower_isa_env`)."""
    return {"default": {}, **lower_isa_settings(), "all": lower_isa_env()}


@dataclass(frozen=True)
class IsaBenchConfig:
    """``bench isa``: render ``profile`` (``size`` standard pairs, None: the profile's; dataset
    ``seed``) with ``workers`` processes once per setting (``only``: these besides default;
    None: every one)."""

    profile: str = "smoke"
    size: int | None = None
    workers: int = 2
    seed: int = 0
    only: tuple[str, ...] | None = None


@dataclass(frozen=True)
class IsaRow:
    """One setting's render: its ``name``, the manifest's ``digest`` (sha256), whether it equals
    the default row's (``same``), the render's ``wall`` seconds, the environment ``forced``, what
    the probe found ``in_effect`` and the dataset ``files`` whose sha256 differs from the default
    row's."""

    name: str
    digest: str
    same: bool
    wall: float
    forced: dict[str, str]
    in_effect: dict[str, str]
    differing: tuple[str, ...]

    def lines(self) -> list[str]:
        """The row's two lines: digest, same/DIFFERS, wall and the variables forced; in effect."""
        same = "same" if self.same else "DIFFERS"
        forced = " ".join(f"{k}={v}" for k, v in self.forced.items()) or "(none)"
        effect = ", ".join(f"{k} {v}" for k, v in self.in_effect.items())
        return [
            f"{self.name:9s} {self.digest[:16]}  {same:7s} {self.wall:5.1f} s  {forced}",
            f"{'':9s} in effect: {effect}",
        ]


@dataclass(frozen=True)
class IsaBenchResult:
    """What :func:`bench_isa` found: one :class:`IsaRow` per setting (default first)."""

    rows: tuple[IsaRow, ...]

    @property
    def same(self) -> bool:
        """Every row's dataset files are the default row's, byte for byte."""
        return not any(row.differing for row in self.rows)

    def lines(self) -> list[str]:
        """Two lines per row, the files differing per row, and the verdict."""
        lines = [line for row in self.rows for line in row.lines()]
        lines += [
            f"{row.name}: files differing from default: {', '.join(row.differing)}"
            for row in self.rows
            if row.differing
        ]
        if self.same:
            return [*lines, "all digests equal"]
        return [*lines, "digests differ: the bytes depend on the CPU"]


def bench_isa(config: IsaBenchConfig) -> IsaBenchResult:
    """Render the dataset once per setting and compare; returns the rows (``same``: every
    digest equal). The opening line (profile, workers, CPU, glibc) goes to
    :func:`benchmark.progress.status`. InputError: an unknown profile or setting, no workers."""
    from benchmark.data.profiles import DATA_PROFILES
    from benchmark.progress import status

    if config.profile not in DATA_PROFILES:
        raise InputError(
            f"bench isa: unknown IsaBenchConfig.profile {config.profile!r}; one of "
            f"{sorted(DATA_PROFILES)}"
        )
    if config.workers < 1:
        raise InputError(f"bench isa: IsaBenchConfig.workers must be >= 1, got {config.workers}")
    rows = isa_rows()
    if config.only is not None:
        unknown = sorted(set(config.only) - set(rows))
        if unknown:
            raise InputError(
                f"bench isa: unknown IsaBenchConfig.only {unknown}; expected some of {list(rows)}"
            )
        rows = {k: v for k, v in rows.items() if k == "default" or k in config.only}
    # Before the minutes of rendering: what runs, and on which CPU.
    status(
        f"uavbench bench isa: profile {config.profile}, {config.workers} workers; "
        f"CPU {cpu_model()}; glibc {platform.libc_ver()[1]}"
    )
    results: dict[str, tuple[dict, str, float, dict[str, str]]] = {}
    with tempfile.TemporaryDirectory(prefix="uavbench-isa-") as tmp:
        for name, env in rows.items():
            effect = probe(env)
            t0 = time.perf_counter()
            manifest, digest = render_manifest(
                Path(tmp) / name,
                env,
                profile=config.profile,
                workers=config.workers,
                seed=config.seed,
                size=config.size,
            )
            results[name] = (manifest, digest, time.perf_counter() - t0, effect)
    base_manifest, base_digest = results["default"][:2]
    base = base_manifest["files"]
    out = []
    for name, (manifest, digest, wall, effect) in results.items():
        files = [
            f for f, e in manifest["files"].items() if base.get(f, {}).get("sha256") != e["sha256"]
        ]
        out.append(IsaRow(name, digest, digest == base_digest, wall, dict(rows[name]), effect,
                          tuple(sorted(files))))  # fmt: skip
    return IsaBenchResult(tuple(out))
