"""``simulate_dataset``: build the worlds, plan the flights, render the shards, write the manifest.

Resumable and deterministic: the plan is a pure function of (profile, seed, generator version);
each shard is rendered from its own sample seeds and written atomically, a rerun skips every
complete shard, and the manifest (with sha256 of every file) is written last. Workers are forked
processes that share the cities copy-on-write and use one thread each.
"""

from __future__ import annotations

import dataclasses
import io
import json
import multiprocessing as mp
import os
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from benchmark.data.camera_effects import apply_camera_effects
from benchmark.data.format import (
    CONFIG,
    FORMAT_VERSION,
    MANIFEST,
    DatasetError,
    atomic_save_npy,
    atomic_write_bytes,
    canonical_json,
    file_entry,
    npy_complete,
    read_json,
    shard_name,
)
from benchmark.data.profiles import FLIGHT_STYLE, GENERALIZED_STYLE, TRAIN_STYLES, Profile
from benchmark.progress import Progress

PLAN_VERSION = 1  # bump when benchmark.sim.flights / splits change what they produce


SPLIT_NOTES = {
    "standard/{train,val,test}": "oxford + cambridge; whole flights per split, val/test flights "
    "redrawn if a frame is within 10 m and 10 deg (heading and pitch) of a training frame",
    "generalized/{train,val}": "= standard/{train,val}",
    "generalized/test": "london (unseen style)",
    "flight/pitch{0,-10,-50}": "industrial, pitch fixed, 70-90 m; satellite image from the "
    "earlier-time world (changed_city), 2.5 x 1.2 km; camera noise, blur, JPEG on UAV images",
    "height{h}/{train,test}": "subsets of standard/{train,test} (whole flights) paired with a "
    "satellite image shot from h m, footprint 2 x 1 km * h / 1000 (paper Fig. 5)",
    "pitch{hi}to{lo}/test": "new oxford + cambridge test flights with pitch in [lo, hi] deg "
    "(paper Fig. 6, view difference)",
}


class ConfigMismatchError(ValueError):
    """The output directory holds a dataset (or a partial one) with another config."""


def dataset_config(profile: Profile, seed: int) -> dict[str, Any]:
    from benchmark.sim import GENERATOR_VERSION

    config = {
        "format_version": FORMAT_VERSION,
        "generator_version": str(GENERATOR_VERSION),
        "plan_version": PLAN_VERSION,
        "profile": profile.to_dict(),
        "seed": int(seed),
    }
    return json.loads(canonical_json(config))  # tuples -> lists, as read back from config.json


def check_output_dir(out: Path, config: dict[str, Any]) -> str:
    """``'new'``, ``'resume'`` or ``'complete'``; ConfigMismatchError if ``out`` holds another.

    Never modifies ``out``.
    """
    if not out.exists():
        return "new"
    if not out.is_dir():
        raise ConfigMismatchError(f"--out {out} exists and is not a directory")
    cfg_path = out / CONFIG
    if not cfg_path.is_file():
        if any(out.iterdir()):
            raise ConfigMismatchError(
                f"--out {out} is a non-empty directory without {CONFIG}; refusing to write into it"
            )
        return "new"
    old = read_json(cfg_path, "dataset config")
    if old != config:
        diffs = _diff(old, config)
        raise ConfigMismatchError(
            f"--out {out} holds a dataset with a different config ({'; '.join(diffs[:8])}); "
            f"choose another --out or the same profile/size/seed"
        )
    return "complete" if (out / MANIFEST).is_file() else "resume"


def _diff(a: Any, b: Any, prefix: str = "") -> list[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for k in sorted(set(a) | set(b)):
            out += _diff(a.get(k), b.get(k), f"{prefix}{k}.")
        return out
    return [] if a == b else [f"{prefix.rstrip('.')}: existing {a!r} != requested {b!r}"]


def parquet_bytes(df: pd.DataFrame) -> bytes:
    """Deterministic parquet bytes (no index, snappy, fixed row group)."""
    buf = io.BytesIO()
    table = pa.Table.from_pandas(df.reset_index(drop=True), preserve_index=False)
    pq.write_table(table, buf, compression="snappy", row_group_size=1 << 20)
    return buf.getvalue()


def build_cities(profile: Profile, seed: int, cache_dir: Path | None) -> dict[tuple[str, str], Any]:
    """All worlds of a dataset: ``{(style, "now"|"earlier"): City}``."""
    from benchmark.sim import build_city, changed_city
    from benchmark.sim.splits import city_seed

    kwargs: dict[str, Any] = {"cache_dir": cache_dir, "metres_per_px": profile.city_metres_per_px}
    if profile.city_size_m is not None:
        kwargs["size_m"] = tuple(profile.city_size_m)
    cities = {}
    for style in (*TRAIN_STYLES, GENERALIZED_STYLE, FLIGHT_STYLE):
        cities[(style, "now")] = build_city(style, city_seed(seed, style), **kwargs)
    now = cities[(FLIGHT_STYLE, "now")]
    change = city_seed(seed, FLIGHT_STYLE, "earlier")
    cities[(FLIGHT_STYLE, "earlier")] = changed_city(now, change, cache_dir=cache_dir)
    return cities


@dataclass
class _Context:
    """What rendering needs. ``cities`` is rebuilt in each worker by ``city_factory``."""

    root: Path
    profile: Profile
    seed: int
    cities: dict[tuple[str, str], Any]
    uav: pd.DataFrame
    sat: pd.DataFrame


_CTX: _Context | None = None


def _single_thread() -> None:
    """One thread per worker for numba/OpenMP/BLAS/cv2/torch: parallelism comes from processes."""
    os.environ.update(OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", NUMBA_NUM_THREADS="1")
    import cv2
    import torch

    cv2.setNumThreads(1)
    torch.set_num_threads(1)


def _worker_init(
    root: Path,
    profile: Profile,
    seed: int,
    city_factory: Callable[[], dict[tuple[str, str], Any]],
    uav: pd.DataFrame,
    sat: pd.DataFrame,
) -> None:
    global _CTX
    _single_thread()  # before the factory imports numba (it reads NUMBA_NUM_THREADS once)
    _CTX = _Context(root, profile, seed, city_factory(), uav, sat)


def render_uav_rows(ctx: _Context, rows: pd.DataFrame) -> np.ndarray:
    """Render UAV samples; uint8 ``(n, S, S, 3)``. Each row's own seed drives its camera effects."""
    from benchmark.sim import Camera, render_uav
    from benchmark.sim.splits import sample_seed

    p = ctx.profile
    camera = Camera(p.image_size, p.image_size, p.fov_deg)
    out = np.empty((len(rows), p.image_size, p.image_size, 3), np.uint8)
    for j, r in enumerate(rows.itertuples(index=False)):
        img = render_uav(
            ctx.cities[(r.city, "now")],
            np.array([r.E, r.N, r.U]),
            r.yaw,
            r.pitch,
            r.roll,
            camera,
            supersample=p.supersample,
        )
        if r.camera_effects:
            img = apply_camera_effects(
                img, np.random.default_rng(sample_seed(ctx.seed, r.uav_index))
            )
        out[j] = img
    return out


def render_sat_rows(ctx: _Context, rows: pd.DataFrame) -> np.ndarray:
    """Render satellite images; uint8 ``(n, S, S, 3)``."""
    from benchmark.sim import render_satellite

    p = ctx.profile
    out = np.empty((len(rows), p.image_size, p.image_size, 3), np.uint8)
    for j, r in enumerate(rows.itertuples(index=False)):
        out[j] = render_satellite(
            ctx.cities[(r.city, r.variant)],
            (r.E, r.N),
            height_m=r.height_m,
            footprint_m=(r.footprint_E_m, r.footprint_N_m),
            size=p.image_size,
        )
    return out


def _shard_rows(table: pd.DataFrame, k: int, size: int) -> pd.DataFrame:
    return table.iloc[k * size : (k + 1) * size]


def shard_size(kind: str, p: Profile) -> int:
    """Images per shard; satellite shards are small so their costly renders spread out."""
    return p.shard_size if kind == "uav" else p.sat_shard_size


def _shard_shape(kind: str, n_rows: int, k: int, p: Profile) -> tuple[int, int, int, int]:
    size = shard_size(kind, p)
    return (min(size, n_rows - k * size), p.image_size, p.image_size, 3)


def _run_task(task: tuple[str, int]) -> tuple[str, int, int]:
    ctx = _CTX
    assert ctx is not None, "worker context not set"
    kind, k = task
    if kind == "warmup":  # one tiny frame: loads the renderer's compiled code in this process
        tiny = dataclasses.replace(ctx, profile=dataclasses.replace(ctx.profile, image_size=8))
        render_uav_rows(tiny, ctx.uav.iloc[:1])
        time.sleep(0.05)  # let the other workers take the remaining warm-up tasks
        return kind, os.getpid(), 0
    table = ctx.uav if kind == "uav" else ctx.sat
    rows = _shard_rows(table, k, shard_size(kind, ctx.profile))
    images = render_uav_rows(ctx, rows) if kind == "uav" else render_sat_rows(ctx, rows)
    atomic_save_npy(ctx.root / shard_name(kind, k), images)
    return kind, k, len(rows)


def _remove_stale_temporaries(out: Path) -> None:
    """Delete ``.name.tmp<pid>`` files left by a killed run (only those of dead processes)."""
    for tmp in [*out.glob(".*.tmp*"), *out.glob("*/.*.tmp*")]:
        pid = tmp.name.rsplit(".tmp", 1)[-1]
        try:
            os.kill(int(pid), 0)
        except ProcessLookupError:
            tmp.unlink(missing_ok=True)
        except (ValueError, PermissionError):
            pass


class RenderPool:
    """Worker processes that render shards of one ``_Context`` (``with RenderPool(...) as p``).

    With ``workers > 1`` and a picklable ``city_factory`` (returning ``ctx.cities``, normally by
    loading them from the city cache, which memory-maps them) the workers are *spawned*, not
    forked: a forked child deadlocks in OpenCV's or OpenMP's thread pool when the parent used it
    before forking. Otherwise the shards are rendered in this process.
    """

    def __init__(
        self,
        ctx: _Context,
        workers: int,
        city_factory: Callable[[], dict[tuple[str, str], Any]] | None = None,
    ) -> None:
        self.ctx = ctx
        self.workers = workers if city_factory is not None else 1
        self._factory = city_factory
        self._pool: Any = None

    def __enter__(self) -> RenderPool:
        if self.workers > 1:
            c = self.ctx
            initargs = (c.root, c.profile, c.seed, self._factory, c.uav, c.sat)
            self._pool = mp.get_context("spawn").Pool(
                self.workers, initializer=_worker_init, initargs=initargs
            )
        return self

    def __exit__(self, *exc: object) -> None:
        if self._pool is not None:
            self._pool.terminate()
            self._pool.join()
            self._pool = None

    def imap(self, tasks: list[tuple[str, int]]) -> Iterator[tuple[str, int, int]]:
        """Render and write ``tasks`` (``("uav"|"sat", k)``); yields ``(kind, k, n)`` as done."""
        global _CTX
        if self._pool is not None:
            yield from self._pool.imap_unordered(_run_task, tasks)
            return
        _CTX = self.ctx
        try:
            for task in tasks:
                yield _run_task(task)
        finally:
            _CTX = None

    def warm_up(self) -> None:
        """Wait until every worker has loaded the cities and the compiled renderer."""
        seen: set[int] = set()
        for _ in range(200):  # a worker still starting takes no task; ask again until all answer
            seen |= {pid for _, pid, _ in self.imap([("warmup", k) for k in range(self.workers)])}
            if len(seen) >= self.workers:
                return


def n_shards(kind: str, n_rows: int, p: Profile) -> int:
    return -(-n_rows // shard_size(kind, p))


def simulate_dataset(
    out: Path,
    profile: Profile,
    seed: int = 0,
    *,
    workers: int = 1,
    cache_dir: Path | None = None,
    max_tasks: int | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Write (or resume, or confirm) the dataset of (profile, seed) at ``out``.

    ``max_tasks`` stops after that many shards without writing the manifest (an interruption, for
    tests and benchmarks). Returns timing statistics. Raises ConfigMismatchError before touching
    ``out`` if it holds a different dataset.
    """
    out = Path(out)
    config = dataset_config(profile, seed)
    state = check_output_dir(out, config)
    stats: dict[str, Any] = {"state": state}
    if state == "complete":
        return stats
    out.mkdir(parents=True, exist_ok=True)
    if state == "new":
        atomic_write_bytes(out / CONFIG, canonical_json(config))
    _remove_stale_temporaries(out)

    t0 = time.perf_counter()
    cities = build_cities(profile, seed, cache_dir)
    stats["cities_s"] = time.perf_counter() - t0

    from benchmark.sim.splits import make_plan

    t0 = time.perf_counter()
    plan = make_plan(profile, {s: c for (s, v), c in cities.items() if v == "now"}, seed)
    stats["plan_s"] = time.perf_counter() - t0
    tables = {"uav.parquet": plan.uav, "sat.parquet": plan.sat, "pairs.parquet": plan.pairs}
    for name, df in tables.items():
        data = parquet_bytes(df)
        path = out / name
        if path.is_file() and path.read_bytes() != data:
            raise DatasetError(f"{path} differs from the plan this code computes; delete {out}")
        if not path.is_file():
            atomic_write_bytes(path, data)

    tasks = [("sat", k) for k in range(n_shards("sat", len(plan.sat), profile))]
    tasks += [("uav", k) for k in range(n_shards("uav", len(plan.uav), profile))]

    def shape_of(kind: str, k: int) -> tuple[int, int, int, int]:
        return _shard_shape(kind, len(plan.uav if kind == "uav" else plan.sat), k, profile)

    sizes = {t: shape_of(*t)[0] for t in tasks}
    pending = [t for t in tasks if not npy_complete(out / shard_name(*t), shape_of(*t))]
    todo = pending if max_tasks is None else pending[:max_tasks]
    total = len(plan.uav) + len(plan.sat)
    done = total - sum(sizes[t] for t in pending)

    ctx = _Context(out, profile, seed, cities, plan.uav, plan.sat)
    t0 = time.perf_counter()
    with Progress(total, "simulate", unit="img", initial=done, enabled=progress) as bar:
        factory = partial(build_cities, profile, seed, cache_dir)
        with RenderPool(ctx, min(workers, len(todo)), factory) as pool:
            for kind, k, n in pool.imap(todo):
                bar.update(n, postfix=f"{kind} shard {k}")
    stats["render_s"] = time.perf_counter() - t0
    stats["rendered_uav"] = sum(sizes[t] for t in todo if t[0] == "uav")
    stats["rendered_sat"] = sum(sizes[t] for t in todo if t[0] == "sat")
    if len(todo) < len(pending):
        stats["state"] = "interrupted"
        return stats
    write_manifest(out, config, plan, {t: shape_of(*t) for t in tasks})
    stats["state"] = "written"
    return stats


def write_manifest(
    out: Path, config: dict[str, Any], plan: Any, shards: dict[tuple[str, int], tuple[int, ...]]
) -> None:
    files = {
        name: file_entry(out, name) for name in ("uav.parquet", "sat.parquet", "pairs.parquet")
    }
    for (kind, k), shape in sorted(shards.items()):
        files[shard_name(kind, k)] = file_entry(out, shard_name(kind, k), shape)
    counts = plan.pairs.split.value_counts()
    manifest = {
        **config,
        "image_size": config["profile"]["image_size"],
        "shard_size": config["profile"]["shard_size"],
        "sat_shard_size": config["profile"]["sat_shard_size"],
        "counts": {
            "uav_images": len(plan.uav),
            "sat_images": len(plan.sat),
            "pairs": len(plan.pairs),
        },
        "splits": {s: int(counts[s]) for s in plan.splits},
        "units": {
            "E, N, U, dE, dN, dU, sat_*": "metres, ENU navigation frame",
            "yaw, pitch, roll, sat_*": "radians, R_b^n = Rz(yaw) Rx(pitch) Ry(roll)",
            "R00..R22": "R_uav^sat = R_uav^n (R_sat^n)^T, row-major (paper Eq. 2)",
            "dE, dN, dU": "UAV position minus satellite capture point",
            "images": "uint8 (n, H, W, 3) RGB, .npy shards",
        },
        "split_definitions": SPLIT_NOTES,
        "files": files,
    }
    atomic_write_bytes(out / MANIFEST, canonical_json(manifest))
