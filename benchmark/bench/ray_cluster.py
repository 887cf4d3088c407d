"""``uavbench bench ray``: the smoke reproduction through the process pool and through a local Ray,
side by side, in one run.

Measures (and returns, for the command to print) the wall time of the reproduction with the process
pool and with Ray as executor (each in a fresh interpreter with a fresh workdir and tracking store,
as a user runs it: imports, Ray's start-up and shutdown included; the dataset is rendered once
beforehand and not timed), their ratio (target: Ray within 1.3x the pool) and whether
``results.csv`` holds the same numbers.
``--repeats N`` alternates the two N times and reports medians, so a load change hits both alike.
"""

from __future__ import annotations

import os
import statistics
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from benchmark.bench.fresh_process import FreshProcessError, run_fresh
from benchmark.errors import InputError

if TYPE_CHECKING:
    import pandas as pd

TARGET_RATIO = 1.3  # issue 11: local Ray within 1.3x the process pool's wall time
TIME_SUFFIXES = ("seconds", "_s", "_ms")  # results.csv columns that are times, not results
NOT_NUMBERS = {"run_id", "training_run_id", "model_uri", "started", "ended"}
ROW_KEYS = ["table", "label", "split", "satellite", "seed"]


@dataclass(frozen=True)
class BenchRayConfig:
    """What ``uavbench bench ray`` times: the reproduction's profile and tables, the units at once
    (``--workers``, processes, for both executors), the alternating repeats, the tracker, and
    where everything is kept (None: a temporary directory)."""

    profile: str = "smoke"
    only: str = "table3"
    workers: int = 2
    repeats: int = 1
    tracker: str = "mlflow"
    dir: Path | None = None


def numbers(results_csv: Path) -> pd.DataFrame:
    """``results.csv`` without its time columns, rows in a fixed order: two reproductions of the
    same plan give equal frames exactly when they computed the same numbers."""
    import pandas as pd

    frame = pd.read_csv(results_csv)
    keep = [c for c in frame.columns if not c.endswith(TIME_SUFFIXES) and c not in NOT_NUMBERS]
    return frame[keep].sort_values(ROW_KEYS).reset_index(drop=True)


def reproduce_once(config: BenchRayConfig, executor: str, data: Path, where: Path) -> float:
    """Wall seconds of one reproduction in a fresh interpreter (``reproduce(ReproduceConfig)``
    as ``uavbench reproduce`` would call it; its output in ``where/reproduce.log``); raises
    RuntimeError if it fails or a unit failed to train."""
    from benchmark.runner.execute.pool import ExecutorConfig
    from benchmark.runner.reproduction import ReproduceConfig, reproduce

    where.mkdir(parents=True)
    run = ReproduceConfig(
        profile=config.profile, only=(config.only,), data=data, workdir=where / "runs",
        out=where / "reports", tracker=config.tracker, log_models=False, quiet=True,
        executor=ExecutorConfig(kind=executor, workers=config.workers),
    )  # fmt: skip
    # one thread per process, as the runner's units
    threads = {var: "1" for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")}
    log = where / "reproduce.log"
    start = time.perf_counter()
    try:
        result = run_fresh(reproduce, run, env=threads, cwd=where, log=log)
    except FreshProcessError as err:
        raise RuntimeError(f"reproduce with the {executor} executor failed: {err}") from err
    wall = time.perf_counter() - start
    if not result.ok:
        failed = "\n".join(result.failures)
        raise RuntimeError(f"reproduce with the {executor} executor: units failed:\n{failed}")
    return wall


@dataclass(frozen=True)
class BenchRayResult:
    """What :func:`bench_ray` measured: the wall seconds of every run of each executor
    (``pool``, ``ray``, in run order) and whether every ray run's ``results.csv`` holds the
    numbers of the pool run of the same repeat (``same``)."""

    pool: tuple[float, ...]
    ray: tuple[float, ...]
    same: bool

    @property
    def pool_s(self) -> float:
        """The median wall seconds of the pool's runs."""
        return statistics.median(self.pool)

    @property
    def ray_s(self) -> float:
        """The median wall seconds of Ray's runs."""
        return statistics.median(self.ray)

    @property
    def ratio(self) -> float:
        """Ray's median wall time over the pool's (target: <= :data:`TARGET_RATIO`)."""
        return self.ray_s / self.pool_s

    def lines(self) -> list[str]:
        """The table: both medians, their ratio against the target, the numbers' verdict."""
        verdict = "within" if self.ratio <= TARGET_RATIO else "OVER"
        return [
            f"process pool   {self.pool_s:7.1f} s (median wall of reproduce)",
            f"local Ray      {self.ray_s:7.1f} s",
            f"Ray / pool     {self.ratio:7.2f}x ({verdict} the {TARGET_RATIO}x target)",
            f"results.csv    {'identical numbers' if self.same else 'NUMBERS DIFFER'}",
        ]


def bench_ray(config: BenchRayConfig) -> BenchRayResult:
    """Time the pool and the local Ray side by side; returns the wall times and whether both
    computed the same numbers. What it does meanwhile (the setup, each run's wall time) goes to
    :func:`benchmark.progress.status`. InputError: workers or repeats below 1, no ray."""
    from benchmark.progress import status
    from benchmark.runner.execute.audit import CUE_EXTRA_SEEDS, cue_dataset_roots
    from benchmark.runner.execute.ray_executor import import_ray
    from benchmark.runner.plan.repro_profiles import get_repro_profile
    from benchmark.runner.reproduction import prepare_dataset

    if config.workers < 1 or config.repeats < 1:
        raise InputError(
            f"BenchRayConfig.workers and .repeats must be >= 1, got {config.workers} and "
            f"{config.repeats}"
        )
    import_ray()  # InputError (exit 2) with the install line before rendering anything
    with tempfile.TemporaryDirectory(prefix="bench-ray-") as tmp:
        root = config.dir if config.dir is not None else Path(tmp)
        data = root / "data"
        profile = get_repro_profile(config.profile)
        status(f"bench ray: profile {config.profile}, tables {config.only}, {config.workers} "
               f"workers, {config.repeats} repeat(s), {os.cpu_count()} cores; rendering the "
               "datasets (untimed)")  # fmt: skip
        prepare_dataset(profile, data, 0, config.workers, quiet=True)
        # The heading-cue audit's extra datasets too: else the first timed run renders them.
        cue_dataset_roots(data, CUE_EXTRA_SEEDS, quiet=True)
        walls: dict[str, list[float]] = {"pool": [], "ray": []}
        for repeat in range(config.repeats):
            for executor in ("pool", "ray"):
                where = root / f"{executor}-{repeat}"
                walls[executor].append(reproduce_once(config, executor, data, where))
                status(f"  {executor:4s} run {repeat + 1}: {walls[executor][-1]:7.1f} s")
        same = all(
            numbers(root / f"ray-{r}" / "reports" / "results.csv").equals(
                numbers(root / f"pool-{r}" / "reports" / "results.csv")
            )
            for r in range(config.repeats)
        )
    return BenchRayResult(tuple(walls["pool"]), tuple(walls["ray"]), same)
