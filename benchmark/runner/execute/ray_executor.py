"""``uavbench reproduce --executor ray``: each training unit a Ray task, locally or on a cluster.

The contract is :func:`benchmark.runner.execute.pool.execute_units`'s: ``todo`` holds
``(Unit, UnitTask)`` pairs, ``on_done(unit, UnitResult)`` runs in this (driver) process in order of
completion, and the worker writes the same ``units/<key>/`` files through the same
:func:`benchmark.runner.execute.worker.run_unit` (one torch thread, as ``worker_init`` sets up), so
the reports and ``results.csv`` are those of the process pool, number for number.

- ``address=None``: a local Ray (``ray.init(address="local", num_cpus=...)``) is started for the
  run and shut down after it; an address (``ray start --head`` prints it) connects to that
  cluster. A Ray the caller already initialised is used as it is and left running.
- Failures: an exception inside a unit comes back as ``UnitResult(ok=False)`` (``run_unit`` never
  raises; a deterministic failure such as a non-finite loss would only fail again, so it is not
  retried). A unit whose worker process or node dies is resubmitted by Ray up to ``max_retries``
  times, then reported as failed ("worker died ..."); the other units carry on. Rerunning the
  command resumes: finished units are read from the tracking store or their files.
- Data: each task first checks on its node that the dataset directory is readable and its manifest
  has the driver's sha256 (a cluster needs the data on a shared file system, at the same path);
  otherwise that unit fails with the reason.
- Tracking: with a non-local cluster the runs must go to an MLflow server; a file or sqlite store
  is refused (:func:`check_ray_tracking`), because every node would write into its own disk.
- Ctrl-C: outstanding tasks are cancelled (their workers killed) and a local Ray is shut down;
  ``reproduce`` then marks the open unit runs KILLED, as with the pool.

``ray`` is optional (``pip install -e ".[ray]"``) and imported only inside these functions.
"""

from __future__ import annotations

import os
import platform
import time
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from urllib.parse import urlsplit

from benchmark.errors import InputError
from benchmark.progress import Progress, status
from benchmark.runner.execute import heartbeat
from benchmark.runner.execute.work_items import Entry, ItemOutcome, WorkItem, item_entries, run_item
from benchmark.runner.execute.worker import UnitResult, UnitTask, run_unit, worker_init

INSTALL_LINE = 'pip install -e ".[ray]"'
LOCAL_HOSTS = ("127.0.0.1", "localhost", "::1")
DEFAULT_CPUS_PER_UNIT = 1.0
DEFAULT_GPUS_PER_UNIT = 0.0
DEFAULT_MAX_RETRIES = 2
SHARED_FS_HINT = (
    "the data directory must be on a shared file system, mounted at the same path on every node"
)

OnDone = Callable[[object, UnitResult], None]


def resolve_resources(
    cpus: float | None, gpus: float | None, retries: int | None
) -> tuple[float, float, int]:
    """``ExecutorConfig.cpus_per_unit``, ``gpus_per_unit``, ``max_retries`` with their defaults
    filled in (None: not given), checked."""
    cpus = DEFAULT_CPUS_PER_UNIT if cpus is None else cpus
    gpus = DEFAULT_GPUS_PER_UNIT if gpus is None else gpus
    retries = DEFAULT_MAX_RETRIES if retries is None else retries
    _check_resources(cpus, gpus, retries)
    return cpus, gpus, retries


def _check_resources(cpus: float, gpus: float, retries: int) -> None:
    if not cpus > 0:
        raise InputError(f"executor.cpus_per_unit must be > 0, got {cpus:g}")
    if not gpus >= 0:
        raise InputError(f"executor.gpus_per_unit must be >= 0, got {gpus:g}")
    if retries < 0:
        raise InputError(f"executor.max_retries must be >= 0, got {retries}")


# ----------------------------------------------------------------------------- guards
def import_ray() -> ModuleType:
    """The ``ray`` module, or a :class:`InputError` (exit 2) with the install line."""
    try:
        import ray
    except ImportError as err:
        raise InputError(
            f"the Ray executor needs the optional dependency ray ({err}); install it with: "
            f"{INSTALL_LINE}"
        ) from err
    return ray


def is_local_address(address: str | None) -> bool:
    """None / ``"local"`` (a Ray started here) or a cluster whose head is this machine's
    loopback address (``127.0.0.1:6379``, ``ray://localhost:10001``)."""
    if address is None or address.strip() in ("", "local"):
        return True
    text = address.strip()
    host = urlsplit(text if "://" in text else f"//{text}").hostname or ""
    return host.lower() in LOCAL_HOSTS


def is_node_local_uri(uri: str) -> bool:
    """A tracking store in a file of this machine: ``sqlite:``, ``file:`` or a plain path."""
    scheme = urlsplit(uri).scheme.lower()
    return scheme in ("", "file", "sqlite") or len(scheme) == 1  # len 1: a Windows drive "C:"


def check_ray_tracking(address: str | None, tracking_uri: str | None) -> None:
    """Refuse a file or sqlite tracking store with a non-local Ray cluster: each unit's run is
    logged by the worker that trains it, on whatever node Ray picked, so a store that is a file
    would be written on that node's disk and the runs would be lost to this machine and the UI.
    ``tracking_uri`` None or "" (nothing logged) always passes."""
    if is_local_address(address) or not tracking_uri or not is_node_local_uri(tracking_uri):
        return
    raise InputError(
        f"the Ray cluster at {address} cannot track to {tracking_uri}: that store is a file, and "
        "each unit's run is logged by the node that trains it, into a file of that node's own "
        "disk, so the runs would be lost (the driver and the UI never see them). Run an MLflow "
        "server every node reaches (docs/gpu-and-cluster.md shows the command) and track to "
        "http://<that host>:5000, or track nothing (tracker null)"
    )


def check_dataset_on_node(root: str | Path, expected_sha256: str) -> str:
    """Empty if the dataset at ``root`` is readable here and its manifest's sha256 is
    ``expected_sha256`` (the driver's), else the reason, naming the path and this host."""
    from benchmark.tracking import manifest_sha256

    path = Path(root).absolute()
    host = platform.node()
    try:
        digest = manifest_sha256(path)
    except OSError as err:  # missing directory or manifest, permission denied, stale NFS handle
        return f"dataset {path} not readable on node {host}: {SHARED_FS_HINT} ({err})"
    if digest != expected_sha256:
        return (
            f"dataset {path} on node {host} is not the driver's (manifest sha256 {digest[:16]}..., "
            f"expected {expected_sha256[:16]}...): {SHARED_FS_HINT}"
        )
    return ""


# ----------------------------------------------------------------------------- the Ray task
def _set_up_node(data_root: str | Path | None, manifest_digest: str, driver_cwd: str) -> str:
    """A Ray task's set-up on its node: the pool worker's (one torch thread, SIGINT ignored),
    the driver's working directory (relative paths of the plan resolve as on the driver, when
    the file system is shared), then the dataset check: "" when it passes or there is nothing
    to check (no ``data_root`` or no digest), else the reason."""
    worker_init()
    if Path(driver_cwd).is_dir():
        os.chdir(driver_cwd)
    if data_root is None or not manifest_digest:
        return ""
    return check_dataset_on_node(data_root, manifest_digest)


def ray_unit(task: UnitTask, manifest_digest: str, driver_cwd: str) -> UnitResult:
    """What one Ray task of a unit runs on its node: :func:`_set_up_node`, then
    :func:`run_unit` (a dataset the node does not share fails the unit, untrained)."""
    start = time.perf_counter()
    problem = _set_up_node(task.cfg.data.root, manifest_digest, driver_cwd)
    if problem:
        return UnitResult(task.key, False, seconds=time.perf_counter() - start, error=problem)
    return run_unit(task)


def ray_item(item: WorkItem, manifest_digest: str, driver_cwd: str) -> ItemOutcome:
    """What a Ray task of a work item runs on its node: :func:`_set_up_node`, then
    ``run_item`` (``manifest_digest`` "" when the item reads no dataset)."""
    start = time.perf_counter()
    problem = _set_up_node(item.data_root, manifest_digest, driver_cwd)
    if problem:
        return ItemOutcome(None, problem, time.perf_counter() - start)
    return run_item(item)


# ----------------------------------------------------------------------------- the driver
def execute_units_ray(
    todo: list[tuple[object, UnitTask]],
    on_done: OnDone,
    quiet: bool,
    *,
    address: str | None = None,
    cpus_per_unit: float = DEFAULT_CPUS_PER_UNIT,
    gpus_per_unit: float = DEFAULT_GPUS_PER_UNIT,
    max_retries: int = DEFAULT_MAX_RETRIES,
    num_cpus: int | None = None,
    task_fn: Callable[..., UnitResult] = ray_unit,
) -> None:
    """Submit every task of ``todo`` to Ray and call ``on_done(unit, result)`` here as each ends.

    ``num_cpus``: CPUs of a local Ray (default ``os.cpu_count()``); ignored with an address.
    ``task_fn(task, manifest_digest, driver_cwd)`` is what a worker runs (:func:`ray_unit`;
    tests wrap it to kill a worker mid-unit)."""
    entries = [Entry(unit, task, str(getattr(unit, "title", task.key)),
                     data_root=str(task.cfg.data.root), heartbeat_dir=task.unit_dir)
               for unit, task in todo]  # fmt: skip

    def lost(entry: Entry, error: str, seconds: float) -> UnitResult:
        return UnitResult(entry.payload.key, False, seconds=seconds, error=error)

    _ray_loop(entries, task_fn, on_done, lost, quiet, ("reproduce", "run", "unit"),
              address=address, cpus=cpus_per_unit, gpus=gpus_per_unit, max_retries=max_retries,
              num_cpus=num_cpus)  # fmt: skip


def execute_items_ray(
    items: list[WorkItem],
    on_done: Callable[[WorkItem, ItemOutcome], None],
    quiet: bool,
    *,
    address: str | None = None,
    cpus_per_item: float = DEFAULT_CPUS_PER_UNIT,
    max_retries: int = DEFAULT_MAX_RETRIES,
    num_cpus: int | None = None,
    label: str = "work",
    unit: str = "item",
    task_fn: Callable[..., ItemOutcome] = ray_item,
) -> None:
    """:func:`execute_units_ray` for work items (no GPU each): ``on_done(item, outcome)`` here
    as each ends; an item Ray could not run (its worker or node died ``max_retries + 1`` times)
    is an outcome with that error."""

    def lost(entry: Entry, error: str, seconds: float) -> ItemOutcome:
        return ItemOutcome(None, error, seconds)

    _ray_loop(item_entries(items), task_fn, on_done, lost, quiet, (label, unit, "item"),
              address=address, cpus=cpus_per_item, gpus=0.0, max_retries=max_retries,
              num_cpus=num_cpus)  # fmt: skip


def _ray_loop(
    entries: list[Entry],
    task_fn: Callable[..., object],
    on_done: Callable[[object, object], None],
    lost: Callable[[Entry, str, float], object],
    quiet: bool,
    names: tuple[str, str, str],
    *,
    address: str | None,
    cpus: float,
    gpus: float,
    max_retries: int,
    num_cpus: int | None,
) -> None:
    """Submit ``task_fn(entry.payload, manifest_digest, driver_cwd)`` for every entry and call
    ``on_done(entry.handle, result)`` here as each ends (``lost(entry, error, seconds)`` when
    Ray could not produce a result). ``names``: the progress label, its unit and the word
    before each Ray task's name."""
    _check_resources(cpus, gpus, max_retries)
    ray = import_ray()
    if not entries:
        return
    label, unit, kind = names
    digests: dict[str, str] = {}
    with Progress(sum(e.size for e in entries), label, unit=unit, enabled=not quiet) as bar:
        for entry in entries:  # the driver's view of the data, which every node must share
            if entry.data_root is not None and entry.data_root not in digests:
                digests[entry.data_root] = _manifest_digest(entry.data_root)
        bar.status("starting Ray" if is_local_address(address) else f"connecting to {address}")
        owned = connect_ray(address, num_cpus)
        pending: dict[object, tuple[Entry, float]] = {}
        try:
            local = address is None or address == "local"
            _check_nodes(ray, cpus, gpus, fatal=owned and local)
            remote = ray.remote(
                num_cpus=cpus,
                num_gpus=gpus,
                max_retries=max_retries,
                retry_exceptions=False,  # an exception is the task's own: it would fail again
            )(task_fn)
            cwd = str(Path.cwd())
            submitted = time.time()
            for entry in entries:
                digest = digests.get(entry.data_root or "", "")
                ref = remote.options(name=f"{kind} {entry.name}"[:120]).remote(
                    entry.payload, digest, cwd
                )
                pending[ref] = (entry, time.monotonic())
            bar.status(f"{len(pending)} {kind}(s) submitted")
            line = heartbeat.RunningLine(bar, since=submitted)
            while pending:
                done, _ = ray.wait(list(pending), num_returns=1, timeout=heartbeat.POLL_S)
                if not done:  # the running units' epochs (heartbeats on a shared file system)
                    line.show([(e.name, e.heartbeat_dir) for e, _ in pending.values()
                               if e.heartbeat_dir is not None])  # fmt: skip
                    continue
                entry, started = pending.pop(done[0])
                value, error = _fetch(ray, done[0], max_retries)
                on_done(entry.handle, value if not error else
                        lost(entry, error, time.monotonic() - started))  # fmt: skip
                bar.update(entry.size, postfix=f"done {entry.name}")
        except BaseException:  # Ctrl-C or on_done failing: stop what still runs, then re-raise
            for ref in pending:
                try:
                    ray.cancel(ref, force=True)  # kills the worker: it may be mid-training
                except Exception:  # already finished or its node is gone
                    pass
            raise
        finally:
            if owned:
                ray.shutdown()


def _manifest_digest(root: str) -> str:
    from benchmark.tracking import manifest_sha256

    try:
        return manifest_sha256(root)
    except OSError as err:
        raise InputError(f"dataset {Path(root).absolute()} not readable: {err}") from err


def connect_ray(address: str | None = None, num_cpus: int | None = None) -> bool:
    """Start a local Ray (``address`` None or "local"; ``num_cpus`` default ``os.cpu_count()``)
    or join the cluster at ``address``. True if this call did (the caller shuts it down with
    ``ray.shutdown()``), False if a Ray was already initialised in this process."""
    import logging

    ray = import_ray()
    if ray.is_initialized():
        return False
    common = {"logging_level": logging.WARNING, "log_to_driver": True}
    if address is None or address == "local":
        for attempt in (1, 2):
            try:
                ray.init(
                    address="local",  # never join a cluster RAY_ADDRESS points at by accident
                    num_cpus=num_cpus or os.cpu_count() or 1,
                    include_dashboard=False,
                    **common,
                )
                break
            except Exception as err:  # Ray gives its raylet a fixed 30 s to register
                ray.shutdown()  # what did start of this attempt
                if attempt == 2:
                    raise RuntimeError(f"could not start a local Ray (twice): {err}") from err
                status(f"warning: starting a local Ray failed ({err}); trying once more")
    else:
        try:
            ray.init(address=address, **common)
        except (ConnectionError, TimeoutError, RuntimeError) as err:
            raise InputError(f"cannot connect to the Ray cluster at {address}: {err}") from err
    return True


def _check_nodes(ray, cpus: float, gpus: float, *, fatal: bool) -> None:
    """A task no node can hold would wait forever: refuse it on a local Ray, warn on a cluster
    (an autoscaler may still add such a node)."""
    nodes = [n.get("Resources", {}) for n in ray.nodes() if n.get("Alive")]
    if any(r.get("CPU", 0) >= cpus and r.get("GPU", 0) >= gpus for r in nodes):
        return
    have = "; ".join(f"CPU {r.get('CPU', 0):g}, GPU {r.get('GPU', 0):g}" for r in nodes) or "none"
    message = (
        f"no Ray node has cpus_per_unit {cpus:g} and gpus_per_unit {gpus:g} free to give "
        f"(nodes: {have})"
    )
    if fatal:
        raise InputError(message)
    status(f"warning: {message}; the units wait until such a node joins")


def _fetch(ray, ref, max_retries: int) -> tuple[object, str]:
    """``(the task's value, "")``, or ``(None, why Ray could not produce it)``."""
    try:
        return ray.get(ref), ""
    except ray.exceptions.RayTaskError as err:  # raised outside the task's own guard: set-up
        cause = err.cause if getattr(err, "cause", None) is not None else err
        return None, f"ray task failed: {type(cause).__name__}: {_first_line(cause)}"
    except ray.exceptions.TaskCancelledError:
        return None, "cancelled"
    except ray.exceptions.RayError as err:  # WorkerCrashedError, NodeDiedError, OutOfMemoryError
        attempts = max_retries + 1
        return None, (
            f"worker died on each of {attempts} attempt(s) (max_retries {max_retries}): "
            f"{type(err).__name__}: {_first_line(err)}"
        )


def _first_line(err: BaseException) -> str:
    lines = [line.strip() for line in str(err).splitlines() if line.strip()]
    return lines[0] if lines else repr(err)
