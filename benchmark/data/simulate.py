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
from dataclasses import dataclass
from pathlib import Path

from benchmark.data.profiles import DataProfile
from benchmark.errors import InputError


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


@dataclass(frozen=True)
class SimulateResult:
    """What :func:`simulate` did to the dataset at ``out`` (profile ``profile``, ``seed``):
    ``state`` is ``"complete"`` (already finished and confirmed: nothing rendered) or
    ``"written"``; the seconds spent building the cities, planning and rendering; the UAV and
    satellite images rendered with ``workers`` processes; and ``replaced``, the shards whose bytes
    on disk differed from their render (corrupted) and were written again."""

    out: Path
    profile: str
    seed: int
    workers: int
    state: str
    cities_s: float = 0.0
    plan_s: float = 0.0
    render_s: float = 0.0
    rendered_uav: int = 0
    rendered_sat: int = 0
    replaced: tuple[str, ...] = ()

    def lines(self) -> list[str]:
        """The summary: one line saying what was done (and how fast)."""
        if self.state == "complete":
            return [
                f"{self.out}: already complete (profile {self.profile}, seed {self.seed}); "
                "nothing to do"
            ]
        n = self.rendered_uav + self.rendered_sat
        rate = n / self.render_s if self.render_s > 0 else float("nan")
        return [
            f"{self.out}: {self.state}; cities {self.cities_s:.1f} s, plan {self.plan_s:.1f} s, "
            f"rendered {self.rendered_uav} UAV + {self.rendered_sat} satellite images in "
            f"{self.render_s:.1f} s ({rate:.1f} img/s, {self.workers} workers)"
        ]

    def warnings(self) -> list[str]:
        """The corrupted shards that were replaced, as one line (empty when none were): worth
        telling apart from the summary (the command prints it on stderr)."""
        if not self.replaced:
            return []
        return [
            f"{self.out}: replaced {len(self.replaced)} corrupted shard(s): "
            + ", ".join(self.replaced)
        ]


def simulate(config: SimulateConfig) -> SimulateResult:
    """Render (or resume, or confirm) the dataset of ``config``; returns what was done. What it
    notices on the way (a lock it waits for, a file rendered again) goes through
    :func:`benchmark.progress.status`. InputError for a directory of another dataset, a busy lock
    or a disk error."""
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
        raise InputError(str(err)) from err
    except OSError as err:
        message = os_error_message(err)
        if message is None:
            raise
        raise InputError(message) from None
    return SimulateResult(
        out=out,
        profile=profile.name,
        seed=config.seed,
        workers=config.workers,
        state=stats["state"],
        cities_s=stats.get("cities_s", 0.0),
        plan_s=stats.get("plan_s", 0.0),
        render_s=stats.get("render_s", 0.0),
        rendered_uav=stats.get("rendered_uav", 0),
        rendered_sat=stats.get("rendered_sat", 0),
        replaced=tuple(stats.get("replaced", ())),
    )
