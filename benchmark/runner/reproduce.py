"""``uavbench reproduce``: simulate, train and evaluate every variant, write the paper's tables.

Steps: (1) simulate the profile's dataset or reuse a matching one; (2) plan the deduplicated
training units of the selected tables and seeds; (3) for each unit, take its results from the
tracking store if a finished run exists, else train/resume and evaluate it (``--jobs`` worker
processes, one torch thread each) and log it; (4) write Markdown tables beside the paper's numbers,
figures, the raw CSV and a claim-by-claim summary under ``--out``.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import json
import multiprocessing
import os
import platform
import signal
import time
from pathlib import Path

from benchmark.errors import UsageError
from benchmark.progress import Progress, format_duration
from benchmark.runner.execute import UnitResult, UnitTask, run_unit, worker_init
from benchmark.runner.logbook import Logbook, write_config
from benchmark.runner.plan import Unit, plan_units
from benchmark.runner.profiles import PROFILES, ReproProfile, get_repro_profile
from benchmark.runner.specs import SpecError, load_specs

HELP = "reproduce the paper's tables and figures: simulate, train, evaluate, track, report"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--profile", choices=sorted(PROFILES), default="quick")
    parser.add_argument(
        "--only", default="", help="comma-separated tables/figures, e.g. table1,fig7 (default: all)"
    )
    parser.add_argument(
        "--seeds",
        type=int,
        default=None,
        help="training seeds per variant, on one dataset (default: the profile's, quick 3)",
    )
    parser.add_argument("--out", type=Path, default=None, help="reports dir (reports/<profile>)")
    parser.add_argument(
        "--workdir", type=Path, default=None, help="checkpoints etc. (runs/<profile>)"
    )
    parser.add_argument("--data", type=Path, default=None, help="dataset dir (data/<profile>)")
    parser.add_argument("--dataset-seed", type=int, default=0)
    parser.add_argument("--jobs", type=int, default=2, help="parallel training processes")
    parser.add_argument("--specs", type=Path, default=None, help="table specs dir")
    parser.add_argument(
        "--tracker", choices=("mlflow", "local", "null"), default="mlflow", help="tracking backend"
    )
    parser.add_argument("--tracking-uri", default=None, help="MLflow server (or env)")
    parser.add_argument(
        "--no-models",
        action="store_true",
        help="log no trained model to the tracker (about 15 MB each at the smoke/quick width; "
        "the checkpoints stay in --workdir)",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bars")


def prepare_dataset(profile: ReproProfile, out: Path, seed: int, workers: int, quiet: bool) -> None:
    """Simulate the dataset (resumes; a complete matching dataset costs nothing)."""
    from benchmark.data import get_profile
    from benchmark.data.simulate import single_thread_env
    from benchmark.data.writer import ConfigMismatchError, simulate_dataset

    single_thread_env()
    try:
        stats = simulate_dataset(
            out,
            get_profile(profile.dataset, profile.dataset_size),
            seed,
            workers=workers,
            progress=not quiet,
        )
    except ConfigMismatchError as err:
        raise UsageError(f"{out}: {err}") from err
    if stats["state"] != "complete":
        print(f"dataset {out}: {stats['state']} (rendering took {stats.get('render_s', 0):.0f} s)")


def execute_units(todo: list[tuple[Unit, UnitTask]], jobs: int, on_done, quiet: bool) -> None:
    """Run tasks inline (``jobs == 1``) or in a spawn pool; ``on_done(unit, result)`` in order of
    completion, in this process.

    Ctrl-C: pool workers ignore SIGINT (``execute.worker_init``); this process stops them
    (SIGTERM) and re-raises, so the user sees one message, not a traceback per worker."""
    with Progress(len(todo), "reproduce", unit="run", enabled=not quiet) as bar:
        if jobs == 1 or len(todo) <= 1:
            for unit, task in todo:
                bar.update(0, postfix=f"running {unit.title}")
                on_done(unit, run_unit(task))
                bar.update(1, postfix=f"done {unit.title}")
            return
        ctx = multiprocessing.get_context("spawn")
        pool = cf.ProcessPoolExecutor(jobs, mp_context=ctx, initializer=worker_init)
        try:
            # Workers are spawned by submit; started with SIGINT ignored (kept across exec, and
            # then Python installs no KeyboardInterrupt handler) they cannot print a traceback
            # even while still importing, before worker_init runs.
            previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
            try:
                futures = {pool.submit(run_unit, task): unit for unit, task in todo}
            finally:
                signal.signal(signal.SIGINT, previous)
            for future in cf.as_completed(futures):
                unit = futures[future]
                on_done(unit, future.result())
                bar.update(1, postfix=f"done {unit.title}")
        except BaseException:
            _stop_pool(pool)
            raise
        pool.shutdown(wait=True)


def _stop_pool(pool: cf.ProcessPoolExecutor) -> None:
    """Cancel what has not started and terminate the workers (they may be mid-training)."""
    processes = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        if process.is_alive():
            process.terminate()
    for process in processes:
        process.join(timeout=10)


def _log_invocation(workdir: Path, record: dict, keys: set[str]) -> list[dict]:
    """Append this invocation to ``<workdir>/invocations.jsonl``; return those that trained units
    of this plan (the provenance of the results), this one last."""
    path = workdir / "invocations.jsonl"
    history = [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []
    record = {**record, "unit_keys": sorted(keys)}
    with path.open("a") as fh:
        fh.write(json.dumps(record) + "\n")
    relevant = [r for r in history if r.get("trained") and keys & set(r.get("unit_keys", []))]
    return [*relevant, record]


def run(args: argparse.Namespace) -> int:
    from benchmark.runner.outputs import write_reports
    from benchmark.tracking import RunStatus, create_tracker, git_commit, manifest_sha256

    started = time.time()
    profile = get_repro_profile(args.profile)
    if args.seeds is not None and args.seeds < 1:
        raise UsageError(f"--seeds must be >= 1, got {args.seeds}")
    if args.jobs < 1:
        raise UsageError(f"--jobs must be >= 1, got {args.jobs}")
    only = [name.strip() for name in args.only.split(",") if name.strip()]
    try:
        specs = load_specs(args.specs, only or None)
    except SpecError as err:
        raise UsageError(str(err)) from err
    seeds = list(range(args.seeds if args.seeds is not None else profile.seeds))
    data_root = args.data or Path("data") / f"{profile.dataset}-s{args.dataset_seed}"
    workdir = args.workdir or Path("runs") / profile.name
    out = args.out or Path("reports") / profile.name

    prepare_dataset(profile, data_root, args.dataset_seed, max(1, args.jobs), args.quiet)
    from benchmark.data import list_splits

    dataset_hash = manifest_sha256(data_root)
    try:
        units = plan_units(specs, profile, seeds, data_root, list_splits(data_root), dataset_hash)
    except ValueError as err:
        raise UsageError(str(err)) from err

    workdir.mkdir(parents=True, exist_ok=True)
    tracker = create_tracker(args.tracker, args.tracking_uri, workdir=Path.cwd())
    provenance = {"git_commit": git_commit() or "unknown", "dataset_manifest": dataset_hash}
    logbook = Logbook(
        tracker,
        profile.name,
        {k: str(v) for k, v in provenance.items()},
        specs=specs,
        data_root=data_root,
    )
    results: dict[str, UnitResult] = {}
    todo: list[tuple[Unit, UnitTask]] = []
    for unit in units:
        stored = [s for job in unit.jobs if (s := logbook.finished(job, unit)) is not None]
        if len(stored) == len(unit.jobs):
            merged: dict[str, dict[str, float]] = {}
            for metrics, _ in stored:
                merged.update(metrics)
            seconds = max(seconds for _, seconds in stored)
            results[unit.key] = UnitResult(unit.key, True, metrics=merged, seconds=seconds)
            continue
        unit_dir = workdir / "units" / unit.key
        live = None
        if args.tracker != "null":
            live = logbook.unit_tracking(unit, log_model=not args.no_models)
        todo.append((unit, UnitTask(unit.key, unit.cfg, unit.eval_splits, unit_dir, tracking=live)))
    print(
        f"reproduce {profile.name}: {len(specs)} tables/figures, {len(units)} training runs "
        f"({len(units) - len(todo)} already in the tracking store), {len(seeds)} seed(s), "
        f"tracking: {tracker.uri or args.tracker}"
    )

    failures: list[str] = []

    def on_done(unit: Unit, result: UnitResult) -> None:
        results[unit.key] = result
        unit_dir = workdir / "units" / unit.key
        if unit_dir.is_dir():
            write_config(unit, unit_dir / "config.json")
        for job in unit.jobs:
            logbook.log_job(job, unit, result)
        if not result.ok:
            failures.append(f"{unit.title}: {result.error}")
            print(f"FAILED {unit.title}: {result.error}")

    status = RunStatus.FINISHED
    try:
        execute_units(todo, args.jobs, on_done, args.quiet)
        record = {
            "started": time.strftime("%Y-%m-%d %H:%M", time.gmtime(started)),
            "wall_s": time.time() - started,
            "trained": len(todo),
            "units": len(units),
            "machine": f"{platform.node()}, {os.cpu_count()} cores",
            "git_commit": provenance["git_commit"],
        }
        invocations = _log_invocation(workdir, record, {u.key for u in units})
        written = write_reports(
            specs, units, results, profile, data_root, out, logbook, invocations, workdir=workdir
        )
    except KeyboardInterrupt:
        status = RunStatus.KILLED
        logbook.kill_unfinished_units(unit.key for unit, _ in todo)
        print("interrupted: finished runs are kept; run the same command again to resume")
        raise
    except BaseException:
        status = RunStatus.FAILED
        raise
    finally:
        logbook.close(
            status if not failures or status is not RunStatus.FINISHED else RunStatus.FAILED
        )
        tracker.close()
    wall = time.time() - started
    print(
        f"wrote {len(written)} report files to {out} in {format_duration(wall)} "
        f"on {platform.node()}"
    )
    if failures:
        print(f"{len(failures)} training run(s) failed:\n  " + "\n  ".join(failures))
    print(browse_hint(args.tracker, tracker))
    return 1 if failures else 0


def browse_hint(kind: str, tracker) -> str:
    """The last line of a reproduction: how to look at what it logged."""
    if getattr(tracker, "using_fallback", False):
        return f"MLflow was unreachable: the runs are files under {tracker.fallback_dir}"
    if kind == "mlflow" and tracker.uri.startswith(("http://", "https://")):
        return f"browse the runs: {tracker.uri} (or uavbench ui --tracking-uri {tracker.uri})"
    if kind == "mlflow":
        return f"browse the runs: uavbench ui --tracking-uri {tracker.uri}"
    if kind == "local":
        return f"the runs are files under {tracker.uri} (run.json, metrics.csv per run)"
    return "nothing was tracked (--tracker null)"
