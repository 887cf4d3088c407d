"""The non-learned rows of the ``sequence`` table fused along the flights (issue 39): the constant
predictor and every reference of a ``kind: sequence`` spec, on each of its splits, fused exactly
as a regression head is (``benchmark.evaluation.sequence_eval.fuse_estimates``: the calibrated
density around each frame's estimate, fitted on the same estimator's frames of the training
split's validation split). A reference's failed frames carry the constant predictor's pose, as in
every table. One "seed" each (they are deterministic); a row whose validation or split frames
were not evaluated is left out.

Work of the reproduction, run before the report is written: one job per (spec, split, row), in a
spawn pool of ``workers`` processes (the jobs are independent, so the tables are the same in any
order and with any number of workers). The report reads the tables only
(``benchmark.runner.report.sequence``).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import pandas as pd

from benchmark.runner.execute.reference_rows import ReferenceResults, dataset_splits
from benchmark.runner.execute.work_pool import map_work
from benchmark.runner.plan.specs import TableSpec
from benchmark.runner.plan.units import val_split_for

CONSTANT = "constant"  # the row name of the constant predictor (its label is the report's)


@dataclass(frozen=True)
class NonLearnedFusion:
    """One non-learned row fused on one split: ``row`` (:data:`CONSTANT` or a reference's
    registry name), ``label`` its reference label (None for the constant predictor: the report
    names it), ``table`` the fusion's long table (``fuse_split``'s columns plus ``odometry``),
    ``position_given`` whether the reference was given the true position (no horizontal error to
    read)."""

    row: str
    label: str | None
    split: str
    table: pd.DataFrame
    position_given: bool


@dataclass(frozen=True)
class _Job:
    spec: str
    row: str
    label: str | None
    split: str
    val: str
    position_given: bool
    frame: pd.DataFrame
    val_frame: pd.DataFrame
    data_root: str


@lru_cache(maxsize=8)
def _split_data(root: str, split: str):  # -> PairDataset, one per split and process
    from benchmark.data import PairDataset

    return PairDataset(root, split)


def _fuse(job: _Job) -> NonLearnedFusion:
    from benchmark.data import odometry_noise
    from benchmark.evaluation.sequence_eval import STRESS_SCALE, fuse_estimates

    data = _split_data(job.data_root, job.split)
    profile = data.manifest["profile"]
    area = float(np.prod(np.asarray(profile["sat_footprint_m"], np.float64)))
    _, table = fuse_estimates(
        job.frame, job.val_frame, data.poses, data.sat_table, odometry_noise(profile),
        split=job.split, val_split=job.val, seed=int(data.manifest["seed"]), area_m2=area,
        stress_scale=STRESS_SCALE if job.split.startswith("long/") else None,
    )  # fmt: skip
    return NonLearnedFusion(job.row, job.label, job.split, table, job.position_given)


def _jobs(specs: list[TableSpec], references: ReferenceResults, data_root: Path) -> list[_Job]:
    from benchmark.references import get_reference_class

    out = []
    for spec in specs:
        if spec.kind != "sequence":
            continue
        val = val_split_for(spec.train_split, dataset_splits(data_root))
        if val is None:
            continue
        rows: list[tuple[str, str | None, bool]] = [(CONSTANT, None, False)]
        for name in spec.references:
            cls = get_reference_class(name)
            given = any("E" in v.columns for v in getattr(cls, "given_values", ()))
            rows.append((name, cls.label, given))

        def frames_of(row: str, split: str, spec: TableSpec = spec) -> pd.DataFrame | None:
            if row == CONSTANT:
                return references.constant(spec.train_split, split)
            return references.table_frame(row, split, "true", spec.train_split)

        for split in spec.all_eval_splits():
            for row, label, given in rows:
                frame, val_frame = frames_of(row, split), frames_of(row, val)
                if frame is not None and val_frame is not None:
                    out.append(_Job(spec.name, row, label, split, val, given, frame, val_frame,
                                    str(data_root)))  # fmt: skip
    return out


def fuse_non_learned(
    specs: list[TableSpec],
    references: ReferenceResults,
    data_root: Path,
    workers: int = 1,
    quiet: bool = False,
) -> dict[str, list[NonLearnedFusion]]:
    """``{spec name: [fused rows]}`` of every ``kind: sequence`` spec of ``specs``, in the
    order (split, row) of the spec, the constant predictor first. ``references`` holds the
    references' frames and the constant predictor's (``ReferenceResults.constants``)."""
    jobs = _jobs(specs, references, data_root)
    results = map_work(
        _fuse, jobs, workers, label="fuse non-learned", name=lambda j: f"{j.row} {j.split}",
        quiet=quiet,
    )  # fmt: skip
    out: dict[str, list[NonLearnedFusion]] = {}
    for job, result in zip(jobs, results, strict=True):
        out.setdefault(job.spec, []).append(result)
    return out
