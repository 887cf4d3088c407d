"""``uavbench verify DATASET``: check every file of a dataset against its manifest, in full.

    uavbench verify data/quick [--quiet]

Hashes every file (sha256; no cache is trusted, so this also finds what a stat cannot see, such as
bit rot), and checks sizes, the shape and dtype of every shard, the row counts of the tables and
of every split, and that ``config.json`` agrees with the manifest. :func:`verify_and_report`
returns the verdict (:class:`VerifyReport`): each bad file, what is wrong with it and the fix (the
``uavbench simulate`` call that renders it again: simulate re-renders exactly the files that
disagree with the manifest); the command exits 0 when all is good, 1 otherwise, and 2 for a path
that is not a dataset at all (InputError). Files found good are recorded in the verification cache
(``benchmark.data.integrity``), so the next ``train`` opens them with a stat.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from benchmark.data.format import CONFIG, MANIFEST, DatasetError, read_json, read_manifest
from benchmark.data.integrity import check_files
from benchmark.data.profiles import DATA_PROFILES, DataProfile, get_data_profile
from benchmark.errors import InputError
from benchmark.progress import Progress


@dataclass(frozen=True)
class Problem:
    """One thing wrong: the file (relative to the dataset), what is wrong with it, and its kind:
    ``"file"`` (bytes disagree with the manifest: re-render), ``"manifest"`` (the manifest
    disagrees with itself or its tables: rebuild it), ``"config"`` (config.json)."""

    file: str
    what: str
    kind: str = "file"


def simulate_command(root: Path, manifest: dict[str, Any]) -> str:
    """The ``uavbench simulate`` call that renders this dataset (or, for a profile the command
    does not offer, a description of it)."""
    stored = manifest.get("profile", {})
    seed = int(manifest.get("seed", 0))
    name = stored.get("name", "?")
    if name in DATA_PROFILES:
        size = stored.get("n_standard")
        base = DATA_PROFILES[name]
        try:
            again = base if size == base.n_standard else get_data_profile(name, size)
        except (ValueError, TypeError):
            again = None
        if again is not None and again.to_dict() == DataProfile.from_dict(stored).to_dict():
            args = f"--profile {name}" + ("" if again is base else f" --size {size}")
            args += f" --seed {seed}" if seed else ""
            return f"`uavbench simulate {args} --out {root}`"
    return f"the command that rendered it (profile {name}, seed {seed}) with its output {root}"


def _shape_problem(path: Path, entry: dict[str, Any]) -> str | None:
    try:
        arr = np.load(path, mmap_mode="r", allow_pickle=False)
    except (OSError, ValueError) as err:
        return f"{path} is not a readable .npy ({err})"
    want = tuple(entry["shape"])
    if arr.dtype != np.uint8 or tuple(arr.shape) != want:
        return f"{path}: {arr.dtype} {tuple(arr.shape)}, {MANIFEST} says uint8 {want}"
    return None


def _count_problems(root: Path, manifest: dict[str, Any]) -> list[Problem]:
    import pandas as pd
    import pyarrow.parquet as pq

    out: list[Problem] = []
    counts = manifest.get("counts", {})
    for table, key in (("uav.parquet", "uav_images"), ("sat.parquet", "sat_images")):
        n = pq.read_metadata(root / table).num_rows
        if n != counts.get(key):
            out.append(
                Problem(table, f"{n} rows, {MANIFEST} counts {key} = {counts.get(key)}", "manifest")
            )
        kind = table.split(".")[0]
        in_shards = sum(
            e["shape"][0] for f, e in manifest["files"].items() if f.startswith(f"{kind}/")
        )
        if in_shards != counts.get(key):
            out.append(
                Problem(MANIFEST, f"{kind} shards hold {in_shards} images, counts {n}", "manifest")
            )
    split = pd.read_parquet(root / "pairs.parquet", columns=["split"]).split.value_counts()
    if int(split.sum()) != counts.get("pairs"):
        out.append(
            Problem(
                "pairs.parquet", f"{int(split.sum())} rows, {MANIFEST} counts pairs", "manifest"
            )
        )
    for name, want in manifest.get("splits", {}).items():
        have = int(split.get(name, 0))
        if have != want:
            out.append(
                Problem(
                    "pairs.parquet", f"split {name!r}: {have} rows, {MANIFEST} {want}", "manifest"
                )
            )
    return out


def verify_dataset(root: str | Path, *, progress: bool = False) -> list[Problem]:
    """Every problem of the dataset at ``root`` (empty: all good). DatasetError if ``root`` has no
    readable manifest (not a finished dataset)."""
    root = Path(root)
    manifest = read_manifest(root)
    files: dict[str, Any] = manifest["files"]
    problems: list[Problem] = []
    config = read_json(root / CONFIG, "dataset config") if (root / CONFIG).is_file() else None
    if config is None:
        problems.append(Problem(CONFIG, f"missing file {root / CONFIG}", "config"))
    elif any(manifest.get(k) != v for k, v in config.items()):
        problems.append(Problem(CONFIG, f"{root / CONFIG} disagrees with {MANIFEST}", "config"))
    total_mb = math.ceil(sum(int(e["bytes"]) for e in files.values()) / 1e6)
    done = [0, 0]  # bytes checked, MB shown

    def on_bytes(n: int) -> None:
        done[0] += n
        step = min(round(done[0] / 1e6), total_mb) - done[1]
        done[1] += step
        bar.update(step)

    collected: list[tuple[str, str]] = []
    with Progress(total_mb, "verify", unit="MB", enabled=progress) as bar:
        for rel in files:
            before = len(collected)
            check_files(root, manifest, [rel], mode="full", on_bytes=on_bytes, collect=collected)
            if len(collected) == before and "shape" in files[rel]:
                shape = _shape_problem(root / rel, files[rel])
                if shape is not None:
                    collected.append((rel, shape))
        bar.update(total_mb - done[1])  # the rounding remainder (and the bad files' bytes)
    problems += [Problem(rel, what) for rel, what in collected]
    bad = {p.file for p in problems}
    if not bad & {"uav.parquet", "sat.parquet", "pairs.parquet"}:
        problems += _count_problems(root, manifest)
    return problems


def _fix(root: Path) -> str:
    """The simulate call from the manifest, else from config.json (written first)."""
    for name in (MANIFEST, CONFIG):
        try:
            return simulate_command(root, read_json(root / name, name))
        except DatasetError:
            continue
    return f"the command that rendered {root}"


@dataclass(frozen=True)
class VerifyReport:
    """The verdict on the dataset at ``root``: its ``n_files`` manifest entries, the
    ``problems`` found (none: all good) and the ``fixes`` for them (the ``uavbench simulate``
    call that renders the bad files again, ...)."""

    root: Path
    n_files: int
    problems: tuple[Problem, ...] = ()
    fixes: tuple[str, ...] = ()

    @property
    def ok(self) -> bool:
        """True when every file matches the manifest."""
        return not self.problems

    def lines(self) -> list[str]:
        """The verdict as printed: one OK line, or one line per problem (naming the file) and a
        last line counting them with the fix."""
        if self.ok:
            return [
                f"{self.root}: OK, {self.n_files} files match {MANIFEST} (sha256, sizes, shapes, "
                "split counts)"
            ]
        lines = []
        for p in self.problems:
            where = str(self.root / p.file)
            lines.append(p.what if where in p.what else f"{where}: {p.what}")
        lines.append(
            f"{self.root}: {len(self.problems)} problem(s) in "
            f"{len({p.file for p in self.problems})} file(s); fix: {'; and '.join(self.fixes)}"
        )
        return lines


def verify_and_report(root: Path, *, progress: bool = True) -> VerifyReport:
    """Verify the dataset at ``root`` in full; returns the verdict with each problem and its fix
    (``ok`` when all is good). InputError when ``root`` is no dataset or on a disk error."""
    from benchmark.data.format import os_error_message

    try:
        problems = verify_dataset(root, progress=progress)
        n = len(read_manifest(root)["files"])
    except DatasetError as err:
        if not (root / CONFIG).is_file() or not (root / MANIFEST).is_file():
            raise InputError(str(err)) from None  # not a dataset, or an unfinished one
        problems, n = [Problem(MANIFEST, str(err))], 1  # a damaged manifest: simulate rebuilds it
    except OSError as err:
        message = os_error_message(err)
        if message is None:
            raise
        raise InputError(message) from None
    kinds = {p.kind for p in problems}
    fixes = []
    if "file" in kinds:
        fixes.append(
            f"rerun {_fix(root)} to render the bad files again (it re-renders exactly the files "
            f"that disagree with {MANIFEST} and keeps the rest)"
        )
    if "manifest" in kinds:
        fixes.append(
            f"{MANIFEST} disagrees with its own tables: delete {root / MANIFEST} and rerun "
            f"{_fix(root)} (it renders every shard again, compares it and rebuilds {MANIFEST})"
        )
    if "config" in kinds:
        fixes.append(f"render the dataset again into a new directory with {_fix(root)}")
    return VerifyReport(root, n, tuple(problems), tuple(fixes))
