"""The non-learned reference rows of the tables (issue 21, item 5): evaluated, cached, as rows.

A table spec lists references by name (``TableSpec.references``; ``benchmark.references``:
``geometry_oracle``, ``gravity_template``, ``feature_pnp``). Each (reference, test split of a
table that lists it) is evaluated once, whatever the training seeds (a reference has none), with
the true and with the swapped satellite image (``benchmark.data.swap``), like a model: the same
per-frame table, metrics and flight bootstrap, and the swap effect of
``benchmark.evaluation.paired.swap_effect``.

**One fallback.** A frame where a reference gives up (``reference_failed``) is evaluated without a
fallback (the cache holds the reference's own answer) and, in every table, given the pose of that
table's constant row: the constant predictor of the split's training split in that table
(``TableSpec.train_split_for``), its per-frame errors on the frame (:func:`with_fallback`). So a
reference that fails on every frame of a split reads exactly the constant row there, in every
table, and the same split in two tables that train on different splits (``towns/test`` in the
encoders table, on ``standard/train``, and in the towns table, on ``towns/train``) gets each
table's own constant. Failed frames count in ``failure_rate``.

Cache, per evaluation: ``<workdir>/references/<name>/<split_filename(split)>[__swap].csv`` (the
per-frame predictions, the format of a model's ``units/<key>/eval/*.csv``, so
``benchmark.evaluation.paired`` and ``benchmark.runner.claims.spread`` read it as they read a
model's; plus ``reference_failed`` and ``reference_score``) and ``.json`` beside it (the record:
what was evaluated and its summary), written last and atomically: its presence means the evaluation
is complete. A record is reused only when it was made with the same reference options, dataset
(manifest sha256), frame stride and reference code (sha256 of ``benchmark/references/*.py``);
otherwise the evaluation runs again. The fallback is no part of it: it is applied when a table
reads the frames.

Cost (measured on the quick dataset, 96 px, one core: about 50 ms a frame for the oracle, 75-100
ms for the template, 30-35 ms for feature + PnP): the 3,480 frames of the quick tables' test
splits, each with the true and the swapped image, take about 19 CPU-minutes for the three. A
reproduction plans them (:func:`plan_references`) as work items of :data:`CHUNK_FRAMES` frames
(the progress moves and every worker stays busy to the end) that the units' executor runs after
the training (``--workers`` processes, or Ray tasks on a cluster; about 10 minutes on 2 cores);
:func:`evaluate_references` runs the same items outside a reproduction (the executor's pool).
On every frame: the rows hold the models' frames and a paired comparison with a model needs no
alignment. A profile in :data:`PROFILE_STRIDE` evaluates every
``stride``-th frame of each flight instead (every flight kept; the table note says so).
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import os
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from benchmark.progress import status
from benchmark.runner.execute.pool import execute_items
from benchmark.runner.execute.work_items import ItemOutcome, WorkItem
from benchmark.runner.execute.worker import SATELLITE_MODES, eval_key, split_filename
from benchmark.runner.plan.specs import TableSpec
from benchmark.runner.plan.units import val_split_for

CONSTANT_LABEL = "Constant (train mean)"  # the constant predictor's rows in every table

__all__ = [
    "MAX_PROCESSES",
    "PROFILE_STRIDE",
    "ReferenceResults",
    "ReferenceWork",
    "constant_baseline",
    "dataset_splits",
    "describe_references",
    "evaluate_references",
    "fails_text",
    "failure_percent",
    "plan_references",
    "reads_text",
    "reference_labels",
    "reference_note",
    "reference_paths",
    "reference_rows",
    "strided_rows",
    "with_fallback",
]

REFERENCE_DIR = "references"  # under the reproduction's work directory
MAX_PROCESSES = 2
# Fewer frames than this to evaluate: in this process (spawning workers costs seconds each).
PARALLEL_MIN_FRAMES = 400
CHUNK_FRAMES = 100  # frames per worker task: 3-10 s each on the quick dataset
# Frame stride by reproduction profile (default 1: every frame). ``paper``: extrapolated, not
# measured: its 224 px test splits hold about 4x the quick frames at about 5x the pixels, so every
# frame would take 20+ CPU-hours; every 8th frame of each flight keeps every flight.
PROFILE_STRIDE: dict[str, int] = {"paper": 8}
# Summary keys kept out of results.csv: timings (they differ between machines and runs).
TIMING_KEYS = ("frames_per_s", "cpu_ms_per_frame")


def reference_labels(spec: TableSpec) -> list[str]:
    """The row labels of ``spec``'s references, in the spec's order (each says it is not
    learned and what true values it is given: ``Reference.label``)."""
    from benchmark.references import get_reference_class

    return [get_reference_class(name).label for name in spec.references]


def reference_paths(
    workdir: str | Path, name: str, split: str, satellite: str
) -> tuple[Path, Path]:
    """``(csv, json)`` of one cached evaluation: ``<workdir>/references/<name>/<split file
    name>[__swap].csv`` and ``.json``."""
    stem = Path(workdir) / REFERENCE_DIR / name / split_filename(eval_key(split, satellite))
    return stem.with_suffix(".csv"), stem.with_suffix(".json")


def strided_rows(flights: Iterable[object], stride: int) -> list[int]:
    """Item indices to evaluate: every ``stride``-th item of each flight (its 1st, ``stride+1``-th
    ...), in item order; every flight keeps at least one frame. ``stride`` 1: every item."""
    if stride < 1:
        raise ValueError(f"reference stride must be >= 1, got {stride}")
    seen: dict[object, int] = {}
    rows = []
    for i, flight in enumerate(flights):
        k = seen.get(flight, 0)
        if k % stride == 0:
            rows.append(i)
        seen[flight] = k + 1
    return rows


# ``benchmark/references/`` modules that compute nothing a reference row reads: the report of
# ``uavbench reference`` (one reference, one split, formatted for the command line).
_NOT_EVALUATION = frozenset({"report.py"})


def _code_digest() -> str:
    """sha256 of the references' source (``benchmark/references/*.py`` but
    :data:`_NOT_EVALUATION`, by name): a change of any reference evaluates again."""
    import benchmark.references as package

    h = hashlib.sha256()
    for path in sorted(Path(package.__file__).parent.glob("*.py")):
        if path.name not in _NOT_EVALUATION:
            h.update(path.name.encode() + b"\0" + path.read_bytes() + b"\0")
    return h.hexdigest()


@dataclass(frozen=True)
class ReferenceTask:
    """One evaluation: reference ``name`` on ``split`` with the ``satellite`` image (``true`` or
    ``swap``), every ``stride``-th frame of each flight, failed frames keeping the reference's own
    answer (each table gives them its constant row's pose: :func:`with_fallback`); the per-frame
    CSV goes to ``csv`` (None: kept in memory only)."""

    name: str
    data_root: str
    split: str
    satellite: str
    stride: int
    csv: str | None

    @property
    def key(self) -> tuple[str, str, str]:
        return self.name, self.split, self.satellite


@dataclass(frozen=True)
class Chunk:
    """Part of a :class:`ReferenceTask`: the items ``rows`` of its split, in order (a worker's
    unit of work: a few seconds each, so the progress moves and both processes stay busy)."""

    task: ReferenceTask
    rows: tuple[int, ...]


def run_chunk(chunk: Chunk) -> tuple[dict[str, float], pd.DataFrame]:
    """Evaluate one chunk (in this process or a worker): ``evaluate_reference``'s ``(summary,
    per-frame table)`` of its rows. Every frame is estimated on its own, so the chunks of a task
    put together are the task evaluated at once."""
    from benchmark.references import create_reference, evaluate_reference

    t = chunk.task
    dataset = _dataset(t.data_root, t.split, t.satellite)
    return evaluate_reference(create_reference(t.name), dataset, rows=list(chunk.rows))


@functools.lru_cache(maxsize=4)
def _dataset(root: str, split: str, satellite: str):
    from benchmark.data import PairDataset

    return PairDataset(root, split, satellite=satellite, verify="size")


def _task_rows(task: ReferenceTask) -> list[int]:
    """The items a task evaluates (:func:`strided_rows` of the split's flights)."""
    from benchmark.evaluation.evaluate import pair_columns

    dataset = _dataset(task.data_root, task.split, "true")
    return strided_rows(pair_columns(dataset).get("flight", range(len(dataset))), task.stride)


def _assemble(parts: list[tuple[dict[str, float], pd.DataFrame]]) -> tuple[dict, pd.DataFrame]:
    """The chunks of one task, in order, as ``evaluate_reference`` would return the whole:
    the concatenated frame, its summary, the frames per second of the time spent evaluating and
    the CPU milliseconds per frame."""
    from benchmark.references import reference_summary

    frame = pd.concat([f for _, f in parts], ignore_index=True)
    elapsed = sum(len(f) / s["frames_per_s"] for s, f in parts if s.get("frames_per_s"))
    summary = reference_summary(frame, elapsed or None)
    cpu_ms = sum(s["cpu_ms_per_frame"] * len(f) for s, f in parts) / len(frame)
    summary["cpu_ms_per_frame"] = cpu_ms
    return summary, frame


def constant_baseline(
    data_root: str | Path, train_split: str, eval_split: str
) -> tuple[dict[str, float], pd.DataFrame]:
    """Errors of always predicting the mean pose of ``train_split`` on ``eval_split`` (no image is
    read): the summary and the per-frame table, with each frame's ``flight`` (for the flight
    bootstrap). The tables' constant row, and the pose every failed reference frame is given."""
    from benchmark.data.dataset import PairDataset
    from benchmark.evaluation.constant import constant_predictor
    from benchmark.evaluation.evaluate import pair_columns

    train = PairDataset(data_root, train_split)
    evaluated = PairDataset(data_root, eval_split)
    summary, frame = constant_predictor(train, evaluated)
    flights = pair_columns(evaluated).get("flight")  # item order, as the frame's rows
    if flights is not None:
        frame = frame.assign(flight=list(flights))
    return summary, frame


def constant_rows(
    specs: list[TableSpec], data_root: Path, val_of: dict[str, str] | None = None
) -> tuple[list[dict], dict[tuple[str, str], pd.DataFrame]]:
    """The constant predictor's results rows of every table spec (its test splits and, for each
    training split in ``val_of``, that validation split) and its per-frame tables keyed
    ``(train split, split)``."""
    val_of = val_of or {}
    rows, frames = [], {}
    summaries: dict[tuple[str, str], dict[str, float]] = {}
    for spec in specs:
        if spec.kind != "table":
            continue
        splits = [(s, spec.train_split_for(s), "test") for s in spec.all_eval_splits()]
        for train in dict.fromkeys(t for _, t, _ in splits):
            val = val_of.get(train)
            if val is not None and val not in spec.all_eval_splits():
                splits.append((val, train, "val"))
        for split, train, role in splits:
            if (train, split) not in summaries:
                summaries[train, split], frames[train, split] = constant_baseline(
                    data_root, train, split
                )
            row = {
                "table": spec.name, "label": CONSTANT_LABEL, "paper_model": "", "x": None,
                "split": split, "satellite_input": "none", "train_split": train, "role": role,
                "seed": 0,
            }  # fmt: skip
            # It reads no image: its error with the swapped satellite image is the same.
            for satellite in SATELLITE_MODES:
                rows.append({**row, "satellite": satellite, **summaries[train, split]})
    return rows, frames


def with_fallback(frame: pd.DataFrame, constant: pd.DataFrame | None) -> pd.DataFrame | None:
    """A reference's per-frame table with every failed frame (``reference_failed``) given the
    constant predictor's prediction and errors on that frame (``constant``: its per-frame table
    on the same split, matched on ``index``); ``frame`` itself when no frame failed, None when
    some did and there is no ``constant``."""
    failed = frame["reference_failed"].astype(bool) if "reference_failed" in frame else None
    if failed is None or not failed.any():
        return frame
    if constant is None:
        return None
    missing = set(frame.loc[failed, "index"]) - set(constant["index"])
    if missing:
        raise ValueError(f"the constant predictor's table lacks frames {sorted(missing)[:5]}")
    columns = [c for c in constant.columns if c in frame.columns and c not in ("index", "flight")]
    given = constant.set_index("index").reindex(frame["index"].to_numpy())  # frame's row order
    out, mask = frame.copy(), failed.to_numpy()
    for column in columns:
        out[column] = np.where(mask, given[column].to_numpy(), frame[column].to_numpy())
    return out


@dataclass
class ReferenceResults:
    """Every evaluation of this report: ``summaries`` and per-frame ``frames`` keyed
    ``(name, split, satellite)``, as evaluated (a failed frame keeps the reference's own answer),
    ``records`` (the cached JSON records, same keys), ``errors`` (evaluations that raised: the
    rows read ``not run``, the table note says why) and, for rows kept from an earlier report,
    the cache under ``workdir`` read on demand.

    A table reads them through :meth:`table_frame` / :meth:`table_summary`, which give the failed
    frames the table's constant pose (:func:`with_fallback`): ``constants`` holds the constant
    predictor's per-frame tables keyed ``(train split, split)``, computed from ``data_root`` when
    missing."""

    summaries: dict[tuple[str, str, str], dict[str, float]] = field(default_factory=dict)
    frames: dict[tuple[str, str, str], pd.DataFrame] = field(default_factory=dict)
    records: dict[tuple[str, str, str], dict] = field(default_factory=dict)
    errors: dict[tuple[str, str, str], str] = field(default_factory=dict)  # first line
    workdir: Path | None = None
    data_root: Path | None = None
    constants: dict[tuple[str, str], pd.DataFrame] = field(default_factory=dict)
    _tables: dict[tuple[str, str, str, str], pd.DataFrame | None] = field(
        default_factory=dict, repr=False
    )

    def evaluation(self, name: str, split: str, satellite: str) -> pd.DataFrame | None:
        """The per-frame table of one evaluation as evaluated (None: not evaluated and not in
        the cache)."""
        key = (name, split, satellite)
        if key not in self.frames and self.record(*key) is not None:
            self.frames[key] = pd.read_csv(reference_paths(self.workdir, *key)[0])
        return self.frames.get(key)

    def constant(self, train_split: str, split: str) -> pd.DataFrame | None:
        """The constant predictor's per-frame table of ``train_split`` on ``split`` (None without
        it and without ``data_root``)."""
        key = (train_split, split)
        if key not in self.constants and self.data_root is not None:
            self.constants[key] = constant_baseline(self.data_root, train_split, split)[1]
        return self.constants.get(key)

    def table_frame(
        self, name: str, split: str, satellite: str, train_split: str
    ) -> pd.DataFrame | None:
        """The per-frame table of reference ``name`` on ``split`` in a table that trains on
        ``train_split``: failed frames given that table's constant pose (None: not evaluated)."""
        key = (name, split, satellite, train_split)
        if key not in self._tables:
            frame = self.evaluation(name, split, satellite)
            needs = frame is not None and bool(frame.get("reference_failed", pd.Series()).any())
            constant = self.constant(train_split, split) if needs else None
            self._tables[key] = None if frame is None else with_fallback(frame, constant)
        return self._tables[key]

    def table_summary(
        self, name: str, split: str, satellite: str, train_split: str
    ) -> dict[str, float] | None:
        """:func:`~benchmark.references.reference_summary` of :meth:`table_frame` and, for the
        swapped image, the swap effect against the true image's frames
        (``benchmark.evaluation.paired.swap_effect``, as a model's); None when not evaluated."""
        from benchmark.evaluation.paired import swap_effect
        from benchmark.references import reference_summary

        frame = self.table_frame(name, split, satellite, train_split)
        if frame is None:
            return None
        summary = reference_summary(frame)
        if satellite == "swap":
            true = self.table_frame(name, split, "true", train_split)
            if true is None:
                return None
            summary.update(swap_effect(true, frame))
        return summary

    def frame_of(
        self, label: str, split: str, satellite: str, train_split: str
    ) -> pd.DataFrame | None:
        """:meth:`table_frame` of the reference labelled ``label`` (None: not a reference, or
        not evaluated and not in the cache)."""
        from benchmark.references import get_reference_class, list_references

        names = [n for n in list_references() if get_reference_class(n).label == label]
        return self.table_frame(names[0], split, satellite, train_split) if names else None

    def record(self, name: str, split: str, satellite: str) -> dict | None:
        """The JSON record of one evaluation: this report's, else the one cached in ``workdir``
        (a table kept from an earlier report), else None."""
        key = (name, split, satellite)
        if key not in self.records and self.workdir is not None and key not in self.errors:
            csv, json_path = reference_paths(self.workdir, *key)
            if csv.is_file() and json_path.is_file():
                try:
                    self.records[key] = json.loads(json_path.read_text())
                except (OSError, ValueError):
                    return None
        return self.records.get(key)


def _wanted(specs: list[TableSpec], available: list[str]) -> list[tuple[str, str, tuple[str, ...]]]:
    """``(reference, split, satellite modes)`` of every spec that lists references, each pair
    once, in spec order: a table's test splits with the true and the swapped image; a
    sequence's test splits and its training split's validation split (``available`` names the
    dataset's splits), where the fusion density is calibrated, with the true image only."""
    out: dict[tuple[str, str], set[str]] = {}
    for spec in specs:
        if spec.kind == "table":
            splits, modes = list(spec.all_eval_splits()), set(SATELLITE_MODES)
        elif spec.kind == "sequence":
            val = val_split_for(spec.train_split, available)
            splits, modes = [*spec.all_eval_splits(), *([val] if val else [])], {"true"}
        else:
            continue
        for name in spec.references:
            for split in splits:
                out.setdefault((name, split), set()).update(modes)
    return [(n, s, tuple(m for m in SATELLITE_MODES if m in modes))
            for (n, s), modes in out.items()]  # fmt: skip


def dataset_splits(root: Path) -> list[str]:
    """The split names of the dataset at ``root`` (its manifest's), [] when it has none yet."""
    try:
        return list(json.loads((root / "manifest.json").read_text()).get("splits", {}))
    except (OSError, ValueError):
        return []


def _record(task: ReferenceTask, summary: dict, frames: int, manifest: str, code: str) -> dict:
    from benchmark.references import create_reference

    ref = create_reference(task.name)
    return {
        "reference": task.name,
        "label": ref.label,
        "given": list(ref.given),
        "options": {k: repr(v) for k, v in ref.options().items()},
        "split": task.split,
        "satellite": task.satellite,
        "stride": task.stride,
        "frames": frames,
        "dataset_manifest": manifest,
        "code_sha256": code,
        "summary": summary,
    }


# What a cached record must match to be reused (the rest describes it).
_IDENTITY = ("reference", "options", "split", "satellite", "stride", "dataset_manifest",
             "code_sha256")  # fmt: skip


def _cached(task: ReferenceTask, expected: dict) -> tuple[dict, dict, pd.DataFrame] | None:
    """``(record, summary, frame)`` of a complete cached evaluation made as ``expected`` says,
    else None (absent, incomplete, unreadable or made otherwise: evaluated again)."""
    if task.csv is None:
        return None
    csv, json_path = Path(task.csv), Path(task.csv).with_suffix(".json")
    if not (csv.is_file() and json_path.is_file()):
        return None
    try:
        record = json.loads(json_path.read_text())
        frame = pd.read_csv(csv)
    except (OSError, ValueError):
        return None
    if any(record.get(k) != expected[k] for k in _IDENTITY) or len(frame) != record.get("frames"):
        return None
    return record, record["summary"], frame


def _write_json(path: Path, record: dict) -> None:
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(record, indent=1, sort_keys=True, default=_json_default) + "\n")
    tmp.replace(path)  # written last: its presence means the evaluation is complete


def _json_default(value: object) -> object:
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def evaluate_references(
    specs: list[TableSpec],
    data_root: str | Path,
    workdir: str | Path | None,
    profile: str,
    quiet: bool = False,
    processes: int | None = None,
    chunk_frames: int = CHUNK_FRAMES,
    max_processes: int = MAX_PROCESSES,
) -> ReferenceResults:
    """Evaluate (or read back from ``workdir``'s cache) every reference of ``specs`` on every
    test split of the tables that list it, true and swapped satellite image, here: the
    :func:`plan_references` work run by the process pool (a reproduction runs the same work
    items with its executor instead: pool or Ray).

    ``profile``: the reproduction profile's name (its frame stride, :data:`PROFILE_STRIDE`);
    ``processes``: worker processes (default: up to ``max_processes`` (the reproduction's
    ``--workers``) and the CPU count when at least :data:`PARALLEL_MIN_FRAMES` frames are to be
    evaluated, else this process), given
    chunks of ``chunk_frames`` frames. Without ``workdir`` nothing is cached. A progress bar
    (stderr) unless ``quiet``. An evaluation that raises is reported (``errors``, stderr) and its
    rows are left out; the others go on."""
    work = plan_references(specs, data_root, workdir, profile, chunk_frames)
    try:
        items = work.items()
        if processes is None:
            cpus = os.cpu_count() or 1
            many = work.frames >= PARALLEL_MIN_FRAMES
            processes = max(1, min(max_processes, cpus, len(items))) if many else 1
        if work.tasks and not quiet:
            status(work.describe(processes))
        if items:
            execute_items(items, processes, work.collect, quiet, "references", "pair")
    finally:
        _dataset.cache_clear()  # the images of this process's evaluations are not kept
    return work.results()


def plan_references(
    specs: list[TableSpec],
    data_root: str | Path,
    workdir: str | Path | None,
    profile: str,
    chunk_frames: int = CHUNK_FRAMES,
) -> ReferenceWork:
    """The references' evaluations of ``specs`` (:func:`evaluate_references`): those whose cached
    record matches (same reference options, dataset, stride and code) read back, the others cut
    into chunks of ``chunk_frames`` frames, the work items an executor runs
    (:meth:`ReferenceWork.items`); :meth:`ReferenceWork.collect` records their outcomes."""
    from benchmark.tracking import manifest_sha256

    root = Path(data_root)
    wanted = _wanted(specs, dataset_splits(root))
    out = ReferenceResults(
        workdir=Path(workdir) if workdir is not None else None, data_root=Path(data_root)
    )
    if not wanted:
        return ReferenceWork({}, [], out, ("", ""))
    stride = PROFILE_STRIDE.get(profile, 1)
    manifest, code = manifest_sha256(root), _code_digest()
    tasks: dict[tuple[str, str, str], ReferenceTask] = {}
    for name, split, satellites in wanted:
        for satellite in satellites:
            csv = reference_paths(workdir, name, split, satellite)[0] if workdir else None
            task = ReferenceTask(name, str(root), split, satellite, stride,
                                 str(csv) if csv else None)  # fmt: skip
            tasks[task.key] = task
    todo: list[ReferenceTask] = []
    for key, task in tasks.items():
        hit = _cached(task, _record(task, {}, 0, manifest, code))
        true_redone = key[2] == "swap" and tasks[(*key[:2], "true")] in todo
        if hit is None or true_redone:  # a swap effect pairs it with today's true frames
            todo.append(task)
        else:
            out.records[key], out.summaries[key], out.frames[key] = hit
    try:
        chunks = [
            Chunk(task, tuple(rows[i : i + chunk_frames]))
            for task in todo
            for rows in [_task_rows(task)]
            for i in range(0, len(rows), chunk_frames)
        ]
    finally:
        _dataset.cache_clear()
    return ReferenceWork(tasks, chunks, out, (manifest, code))


class ReferenceWork:
    """The references' evaluations still to run, as chunks of frames (:meth:`items`: work items
    for an executor, ``run_chunk`` each), and their recording in this process (:meth:`collect`,
    as each outcome arrives, in any order): a true-image evaluation is written (its CSV, then its
    JSON record, ``stamp``: dataset manifest and code digest) once its chunks are in, a swap one
    once its true one is (or reported failed when that one failed). :meth:`results` is the
    whole, the cached evaluations included."""

    def __init__(
        self,
        tasks: dict[tuple[str, str, str], ReferenceTask],
        chunks: list[Chunk],
        out: ReferenceResults,
        stamp: tuple[str, str],
    ) -> None:
        self.tasks, self.chunks, self.out, self.stamp = tasks, chunks, out, stamp
        self.expected: dict[tuple[str, str, str], int] = {}
        for chunk in chunks:
            self.expected[chunk.task.key] = self.expected.get(chunk.task.key, 0) + 1
        self.parts: dict[tuple[str, str, str], list[tuple[int, tuple]]] = {}
        self.done: dict[tuple[str, str, str], tuple[dict, pd.DataFrame]] = {}

    @property
    def frames(self) -> int:
        """Frames still to evaluate."""
        return sum(len(c.rows) for c in self.chunks)

    def items(self) -> list[WorkItem]:
        """One work item per chunk (key: its evaluation and first row; size: its frames)."""
        return [
            WorkItem(f"{_what(c)} @{c.rows[0]}", _what(c), run_chunk, c, size=len(c.rows),
                     data_root=c.task.data_root)
            for c in self.chunks
        ]  # fmt: skip

    def describe(self, processes: int) -> str:
        """One status line: what is run, what is read back, and where."""
        n_run, n_all = len(self.expected), len(self.tasks)
        if not n_run:
            where = self.out.workdir / REFERENCE_DIR if self.out.workdir else "memory"
            return f"references: {n_all} evaluation(s) read back from {where}"
        stride = self.chunks[0].task.stride
        every = f", 1 frame in {stride} of each flight" if stride > 1 else ""
        return (
            f"references: {n_run} evaluation(s) to run ({n_all - n_run} read back), "
            f"{processes} process(es){every}"
        )

    def collect(self, item: WorkItem, outcome: ItemOutcome) -> None:
        """Record one chunk's outcome (an error costs its evaluation's rows, not the report)."""
        chunk: Chunk = item.arg
        key = chunk.task.key
        if key in self.out.errors:
            return
        if not outcome.ok:
            self.out.errors[key] = outcome.error
            self.parts.pop(key, None)
            status(f"reference {key[0]} {eval_key(*key[1:])} failed: {outcome.error}")
        else:
            self.parts.setdefault(key, []).append((chunk.rows[0], outcome.value))
            if len(self.parts[key]) == self.expected[key]:
                ordered = sorted(self.parts.pop(key), key=lambda p: p[0])
                self.done[key] = _assemble([r for _, r in ordered])
        self._flush()

    def _flush(self) -> None:
        for key in sorted(self.done, key=lambda k: k[2] != "true"):
            true_key = (*key[:2], "true")
            if key[2] == "swap" and true_key in self.out.errors:
                self.done.pop(key)
                self.out.errors[key] = (
                    f"its true-image evaluation failed ({self.out.errors[true_key]})"
                )
            elif key[2] == "true" or true_key in self.out.frames:
                self._finish(self.tasks[key])

    def _finish(self, task: ReferenceTask) -> None:
        from benchmark.evaluation.metrics import write_predictions_csv

        summary, frame = self.done.pop(task.key)
        if task.csv is not None:
            write_predictions_csv(frame, task.csv)
            frame = pd.read_csv(task.csv)  # as written: what a later report reads back
        record = _record(task, summary, len(frame), *self.stamp)
        if task.csv is not None:
            _write_json(Path(task.csv).with_suffix(".json"), record)
        out = self.out
        out.records[task.key], out.summaries[task.key], out.frames[task.key] = (
            record, summary, frame
        )  # fmt: skip

    def results(self) -> ReferenceResults:
        """Every evaluation recorded so far (a swap one whose true one never came is dropped)."""
        for key in [k for k in self.done if k[2] == "swap"]:
            self.done.pop(key)
        return self.out


def _what(chunk: Chunk) -> str:
    t = chunk.task
    return f"{t.name} {eval_key(t.split, t.satellite)}"


def reference_rows(specs: list[TableSpec], results: ReferenceResults) -> list[dict]:
    """``results.csv`` rows of the references of every table spec: one per (table, reference,
    split, satellite mode), the metrics of :meth:`ReferenceResults.table_summary` (failed frames
    given the table's constant pose), ``seed`` 0, ``role`` ``test``, ``satellite_input``
    ``image``, ``reference`` its registry name and ``train_split`` the table's for the split (the
    constant row's: the rows sit beside the table's models)."""
    from benchmark.references import get_reference_class

    rows = []
    for spec in specs:
        if spec.kind != "table":
            continue
        for name in spec.references:
            label = get_reference_class(name).label
            for split in spec.all_eval_splits():
                train = spec.train_split_for(split)
                for satellite in SATELLITE_MODES:
                    summary = results.table_summary(name, split, satellite, train)
                    if summary is None:
                        continue
                    # Sorted: results.csv has the same columns in the same order whatever order
                    # the summary's keys came in.
                    metrics = {k: summary[k] for k in sorted(summary) if k not in TIMING_KEYS}
                    rows.append(
                        {"table": spec.name, "label": label, "paper_model": "", "x": None,
                         "split": split, "satellite": satellite, "satellite_input": "image",
                         "train_split": train, "role": "test", "seed": 0,
                         "reference": name, **metrics}
                    )  # fmt: skip
    return rows


def reference_note(spec: TableSpec, results: ReferenceResults) -> str:
    """The paragraph under a table with reference rows: what each is given, the frames it was
    evaluated on, its failure rate and speed per split; ``""`` for a table without."""
    if spec.kind != "table" or not spec.references:
        return ""
    lines = [
        "",
        "Non-learned rows (issue 21), evaluated like the models (the models' test frames unless "
        "a stride is stated below, the same metrics, flight bootstrap and swap probe; no seed, "
        "so one evaluation) and part of no claim about the heads. A frame where a reference "
        "gives up (too few ground pixels, template cells or PnP inliers) gets the pose of this "
        "table's constant row (the mean pose of the split the table's models train on) and "
        "counts as failed. A reference that fails on every frame of a split reads "
        f"`{fails_text(1.0)}` in its cells there (its numbers would be the constant row's); "
        "one that fails on some frames shows its numbers, those frames counted with the "
        "constant row's errors, and says `fails on N % of frames` after its name (with the "
        "swapped image's rate when that differs). They are not evaluated on validation splits "
        "(nothing is chosen on them): their *val* cells read `–`.",
        "",
    ]
    for name in spec.references:
        parts = []
        for split in spec.all_eval_splits():
            record = results.record(name, split, "true")
            error = results.errors.get((name, split, "true")) or results.errors.get(
                (name, split, "swap")
            )
            if record is None:
                parts.append(f"`{split}` not run" + (f" ({error})" if error else ""))
                continue
            s = record["summary"]
            stride = int(record.get("stride", 1))
            frames = f"{record['frames']} frames" + (
                f" (1 in {stride} of each flight)" if stride > 1 else ""
            )
            rate = s.get("failure_rate", math.nan)
            cpu = s.get("cpu_ms_per_frame", math.nan)
            parts.append(
                f"`{split}` {frames}, failed {failure_percent(rate)}"
                + (f", {cpu:.0f} ms of CPU a frame" if math.isfinite(cpu) else "")
                + (f"; swapped image not run ({error})" if error else "")
            )
        lines.append(f"- `{name}` ({reads_text(name)}): " + "; ".join(parts) + ".")
    return "\n".join(lines) + "\n"


def failure_percent(rate: float) -> str:
    """A failure rate in percent, ``"37 %"``: never ``"0 %"`` for a rate above zero (``"<1 %"``)
    nor ``"100 %"`` below one (``">99 %"``); ``"?"`` for NaN."""
    if not math.isfinite(rate):
        return "?"
    percent = 100.0 * rate
    if 0 < percent < 1:
        return "<1 %"
    if 99 < percent < 100:
        return ">99 %"
    return f"{percent:.0f} %"


def fails_text(rate: float) -> str:
    """``"fails on 37 % of frames"``: how a table says a reference's failure rate."""
    return f"fails on {failure_percent(rate)} of frames"


def reads_text(name: str) -> str:
    """Which true values reference ``name`` reads (``Reference.given``) and what it estimates."""
    from benchmark.references import get_reference_class

    given = get_reference_class(name).given
    if given:
        return f"reads the true {', '.join(given)}; estimates the rest of the pose from the images"
    return "reads no true pose value; estimates the whole pose from the two images"


def describe_references(names: Iterable[str]) -> list[str]:
    """One sentence per reference: its row label (which says it is not learned), its registry
    name and which true values it reads, for the README and the tracker's descriptions."""
    from benchmark.references import get_reference_class

    return [f"{get_reference_class(n).label}, `{n}`: {reads_text(n)}" for n in names]
