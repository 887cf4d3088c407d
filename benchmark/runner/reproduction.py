"""One reproduction: simulate, train and evaluate every table row, write the paper's tables.

``reproduce(ReproduceConfig(...))`` is what ``uavbench reproduce`` runs (its flags are parsed in
``benchmark.commands.reproduce``) and what a Python caller runs. Steps: (1) simulate the
profile's dataset or reuse a matching one; (2) plan the deduplicated training units of the
selected tables and seeds; (3) for each unit, take its results from the tracking store if a
finished run exists, else train/resume and evaluate it (``executor.workers`` worker processes,
one torch thread each) and log it; (4) write Markdown tables beside the paper's numbers, figures,
the raw CSV and a claim-by-claim summary under ``out``.
"""

from __future__ import annotations

import dataclasses
import os
import platform
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from benchmark.errors import InputError
from benchmark.locks import LockBusyError, work_lock
from benchmark.progress import Progress, format_duration, status
from benchmark.runner.execute.audit import check_cue_datasets
from benchmark.runner.execute.pool import (
    ExecutorConfig,
    check_executor,
    run_executor,
    run_work_items,
)
from benchmark.runner.execute.ray_executor import is_local_address
from benchmark.runner.execute.worker import (
    UnitResult,
    UnitTask,
    fusion_done,
    joint_sequence_paths,
    sequence_paths,
    volume_sequence_paths,
)
from benchmark.runner.plan.invocations import (
    LOCK,
    owner_tags,
    relevant_invocations,
    start_invocation,
)
from benchmark.runner.plan.partial import DEFAULT_STALE, STALE_MODES, MergePlan, plan_merge
from benchmark.runner.plan.repro_profiles import ReproProfile, get_repro_profile
from benchmark.runner.plan.specs import SpecError, load_specs
from benchmark.runner.plan.units import Unit, plan_units
from benchmark.runner.report.logbook import Logbook, write_config

if TYPE_CHECKING:
    from benchmark.runner.claims.report_numbers import ReportInputs, ReportNumbers
    from benchmark.runner.execute.reference_rows import ReferenceResults
    from benchmark.tracking import Tracker


@dataclass(frozen=True)
class ReproduceConfig:
    """One reproduction (``uavbench reproduce``'s flags, typed; the defaults are the command's).

    ``only``: table/figure names or groups (``paper``, ``extras``; empty: all). ``seeds`` None:
    the profile's. ``out``/``workdir``/``data`` None: ``reports/<profile>``, ``runs/<profile>``,
    ``data/<dataset>-s<dataset_seed>``. ``wait=False`` refuses (exit 2) instead of waiting when
    another reproduction holds ``workdir``. ``executor.workers`` (``--workers``) also renders the
    dataset."""

    profile: str = "quick"
    only: tuple[str, ...] = ()
    seeds: int | None = None
    stale: str = DEFAULT_STALE  # one of STALE_MODES
    out: Path | None = None
    workdir: Path | None = None
    data: Path | None = None
    dataset_seed: int = 0
    specs: Path | None = None  # None: reports/configs of this checkout
    tracker: str = "mlflow"  # mlflow, local or null
    tracking_uri: str | None = None  # None: MLFLOW_TRACKING_URI, else ./mlflow.db
    log_models: bool = True
    device: str = "auto"
    precision: str = "auto"
    quiet: bool = False
    wait: bool = True
    executor: ExecutorConfig = field(default_factory=ExecutorConfig)


def prepare_dataset(profile: ReproProfile, out: Path, seed: int, workers: int, quiet: bool) -> None:
    """Simulate the dataset (resumes; a complete matching dataset costs nothing)."""
    from benchmark.data import get_data_profile
    from benchmark.data.simulate import single_thread_env
    from benchmark.data.writer import ConfigMismatchError, simulate_dataset

    single_thread_env()
    try:
        stats = simulate_dataset(
            out,
            get_data_profile(profile.dataset, profile.dataset_size),
            seed,
            workers=workers,
            progress=not quiet,
        )
    except ConfigMismatchError as err:
        if not err.differences:  # not a dataset at all (a file, a foreign directory)
            raise InputError(f"{out}: {err}") from None
        raise InputError(
            f"{out} holds a dataset of another simulator or profile ({err.summary}); choose "
            f"another data directory, or move it away (or delete it) and it is rendered there"
        ) from None
    if stats["state"] != "complete":
        status(f"dataset {out}: {stats['state']} (rendering took {stats.get('render_s', 0):.0f} s)")


def _data_error(root: Path, profile: ReproProfile, seed: int, err: Exception) -> InputError:
    """One line for a dataset that cannot be used or repaired: what is wrong and the fix."""
    from benchmark.data.format import os_error_message

    if isinstance(err, OSError):
        what = os_error_message(err) or f"{err.strerror or err}: {err.filename or root}"
    else:
        what = str(err)
    return InputError(
        f"dataset {root} is damaged and was not repaired ({what}); run `uavbench verify {root}` "
        f"to list every bad file and its fix (bad bytes: render profile {profile.dataset!r}, "
        f"seed {seed}, into {root} again)"
    )


def _check_data(root: Path, profile: ReproProfile, config: ReproduceConfig) -> str:
    """Simulate or confirm the dataset before any training: every file's sha256 is checked
    (cached by file identity, ``benchmark.data.integrity``) and bad files are rendered again. A
    dataset that stays damaged (config unreadable, a repair that cannot write) is one line and
    exit 2, never one failure per unit. Returns the manifest's sha256."""
    from benchmark.data.format import DatasetError, os_error_message
    from benchmark.tracking import manifest_sha256

    try:
        prepare_dataset(
            profile, root, config.dataset_seed, max(1, config.executor.workers), config.quiet
        )
        return manifest_sha256(root)
    except DatasetError as err:
        raise _data_error(root, profile, config.dataset_seed, err) from None
    except OSError as err:
        if os_error_message(err) is None:
            raise  # not a disk or permission problem: a bug, let it surface
        raise _data_error(root, profile, config.dataset_seed, err) from None


def _with_device(
    profile: ReproProfile, device: str, precision: str, executor: ExecutorConfig
) -> ReproProfile:
    """``profile`` training on ``device`` in ``precision``, checked before any work: a bad name,
    a device this machine lacks or bf16 on a CPU without native bf16 is one line (exit 2).

    The units' keys are computed here, on the driver, and name their precision; ``"auto"`` is
    resolved into the units' configs by the plan (``plan.units.resolved_precision``). With a
    remote Ray cluster the driver is not where the units compute (a CPU driver, GPU workers),
    so ``"auto"`` is refused there and the device is only checked by name: each worker resolves
    the device itself, checks that it runs the precision, and tags the runs with both."""
    from benchmark.models.device import (
        check_device_name,
        check_precision_name,
        resolve_placement,
    )

    try:
        check_device_name(device)
        check_precision_name(precision)
        if executor.kind == "ray" and not is_local_address(executor.ray_address):
            if precision == "auto":
                raise ValueError(
                    f"precision 'auto' with the remote Ray cluster {executor.ray_address}: the "
                    "units' keys are computed on this machine, which is not where they train, "
                    "so 'auto' could name one precision here and train in another there; "
                    "choose the precision explicitly (fp32, bf16 or fp16)"
                )
        else:
            resolve_placement(device, precision)  # each worker resolves its own placement once
    except ValueError as err:
        raise InputError(f"reproduce: {err}") from None
    return dataclasses.replace(profile, device=device, precision=precision)


@dataclass(frozen=True)
class ReproduceResult:
    """What one reproduction did: the report files ``written`` under ``out`` in ``wall_s``
    seconds on ``host``, the ``failures`` (one line per unit that failed to train), and where the
    runs went (``tracking``: the tracker's summary; ``browse``: how to look at them, or "")."""

    out: Path
    written: tuple[Path, ...]
    wall_s: float
    host: str
    failures: tuple[str, ...]
    tracking: str
    browse: str

    @property
    def ok(self) -> bool:
        """Every unit trained."""
        return not self.failures

    def lines(self) -> list[str]:
        """The closing lines ``uavbench reproduce`` prints."""
        lines = [
            f"wrote {len(self.written)} report files to {self.out} in "
            f"{format_duration(self.wall_s)} on {self.host}"
        ]
        if self.failures:
            lines.append(
                f"{len(self.failures)} training run(s) failed:\n  " + "\n  ".join(self.failures)
            )
        lines.append(self.tracking)
        return lines + ([self.browse] if self.browse else [])


def reproduce(config: ReproduceConfig) -> ReproduceResult:
    """Run one reproduction; what it wrote and which units failed (:class:`ReproduceResult`;
    ``ok`` when every unit trained). Bad input (a value out of range, an unknown table, a device
    this machine lacks, a damaged dataset, a busy ``workdir`` with ``wait=False``) raises
    ``InputError`` before any training. What it is doing goes to ``benchmark.progress.status``."""
    try:
        repro = get_repro_profile(config.profile)
    except ValueError as err:
        raise InputError(str(err)) from None
    profile = _with_device(repro, config.device, config.precision, config.executor)
    if config.seeds is not None and config.seeds < 1:
        raise InputError(f"seeds must be >= 1, got {config.seeds}")
    if config.executor.workers < 1:
        raise InputError(f"executor.workers must be >= 1, got {config.executor.workers}")
    if config.stale not in STALE_MODES:
        raise InputError(f"stale must be one of {STALE_MODES}, got {config.stale!r}")
    check_executor(config.executor, planned_tracking_uri(config.tracker, config.tracking_uri))
    try:
        specs = load_specs(config.specs, list(config.only) or None)
    except SpecError as err:
        raise InputError(str(err)) from err
    workdir = config.workdir or Path("runs") / profile.name
    # One writer per work directory for the whole invocation: a second one waits (or, with
    # wait=False, raises naming the holder); a dead holder's lock is taken over.
    try:
        with work_lock(
            workdir / LOCK,
            what=f"uavbench reproduce --profile {profile.name}",
            wait=config.wait,
            notify=status,
        ):
            return _run_locked(config, profile, specs, workdir)
    except LockBusyError as err:
        raise InputError(f"{err} (or choose another workdir)") from None


def planned_tracking_uri(tracker: str, tracking_uri: str | None) -> str | None:
    """The store the units will log to, as the tracker will resolve it (``tracking_uri``, else
    ``MLFLOW_TRACKING_URI``, else ``./mlflow.db``), known before the tracker is made; None when
    nothing is logged."""
    if tracker == "null":
        return None
    if tracker == "local":
        return str(Path.cwd() / "tracking-local")  # a directory on this machine
    return tracking_uri or os.environ.get("MLFLOW_TRACKING_URI") or "sqlite:///mlflow.db"


def _run_locked(
    config: ReproduceConfig, profile: ReproProfile, specs: list, workdir: Path
) -> ReproduceResult:
    from benchmark.data import list_splits
    from benchmark.tracking import RunStatus, create_tracker, git_commit

    started = time.time()
    seeds = list(range(config.seeds if config.seeds is not None else profile.seeds))
    data_root = config.data or Path("data") / f"{profile.dataset}-s{config.dataset_seed}"
    out = config.out or Path("reports") / profile.name
    dataset_hash = _check_data(data_root, profile, config)
    # The report stage renders the heading-cue audit's datasets next to this one: one left by
    # an earlier simulator would stop it after the training, so it is refused now.
    check_cue_datasets(data_root)
    try:
        units = plan_units(specs, profile, seeds, data_root, list_splits(data_root), dataset_hash,
                           workdir)  # fmt: skip
    except ValueError as err:
        raise InputError(str(err)) from err

    # What happens to the report's other tables, said before any training (and in the README).
    merge = plan_merge(out, specs, profile, data_root, workdir, dataset_hash, config.stale)
    if merge.describe():
        status(merge.describe())

    workdir.mkdir(parents=True, exist_ok=True)
    tracker = create_tracker(config.tracker, config.tracking_uri, workdir=Path.cwd())
    # The report directory is this run's output: rewriting a committed report is not dirty code.
    commit = git_commit(ignore=[out]) or "unknown"
    provenance = {"git_commit": commit, "dataset_manifest": dataset_hash}
    logbook = Logbook(
        tracker,
        profile.name,
        {k: str(v) for k, v in provenance.items()},
        specs=specs,
        data_root=data_root,
        owner=owner_tags(workdir),
    )
    # Runs left RUNNING by an invocation that was killed (kill -9, power loss) end KILLED.
    stale = logbook.close_stale(spec.name for spec in load_specs(config.specs))
    if stale:
        status(f"closed {len(stale)} run(s) left RUNNING by a killed invocation: now KILLED")
    results: dict[str, UnitResult] = {}
    trained_seconds: dict[str, float] = {}  # units trained before, run again for files only
    todo: list[tuple[Unit, UnitTask]] = []
    for unit in units:
        if unit.shared_encoder and not unit.jobs:
            continue  # trained when a unit that needs it trains (below)
        stored = [s for job in unit.jobs if (s := logbook.finished(job, unit)) is not None]
        # the flight-fusion files are read from the work directory by the report: a unit whose
        # jobs are all in the store but whose files are gone runs again (it retrains nothing)
        wanted = ((sequence_paths, unit.fuse_splits), (volume_sequence_paths, unit.volume_splits),
                  (joint_sequence_paths, unit.joint_splits))  # fmt: skip
        fused = all(
            fusion_done(paths, workdir / "units" / unit.key, split)
            for paths, splits in wanted
            for split in splits
        )
        if len(stored) == len(unit.jobs) and stored:
            seconds = max(seconds for _, seconds in stored)
            if fused:
                merged: dict[str, dict[str, float]] = {}
                for metrics, _ in stored:
                    merged.update(metrics)
                results[unit.key] = UnitResult(unit.key, True, metrics=merged, seconds=seconds)
                continue
            # runs again for its fusion files only: its training time stays the stored one
            trained_seconds[unit.key] = seconds
        unit_dir = workdir / "units" / unit.key
        live = None
        if config.tracker != "null":
            live = logbook.unit_tracking(unit, log_model=config.log_models)
        todo.append(
            (
                unit,
                UnitTask(
                    unit.key,
                    unit.cfg,
                    unit.eval_splits,
                    unit_dir,
                    tracking=live,
                    fuse_splits=unit.fuse_splits,
                    volume_splits=unit.volume_splits,
                    joint_splits=unit.joint_splits,
                ),
            )
        )
    todo = _with_shared_encoders(todo, units, workdir, logbook, config)
    status(
        f"reproduce {profile.name}: {len(specs)} tables/figures, {len(units)} training runs "
        f"({len(units) - len(todo)} already in the tracking store), {len(seeds)} seed(s), "
        f"logging to {tracker.uri or config.tracker}"
    )
    # Journalled now and as each unit finishes: a killed invocation still shows what it trained.
    keys = [u.key for u in units]
    invocation = start_invocation(workdir, keys, provenance["git_commit"], started)
    failures: list[str] = []

    def on_done(unit: Unit, result: UnitResult) -> None:
        if result.ok and unit.key in trained_seconds:  # not this invocation's re-evaluation
            result.seconds = trained_seconds[unit.key]
        results[unit.key] = result
        unit_dir = workdir / "units" / unit.key
        if unit_dir.is_dir():
            write_config(unit, unit_dir / "config.json")
        for job in unit.jobs:
            logbook.log_job(job, unit, result)
        invocation.unit_done(unit.key, result.ok)
        if not result.ok:
            failures.append(f"{unit.title}: {result.error}")
            status(f"FAILED {unit.title}: {result.error}")

    run_status = RunStatus.FINISHED
    units_log_to = None if config.tracker == "null" else tracker.uri  # null's uri reads "null"
    try:
        # First the shared encoders (their checkpoints are what the others load) and every
        # unit that needs none, then the units on the shared encoders; one whose shared encoder
        # failed is reported failed without running.
        first = [(u, t) for u, t in todo if not u.needs]
        run_executor(config.executor, first, on_done, config.quiet, units_log_to)
        broken = {u.key: u.title for u, _ in first if not results[u.key].ok}
        rest = []
        for unit, task in todo:
            if not unit.needs:
                continue
            bad = [broken[k] for k in unit.needs if k in broken]
            if bad:
                on_done(unit, UnitResult(unit.key, False, error=f"its shared encoder failed "
                                         f"({bad[0]})"))  # fmt: skip
            else:
                rest.append((unit, task))
        run_executor(config.executor, rest, on_done, config.quiet, units_log_to)
        invocation.end("failed" if failures else "finished")
        invocations = relevant_invocations(workdir, keys, invocation.id)
        stage = _ReportStage(specs, units, results, profile, (data_root, out, workdir), merge,
                             config)  # fmt: skip
        references = _report_work(stage)
        inputs = _report_inputs(stage, logbook, references)
        numbers = _report_numbers(stage, inputs)
        written = _write_reports(stage, logbook, invocations, inputs, numbers)
    except KeyboardInterrupt:
        run_status = RunStatus.KILLED
        invocation.end("interrupted")
        logbook.kill_unfinished_units(unit.key for unit, _ in todo)
        status("interrupted: finished runs are kept; run the same command again to resume")
        raise
    except BaseException:
        run_status = RunStatus.FAILED
        raise
    finally:
        logbook.close(
            run_status if not failures or run_status is not RunStatus.FINISHED else RunStatus.FAILED
        )
        tracker.close()
    # Where the runs really went (counted at the end, not assumed at the start): the store, or
    # the local fallback and the `uavbench sync` that sends them; then how to browse them.
    return ReproduceResult(
        out=out,
        written=tuple(written),
        wall_s=time.time() - started,
        host=platform.node(),
        failures=tuple(failures),
        tracking=tracker.summary(),
        browse=browse_hint(config.tracker, tracker),
    )


def _with_shared_encoders(
    todo: list[tuple[Unit, UnitTask]],
    units: list[Unit],
    workdir: Path,
    logbook: Logbook,
    config: ReproduceConfig,
) -> list[tuple[Unit, UnitTask]]:
    """``todo`` with the shared-encoder units its units need put first, each once, even when the
    tracking store has them: their checkpoints must be in ``workdir`` (a finished one costs
    nothing to "run" again; a FINISHED run in the store is reused by the worker)."""
    queued = {u.key for u, _ in todo}
    needed = {k for u, _ in todo for k in u.needs}
    shared = []
    for unit in units:
        if unit.key in needed and unit.key not in queued:
            live = None
            if config.tracker != "null":
                live = logbook.unit_tracking(unit, log_model=config.log_models)
            task = UnitTask(unit.key, unit.cfg, unit.eval_splits, workdir / "units" / unit.key,
                            tracking=live, fuse_splits=unit.fuse_splits,
                            volume_splits=unit.volume_splits,
                            joint_splits=unit.joint_splits)  # fmt: skip
            shared.append((unit, task))
    return shared + todo


@dataclass(frozen=True)
class _ReportStage:
    """What the report stage's three steps (:func:`_report_inputs`, :func:`_report_numbers`,
    :func:`_write_reports`) read: today's specs and units, their results, the profile, the
    ``(data_root, out, workdir)`` paths, the merge with an earlier report and the configuration."""

    specs: list
    units: list[Unit]
    results: dict[str, UnitResult]
    profile: ReproProfile
    paths: tuple[Path, Path, Path]
    merge: MergePlan
    config: ReproduceConfig


def _report_work(stage: _ReportStage) -> ReferenceResults:
    """The report stage's work items, run by the units' executor (``executor.workers``
    processes, or Ray tasks): the non-learned references' evaluations not yet cached in
    ``<workdir>/references`` (chunks of frames) and the heading-cue audit's extra datasets not
    yet rendered. The references' results (cached ones included); the datasets are on disk. A
    dataset that failed to render is rendered again by the audit itself (it resumes), which
    then raises if it still fails."""
    from benchmark.data.format import DatasetError
    from benchmark.runner.execute.audit import cue_dataset_items
    from benchmark.runner.execute.reference_rows import plan_references
    from benchmark.runner.execute.work_items import ItemOutcome, WorkItem

    (data_root, _, workdir), config = stage.paths, stage.config
    try:
        references = plan_references(stage.specs, data_root, workdir, stage.profile.name)
        renders = cue_dataset_items(data_root)
    except DatasetError as err:
        raise _data_error(data_root, stage.profile, 0, err) from None
    datasets = {item.key for item in renders}
    items = [*references.items(), *renders]
    if references.tasks and not config.quiet:
        status(references.describe(max(1, config.executor.workers)))

    def on_done(item: WorkItem, outcome: ItemOutcome) -> None:
        if item.key in datasets:
            if not outcome.ok:
                status(f"{item.title} failed ({outcome.error}); the audit renders it again")
            return
        references.collect(item, outcome)

    run_work_items(config.executor, items, on_done, config.quiet, label="report work",
                   unit="pair")  # fmt: skip
    return references.results()


def _report_inputs(
    stage: _ReportStage, logbook: Logbook, references: ReferenceResults
) -> ReportInputs:
    """The report stage's work, before any report file is written (a failure leaves the report
    directory as it was), after :func:`_report_work` (``references``: its results): the constant
    predictor on every table's splits, the heading-cue audit (its extra datasets rendered by
    then) and the non-learned rows of the sequence tables fused along the flights, in
    ``executor.workers`` processes, the provenance digests
    (every checkpoint's weights, every prediction file) and Table 6's measurements (cached in
    ``<workdir>/costs``; a new one logged to ``logbook``)."""
    from benchmark.data.format import DatasetError, read_manifest
    from benchmark.runner.claims.report_numbers import (
        ReportInputs,
        results_frame,
        validation_splits,
    )
    from benchmark.runner.execute.audit import heading_cue_rows
    from benchmark.runner.execute.costs import measure_costs
    from benchmark.runner.execute.non_learned import fuse_non_learned
    from benchmark.runner.execute.provenance import collect_provenance
    from benchmark.runner.execute.reference_rows import constant_rows

    specs, units, results, profile = stage.specs, stage.units, stage.results, stage.profile
    merge, (data_root, out, workdir) = stage.merge, stage.paths
    workers, quiet = max(1, stage.config.executor.workers), stage.config.quiet
    try:
        val_of = validation_splits(results_frame(units, results))
        rows, frames = constant_rows(specs, data_root, val_of)
        references.constants.update(frames)
        audit = heading_cue_rows(data_root, workers=workers, quiet=quiet)
        fused = fuse_non_learned([*specs, *merge.live], references, data_root, workers, quiet)
        done = {u.key: UnitResult(u.key, True) for u in merge.live_units} | results
        # A shared encoder that ran in an earlier invocation is in no result of this one, but
        # its weights made every feature its heads read: digested whenever one of them is.
        needed = {k for u in [*units, *merge.live_units] if u.key in done and done[u.key].ok
                  for k in u.needs}  # fmt: skip
        done |= {k: UnitResult(k, True) for k in needed if k not in done}
        provenance = collect_provenance([*units, *merge.live_units], done, data_root, workdir, out)
        costs = {}
        cost_specs = [s for s in specs if s.kind == "cost"]
        input_size = int(read_manifest(data_root)["image_size"]) if cost_specs else 0
        for spec in cost_specs:  # Table 6: cached per model and machine in <workdir>/costs
            with Progress(1, "costs", unit="table", enabled=not quiet) as bar:
                costs[spec.name] = measure_costs(
                    spec, profile, input_size, logbook, workdir / "costs", bar=bar
                )
                bar.update(1)
    except DatasetError as err:
        raise _data_error(data_root, profile, 0, err) from None
    return ReportInputs(rows, frames, references, audit, fused, provenance, costs)


def _report_numbers(stage: _ReportStage, inputs: ReportInputs) -> ReportNumbers:
    """Every number of the report, before any report file is written: the rows of
    ``results.csv``, the tables' flight x seed intervals (``executor.workers`` processes) and the
    claims (``claims.report_numbers``)."""
    from benchmark.data.format import DatasetError
    from benchmark.runner.claims.report_numbers import report_numbers

    data_root, _, workdir = stage.paths
    try:
        return report_numbers(
            stage.specs, stage.units, stage.results, data_root, workdir, merge=stage.merge,
            inputs=inputs, workers=max(1, stage.config.executor.workers), quiet=stage.config.quiet,
        )  # fmt: skip
    except DatasetError as err:
        raise _data_error(data_root, stage.profile, 0, err) from None


def _write_reports(
    stage: _ReportStage,
    logbook: Logbook,
    invocations: list[dict],
    inputs: ReportInputs,
    numbers: ReportNumbers,
) -> list[Path]:
    """``outputs.write_reports`` with the merge planned before training, the inputs computed
    by :func:`_report_inputs` and the numbers by :func:`_report_numbers`: it only writes. A
    dataset damaged while the units ran (their results are kept in the store) is one line with
    the fix instead of a traceback."""
    from benchmark.data.format import DatasetError
    from benchmark.runner.report.outputs import write_reports

    data_root, out, workdir = stage.paths
    try:
        return write_reports(
            stage.specs, stage.units, stage.results, stage.profile, data_root, out, logbook,
            invocations, workdir=workdir, merge=stage.merge, inputs=inputs, numbers=numbers,
        )  # fmt: skip
    except DatasetError as err:
        raise _data_error(data_root, stage.profile, 0, err) from None


def browse_hint(kind: str, tracker: Tracker) -> str:
    """How to look at what a reproduction logged to MLflow (``""`` for the other backends and
    for a fallback: ``tracker.summary()``, printed before it, says where those runs are)."""
    if kind != "mlflow" or getattr(tracker, "using_fallback", False):
        return ""
    if tracker.uri.startswith(("http://", "https://")):
        return f"browse the runs: {tracker.uri} (or uavbench ui --tracking-uri {tracker.uri})"
    return f"browse the runs: uavbench ui --tracking-uri {tracker.uri}"
