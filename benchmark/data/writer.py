"""``simulate_dataset``: build the worlds, plan the flights, render the shards, write the manifest.

Resumable and deterministic: the plan is a pure function of (profile, seed, generator version);
each shard is rendered from its own sample seeds and written atomically, a rerun skips every
complete shard, and the manifest (with sha256 of every file) is written last. Workers are forked
processes that share the cities copy-on-write and use one thread each.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from benchmark.data.format import (
    CONFIG,
    FORMAT_VERSION,
    MANIFEST,
    TABLES,
    DatasetError,
    atomic_write_bytes,
    canonical_json,
    read_json,
    read_manifest,
    shard_name,
)
from benchmark.data.integrity import check_files
from benchmark.data.journal import JOURNAL, append_journal, read_journal, remove_journal, trusted
from benchmark.data.profiles import FLIGHT_STYLE, GENERALIZED_STYLE, TRAIN_STYLES, DataProfile
from benchmark.data.render_pool import RenderContext, RenderPool, _shard_shape, shard_size
from benchmark.errors import InputError
from benchmark.locks import work_lock
from benchmark.progress import Progress, status

LOCK = ".simulate.lock"  # one writer per dataset directory (benchmark.locks)
# Bump when benchmark.sim.flights / splits change what they produce. 3: labels through
# benchmark.sim.detmath (libm, fixed-order products) instead of torch (issue 20). 4: odometry
# columns (odo_*) and the long/* test splits (issue 39).
PLAN_VERSION = 4


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
    "frames/{train,val,test}": "the frames of all standard flights re-split at random (a naive "
    "split of video frames, for the leakage audit); same sizes as standard/*",
    "towns/{train,val,test,london}": "many small procedurally distinct towns, one centre each; "
    "train/val/test towns are distinct oxford/cambridge-style towns, london towns the held-out "
    "style",
    "confirm/{standard,towns,generalized}": "the confirmation draw (issue 38): new test flights "
    "as large as standard/test, towns/test, generalized/test, from seed streams nothing was "
    "chosen on",
    "long/{standard,towns,london}": "test-only flights of 62 s (a sample every 2 s) in the "
    "standard test cities, the towns/test towns and the london style, for the flight fusion",
    "odometry": "every UAV sample carries the motion since the previous sample of its flight "
    "(odo_dyaw rad; odo_dx, odo_dy, odo_dz m in the levelled heading frame of the previous "
    "sample; NaN on a flight's first sample) with the profile's odometry noise",
    "illumination": "every flight has its own illumination state (sun, shadows) and fog "
    "visibility, every satellite image its own independent state (columns light, sun_az, sun_el, "
    "visibility_m, sat_light, sat_sun_az, sat_sun_el)",
}


class ConfigMismatchError(InputError):
    """The output directory holds a dataset (or a partial one) with another config (an
    :class:`~benchmark.errors.InputError`, so a ValueError as before).

    ``differences``: one ``"field: existing .. != requested .."`` per differing config field
    (empty when ``out`` is no dataset at all), for callers that word their own fix."""

    def __init__(self, message: str, differences: tuple[str, ...] = ()) -> None:
        super().__init__(message)
        self.differences = differences

    @classmethod
    def of_dataset(cls, out: Path, differences: tuple[str, ...]) -> ConfigMismatchError:
        """``out`` holds a dataset whose config differs from the requested one in
        ``differences``."""
        return cls(
            f"output directory {out} holds a dataset with a different config "
            f"({_summary(differences)}); choose another output directory or the same "
            "profile/size/seed",
            differences,
        )

    @property
    def summary(self) -> str:
        """The first eight differences, ``"; "``-joined (the message's parenthesis)."""
        return _summary(self.differences)


def _summary(differences: tuple[str, ...]) -> str:
    return "; ".join(differences[:8])


def dataset_config(profile: DataProfile, seed: int) -> dict[str, Any]:
    from benchmark.sim import GENERATOR_VERSION, source_digest

    config = {
        "format_version": FORMAT_VERSION,
        "generator_version": str(GENERATOR_VERSION),
        # The simulator's code itself: a dataset rendered by other code is never resumed or
        # reused as if it were this code's (issue 10, reproducibility across machines).
        "generator_source": source_digest(),
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
        raise ConfigMismatchError(f"output directory {out} exists and is not a directory")
    cfg_path = out / CONFIG
    if not cfg_path.is_file():
        if any(p.name not in (LOCK, JOURNAL) for p in out.iterdir()):
            raise ConfigMismatchError(
                f"output directory {out} is a non-empty directory without {CONFIG}; refusing to "
                "write into it"
            )
        return "new"
    old = read_json(cfg_path, "dataset config")
    if old != config:
        raise ConfigMismatchError.of_dataset(out, tuple(_diff(old, config)))
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


def build_cities(
    profile: DataProfile, seed: int, cache_dir: Path | None, *, progress: bool = False
) -> dict[tuple[str, str], Any]:
    """All worlds of a dataset: ``{(name, "now"|"earlier"): City}`` (paper styles and towns)."""
    from benchmark.sim import build_city, build_town, changed_city, city_seed, town_list

    kwargs: dict[str, Any] = {"cache_dir": cache_dir, "metres_per_px": profile.city_metres_per_px}
    if profile.city_size_m is not None:
        kwargs["size_m"] = tuple(profile.city_size_m)
    cities = {}
    for style in (*TRAIN_STYLES, GENERALIZED_STYLE, FLIGHT_STYLE):
        cities[(style, "now")] = build_city(style, city_seed(seed, style), **kwargs)
    now = cities[(FLIGHT_STYLE, "now")]
    change = city_seed(seed, FLIGHT_STYLE, "earlier")
    cities[(FLIGHT_STYLE, "earlier")] = changed_city(now, change, cache_dir=cache_dir)
    towns = town_list(
        tuple(profile.n_towns),
        seed,
        train_styles=TRAIN_STYLES,
        london_style=GENERALIZED_STYLE,
        confirm_draw=profile.confirm_draw,
    )
    size = tuple(profile.town_size_m)
    with Progress(len(towns), "towns", unit="town", enabled=progress and bool(towns)) as bar:
        for town in towns:
            cities[(town.name, "now")] = build_town(
                town, size_m=size, metres_per_px=profile.town_metres_per_px, cache_dir=cache_dir
            )
            bar.update(1)
    return cities


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


def n_shards(kind: str, n_rows: int, p: DataProfile) -> int:
    return -(-n_rows // shard_size(kind, p))


def dataset_problems(out: Path) -> list[tuple[str, str]]:
    """``(file, problem)`` for every file of a finished dataset that disagrees with its manifest
    (cached sha256: a stat per file once each was hashed, ``benchmark.data.integrity``)."""
    try:
        manifest = read_manifest(out)
    except DatasetError as err:
        return [(MANIFEST, str(err))]
    problems: list[tuple[str, str]] = []
    check_files(out, manifest, list(manifest["files"]), collect=problems)
    return problems


def _start_repair(out: Path, problems: list[tuple[str, str]], say: Callable[[str], None]) -> None:
    """Turn a finished dataset with bad files into a resumable one: journal the files that still
    match the manifest, then remove the manifest (the bad files get rendered again)."""
    bad = {rel for rel, _ in problems}
    for _, problem in problems:
        say(f"simulate: {problem}; rendering it again")
    if MANIFEST not in bad:
        files = read_manifest(out)["files"]
        for rel, entry in files.items():
            if rel not in bad:
                append_journal(out, rel, entry["sha256"], int(entry["bytes"]), "manifest")
    (out / MANIFEST).unlink(missing_ok=True)


def simulate_dataset(
    out: Path,
    profile: DataProfile,
    seed: int = 0,
    *,
    workers: int = 1,
    cache_dir: Path | None = None,
    max_tasks: int | None = None,
    progress: bool = True,
    wait: bool = True,
    notify: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Write (or resume, repair or confirm) the dataset of (profile, seed) at ``out``.

    A finished dataset is confirmed by a cached checksum check of every file; a file that
    disagrees with the manifest is rendered again. Shards found on disk are trusted only through
    the render journal (``benchmark.data.journal``); others are rendered again and compared byte
    for byte, a differing one is replaced. One process renders into ``out`` at a time: the lock
    ``out/.simulate.lock`` (``benchmark.locks``); with ``wait`` a second call waits for it, else it
    raises ``LockBusyError`` naming the holder. What it notices on the way (the wait, a lock taken
    over, a file rendered again) goes to ``notify``, default :func:`benchmark.progress.status`.

    ``max_tasks`` stops after that many shards without writing the manifest (an interruption, for
    tests and benchmarks). Returns statistics: ``state`` (complete, written, interrupted),
    timings, ``rendered_uav``/``rendered_sat`` images, ``replaced`` (shards whose bytes on disk
    differed from their render). Raises ConfigMismatchError before touching ``out`` if it holds a
    different dataset.
    """
    out = Path(out)
    say = notify or status
    config = dataset_config(profile, seed)
    state = check_output_dir(out, config)
    if state == "complete" and not dataset_problems(out):
        return {"state": "complete"}
    out.mkdir(parents=True, exist_ok=True)
    what = f"uavbench simulate (profile {profile.name}, seed {seed})"
    with work_lock(out / LOCK, what=what, wait=wait, notify=say):
        state = check_output_dir(out, config)  # another process may have finished it meanwhile
        if state == "complete":
            problems = dataset_problems(out)
            if not problems:
                return {"state": "complete"}
            _start_repair(out, problems, say)
        elif state == "new":
            atomic_write_bytes(out / CONFIG, canonical_json(config))
        return _render(out, profile, seed, config, workers, cache_dir, max_tasks, progress, say)


def _render(
    out: Path,
    profile: DataProfile,
    seed: int,
    config: dict[str, Any],
    workers: int,
    cache_dir: Path | None,
    max_tasks: int | None,
    progress: bool,
    say: Callable[[str], None],
) -> dict[str, Any]:
    """Plan, render what is not trusted on disk, write the manifest (under the lock)."""
    _remove_stale_temporaries(out)
    stats: dict[str, Any] = {"state": "resume"}
    t0 = time.perf_counter()
    cities = build_cities(profile, seed, cache_dir, progress=progress)
    stats["cities_s"] = time.perf_counter() - t0

    from benchmark.sim import make_plan

    t0 = time.perf_counter()
    plan = make_plan(profile, cities, seed)
    stats["plan_s"] = time.perf_counter() - t0
    known: dict[str, tuple[int, str]] = {}  # file -> (bytes, sha256) of bytes this code produced
    tables = {"uav.parquet": plan.uav, "sat.parquet": plan.sat, "pairs.parquet": plan.pairs}
    for name, df in tables.items():
        data = parquet_bytes(df)
        path = out / name
        if path.is_file() and path.read_bytes() != data:
            say(f"simulate: {path} differs from the plan (same config and code): rewriting it")
        if not path.is_file() or path.read_bytes() != data:
            atomic_write_bytes(path, data)
        known[name] = (len(data), hashlib.sha256(data).hexdigest())

    tasks = [("sat", k) for k in range(n_shards("sat", len(plan.sat), profile))]
    tasks += [("uav", k) for k in range(n_shards("uav", len(plan.uav), profile))]

    def shape_of(kind: str, k: int) -> tuple[int, int, int, int]:
        return _shard_shape(kind, len(plan.uav if kind == "uav" else plan.sat), k, profile)

    sizes = {t: shape_of(*t)[0] for t in tasks}
    journal = read_journal(out)
    pending = []
    for t in tasks:
        entry = trusted(out, shard_name(*t), journal)
        if entry is None:
            pending.append(t)
        else:
            known[shard_name(*t)] = (entry["bytes"], entry["sha256"])
    todo = pending if max_tasks is None else pending[:max_tasks]
    total = len(plan.uav) + len(plan.sat)
    done = total - sum(sizes[t] for t in pending)

    ctx = RenderContext(out, profile, seed, cities, plan.uav, plan.sat)
    stats["replaced"] = []
    t0 = time.perf_counter()
    with Progress(total, "simulate", unit="img", initial=done, enabled=progress) as bar:
        factory = partial(build_cities, profile, seed, cache_dir)
        with RenderPool(ctx, min(workers, len(todo)), factory) as pool:
            for r in pool.imap(todo):
                rel = shard_name(r.kind, r.k)
                append_journal(out, rel, r.sha256, r.bytes)
                known[rel] = (r.bytes, r.sha256)
                if r.status == "replaced":
                    stats["replaced"].append(rel)
                    say(f"simulate: {out / rel} differed from its render (corrupted): replaced")
                bar.update(r.n, postfix=f"{r.kind} shard {r.k}")
    stats["render_s"] = time.perf_counter() - t0
    stats["rendered_uav"] = sum(sizes[t] for t in todo if t[0] == "uav")
    stats["rendered_sat"] = sum(sizes[t] for t in todo if t[0] == "sat")
    if len(todo) < len(pending):
        stats["state"] = "interrupted"
        return stats
    write_manifest(out, config, plan, {t: shape_of(*t) for t in tasks}, known)
    remove_journal(out)
    stats["state"] = "written"
    return stats


def write_manifest(
    out: Path,
    config: dict[str, Any],
    plan: Any,
    shards: dict[tuple[str, int], tuple[int, ...]],
    known: dict[str, tuple[int, str]],
) -> None:
    """The manifest, from the digests of bytes this code produced (``known``: file -> (bytes,
    sha256)), never from hashing what happens to be on disk."""

    def entry(rel: str, shape: tuple[int, ...] | None = None) -> dict[str, Any]:
        nbytes, sha = known[rel]
        return {"bytes": nbytes, "sha256": sha, **({"shape": list(shape)} if shape else {})}

    files = {name: entry(name) for name in TABLES}
    for (kind, k), shape in sorted(shards.items()):
        files[shard_name(kind, k)] = entry(shard_name(kind, k), shape)
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
