"""``uavbench simulate``: render the UAV/satellite pair dataset of a profile (resumable, parallel).

    uavbench simulate --profile {smoke,quick,paper} [--size N] [--out DIR] [--workers K] [--seed S]

Rerunning the same command after an interruption continues where it stopped and produces the
same bytes as an uninterrupted run; rerunning it on a finished dataset confirms it (a cached
checksum check) and renders again any file that no longer matches its manifest. Shards found on
disk that this code's journal does not vouch for are rendered again and compared byte for byte.
An ``--out`` holding a dataset of another profile, size or seed is refused without touching it.

One process renders into a directory at a time (``DIR/.simulate.lock``): a second invocation waits
for the first, saying who holds the lock, then finds the dataset finished; with ``--no-wait`` it
exits 2 instead, naming the holder (pid, host, start). A lock left by a killed process is taken
over. Disk full and permission errors end in one line naming the path and the fix (exit 2).
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from pathlib import Path

from benchmark.data.profiles import DataProfile
from benchmark.errors import UsageError


def default_out(profile: str, size: int | None, seed: int) -> Path:
    name = profile + (f"-n{size}" if size is not None else "") + (f"-s{seed}" if seed else "")
    return Path("data") / name


def single_thread_env() -> None:
    """One thread per process for numba/OpenMP/BLAS: parallelism comes from the workers.

    Must run before numba is imported (it reads NUMBA_NUM_THREADS once).
    """
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ.setdefault(var, "1")


@dataclass(frozen=True)
class SimulateConfig:
    """One ``uavbench simulate`` call: the ``profile`` (sized), dataset ``seed``, output
    directory, rendering ``workers``, the city cache (None: the default), whether to wait for
    another process rendering into ``out`` and whether to show a progress bar."""

    profile: DataProfile
    seed: int
    out: Path
    workers: int
    city_cache: Path | None = None
    wait: bool = True
    progress: bool = True


def simulate(config: SimulateConfig) -> int:
    """Render (or resume, or confirm) the dataset of ``config``; print what was done; exit code
    0. UsageError for a directory of another dataset, a busy lock or a disk error."""
    single_thread_env()
    from benchmark.data.format import DatasetError, os_error_message
    from benchmark.data.writer import ConfigMismatchError, simulate_dataset
    from benchmark.locks import LockBusyError

    out, profile = config.out, config.profile
    try:
        stats = simulate_dataset(
            out,
            profile,
            config.seed,
            workers=config.workers,
            cache_dir=config.city_cache,
            progress=config.progress,
            wait=config.wait,
        )
    except (ConfigMismatchError, LockBusyError, DatasetError) as err:
        raise UsageError(str(err)) from err
    except OSError as err:
        message = os_error_message(err)
        if message is None:
            raise
        raise UsageError(message) from None
    if stats.get("replaced"):
        print(f"{out}: replaced {len(stats['replaced'])} corrupted shard(s): "
              + ", ".join(stats["replaced"]), file=sys.stderr)  # fmt: skip
    if stats["state"] == "complete":
        print(
            f"{out}: already complete (profile {profile.name}, seed {config.seed}); nothing to do"
        )
    else:
        n = stats["rendered_uav"] + stats["rendered_sat"]
        rate = n / stats["render_s"] if stats["render_s"] > 0 else float("nan")
        print(
            f"{out}: {stats['state']}; cities {stats['cities_s']:.1f} s, "
            f"plan {stats['plan_s']:.1f} s, "
            f"rendered {stats['rendered_uav']} UAV + {stats['rendered_sat']} satellite images in "
            f"{stats['render_s']:.1f} s ({rate:.1f} img/s, {config.workers} workers)",
            file=sys.stdout,
        )
    return 0
