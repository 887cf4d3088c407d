"""``uavbench bench ray``: the smoke reproduction through the process pool and through a local Ray,
side by side, in one run.

Prints the wall time of ``uavbench reproduce --executor pool`` and ``--executor ray`` (each a fresh
process with a fresh workdir and tracking store, as a user runs it: imports, Ray's start-up and
shutdown included; the dataset is rendered once beforehand and not timed), their ratio (target:
Ray within 1.3x the pool) and whether ``results.csv`` holds the same numbers. ``--repeats N``
alternates the two N times and reports medians, so a load change hits both alike.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TARGET_RATIO = 1.3  # issue 11: local Ray within 1.3x the process pool's wall time
TIME_SUFFIXES = ("seconds", "_s", "_ms")  # results.csv columns that are times, not results
NOT_NUMBERS = {"run_id", "training_run_id", "model_uri", "started", "ended"}
ROW_KEYS = ["table", "label", "split", "satellite", "seed"]


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="uavbench bench ray", description=__doc__)
    p.add_argument("--profile", default="smoke")
    p.add_argument("--only", default="table3", help="tables to reproduce (default table3)")
    p.add_argument("--jobs", type=int, default=2, help="units at once, for both executors")
    p.add_argument("--repeats", type=int, default=1, help="alternating runs of each executor")
    p.add_argument("--tracker", choices=("mlflow", "local", "null"), default="mlflow")
    p.add_argument(
        "--dir", type=Path, default=None, help="keep everything here (default: a temporary dir)"
    )
    args = p.parse_args(argv)
    if args.jobs < 1 or args.repeats < 1:
        p.error("--jobs and --repeats must be >= 1")
    return args


def numbers(results_csv: Path):
    """``results.csv`` without its time columns, rows in a fixed order: two reproductions of the
    same plan give equal frames exactly when they computed the same numbers."""
    import pandas as pd

    frame = pd.read_csv(results_csv)
    keep = [c for c in frame.columns if not c.endswith(TIME_SUFFIXES) and c not in NOT_NUMBERS]
    return frame[keep].sort_values(ROW_KEYS).reset_index(drop=True)


def reproduce_once(args: argparse.Namespace, executor: str, data: Path, where: Path) -> float:
    """Wall seconds of one ``uavbench reproduce`` in a fresh process; raises if it fails."""
    where.mkdir(parents=True)
    argv = [
        sys.executable, "-m", "benchmark.cli", "reproduce", "--profile", args.profile,
        "--only", args.only, "--data", str(data), "--workdir", str(where / "runs"),
        "--out", str(where / "reports"), "--tracker", args.tracker, "--no-models", "--quiet",
        "--jobs", str(args.jobs), "--executor", executor,
    ]  # fmt: skip
    checkout = str(Path(__file__).resolve().parents[2])  # this checkout, not an installed copy
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([checkout, os.environ.get("PYTHONPATH", "")]),
    }
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
        env[var] = "1"
    start = time.perf_counter()
    done = subprocess.run(argv, cwd=where, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - start
    if done.returncode != 0:
        tail = "\n".join((done.stdout + done.stderr).splitlines()[-15:])
        raise RuntimeError(f"reproduce --executor {executor} exited {done.returncode}:\n{tail}")
    return wall


def main(argv: list[str]) -> int:
    from benchmark.runner.claims.data_audit import CUE_EXTRA_SEEDS, cue_dataset_roots
    from benchmark.runner.execute.ray_executor import import_ray
    from benchmark.runner.plan.repro_profiles import get_repro_profile
    from benchmark.runner.reproduce import prepare_dataset

    args = parse_args(argv)
    import_ray()  # exit 2 with the install line before rendering anything
    with tempfile.TemporaryDirectory(prefix="bench-ray-") as tmp:
        root = args.dir if args.dir is not None else Path(tmp)
        data = root / "data"
        profile = get_repro_profile(args.profile)
        print(f"bench ray: {args.profile} --only {args.only}, --jobs {args.jobs}, "
              f"{args.repeats} repeat(s), {os.cpu_count()} cores; rendering the datasets (untimed)",
              flush=True)  # fmt: skip
        prepare_dataset(profile, data, 0, args.jobs, quiet=True)
        # The heading-cue audit's extra datasets too: else the first timed run renders them.
        cue_dataset_roots(data, CUE_EXTRA_SEEDS, quiet=True)
        walls: dict[str, list[float]] = {"pool": [], "ray": []}
        for repeat in range(args.repeats):
            for executor in ("pool", "ray"):
                where = root / f"{executor}-{repeat}"
                walls[executor].append(reproduce_once(args, executor, data, where))
                print(f"  {executor:4s} run {repeat + 1}: {walls[executor][-1]:7.1f} s", flush=True)
        pool, ray = (statistics.median(walls[e]) for e in ("pool", "ray"))
        same = all(
            numbers(root / f"ray-{r}" / "reports" / "results.csv").equals(
                numbers(root / f"pool-{r}" / "reports" / "results.csv")
            )
            for r in range(args.repeats)
        )
    ratio = ray / pool
    verdict = "within" if ratio <= TARGET_RATIO else "OVER"
    print(f"process pool   {pool:7.1f} s (median wall of reproduce)")
    print(f"local Ray      {ray:7.1f} s")
    print(f"Ray / pool     {ratio:7.2f}x ({verdict} the {TARGET_RATIO}x target)")
    print(f"results.csv    {'identical numbers' if same else 'NUMBERS DIFFER'}")
    return 0 if same else 1
