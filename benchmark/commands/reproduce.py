"""``uavbench reproduce``: parse the flags into a :class:`benchmark.runner.ReproduceConfig` and
run :func:`benchmark.runner.reproduce` (simulate, train, evaluate, track, report).

Only parsing happens here; every check and every default that is not a flag's lives in the
library, so ``reproduce(ReproduceConfig(...))`` from Python behaves as this command does.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from benchmark.runner.execute.pool import ExecutorConfig
from benchmark.runner.execute.ray_executor import (
    DEFAULT_CPUS_PER_UNIT,
    DEFAULT_GPUS_PER_UNIT,
    DEFAULT_MAX_RETRIES,
    INSTALL_LINE,
)
from benchmark.runner.plan.partial import DEFAULT_STALE, STALE_MODES
from benchmark.runner.plan.repro_profiles import PROFILES
from benchmark.runner.reproduction import ReproduceConfig, reproduce

HELP = "reproduce the paper's tables and figures: simulate, train, evaluate, track, report"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--profile", choices=sorted(PROFILES), default="quick")
    parser.add_argument(
        "--only",
        default="",
        help="comma-separated tables/figures (table1,fig7) or groups: paper (the paper's tables "
        "and figures), extras (extended, leakage, towns); default: all",
    )
    parser.add_argument(
        "--seeds",
        type=int,
        default=None,
        help="training seeds per variant, on one dataset (default: the profile's, quick 3)",
    )
    parser.add_argument(
        "--stale",
        choices=STALE_MODES,
        default=DEFAULT_STALE,
        help="with --only: what to do with the report's other tables when they come from an "
        "earlier run (other dataset, profile or code, or predictions gone): keep them as "
        "written, marked 'from an earlier run at <commit>' and left out of today's claims "
        "(default), or drop them with their files and README lines",
    )
    parser.add_argument("--out", type=Path, default=None, help="reports dir (reports/<profile>)")
    parser.add_argument(
        "--workdir", type=Path, default=None, help="checkpoints etc. (runs/<profile>)"
    )
    parser.add_argument("--data", type=Path, default=None, help="dataset dir (data/<profile>)")
    parser.add_argument("--dataset-seed", type=int, default=0)
    add_workers_argument(parser, "parallel training processes (units at once)")
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
    parser.add_argument(
        "--device",
        default="auto",
        help="where every unit trains and evaluates: auto (CUDA, else MPS, else CPU), cpu, cuda, "
        "cuda:N, mps (default: auto; not part of a unit's identity)",
    )
    parser.add_argument(
        "--precision",
        default="auto",
        help="auto, fp32, bf16 or fp16 for every unit (default auto: bf16 on CUDA with bf16, "
        "fp32 on every CPU); bf16 on a CPU needs native bf16 (avx512_bf16/amx_bf16) or "
        "UAVBENCH_ALLOW_SLOW_BF16=1; a precision other than fp32 trains other units",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    add_executor_arguments(parser)
    parser.add_argument(
        "--no-wait",
        action="store_true",
        help="exit 2 naming the holder instead of waiting when another reproduce holds --workdir",
    )


class _RenamedJobs(argparse.Action):
    """``--jobs`` was renamed: exit 2 with one line naming ``--workers`` (argparse alone would
    print its generic "unrecognized arguments")."""

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: object,
        option_string: str | None = None,
    ) -> None:
        parser.exit(
            2,
            f"{parser.prog}: error: --jobs is now --workers (worker processes; "
            "'jobs' are a unit's table rows)\n",
        )


def add_workers_argument(parser: argparse.ArgumentParser, help_text: str) -> None:
    """``--workers N``: worker processes (units at once), and the old name ``--jobs`` hidden,
    refused with a one-line error that names the new one."""
    parser.add_argument("--workers", type=int, default=2, help=help_text)
    parser.add_argument("--jobs", nargs="?", action=_RenamedJobs, help=argparse.SUPPRESS)


def add_executor_arguments(parser: argparse.ArgumentParser) -> None:
    """``--executor {pool,ray}``, ``--ray-address``, ``--cpus-per-unit``, ``--gpus-per-unit``,
    ``--max-retries``. The Ray-only flags default to None, so the library can refuse them
    without ``--executor ray`` (``benchmark.runner.execute.pool.check_executor``)."""
    group = parser.add_argument_group("executor (where the training units run)")
    group.add_argument(
        "--executor",
        choices=("pool", "ray"),
        default="pool",
        help="pool: --workers local worker processes (default); ray: one Ray task per unit, on a "
        f"local Ray or on --ray-address (needs {INSTALL_LINE})",
    )
    group.add_argument(
        "--ray-address",
        default=None,
        help="Ray cluster to submit to, as `ray start --head` prints it (HOST:6379 or "
        "ray://HOST:10001); default: a local Ray with --workers x --cpus-per-unit CPUs, "
        "started for this run",
    )
    group.add_argument(
        "--cpus-per-unit",
        type=float,
        default=None,
        help=f"CPUs Ray reserves per unit (default {DEFAULT_CPUS_PER_UNIT:g}; training uses one "
        "torch thread, the others serve DataLoader workers)",
    )
    group.add_argument(
        "--gpus-per-unit",
        type=float,
        default=None,
        help=f"GPUs Ray reserves per unit (default {DEFAULT_GPUS_PER_UNIT:g}; 0.5 puts two units "
        "on one GPU)",
    )
    group.add_argument(
        "--max-retries",
        type=int,
        default=None,
        help="times Ray reruns a unit whose worker process or node died "
        f"(default {DEFAULT_MAX_RETRIES})",
    )


def executor_config(args: argparse.Namespace) -> ExecutorConfig:
    """The executor flags (and ``--workers``, the units at once for both executors)."""
    return ExecutorConfig(
        kind=args.executor,
        workers=args.workers,
        ray_address=args.ray_address,
        cpus_per_unit=args.cpus_per_unit,
        gpus_per_unit=args.gpus_per_unit,
        max_retries=args.max_retries,
    )


def config_from(args: argparse.Namespace) -> ReproduceConfig:
    """The parsed flags as the library's frozen configuration."""
    return ReproduceConfig(
        profile=args.profile,
        only=tuple(name.strip() for name in args.only.split(",") if name.strip()),
        seeds=args.seeds,
        stale=args.stale,
        out=args.out,
        workdir=args.workdir,
        data=args.data,
        dataset_seed=args.dataset_seed,
        specs=args.specs,
        tracker=args.tracker,
        tracking_uri=args.tracking_uri,
        log_models=not args.no_models,
        device=args.device,
        precision=args.precision,
        quiet=args.quiet,
        wait=not args.no_wait,
        executor=executor_config(args),
    )


def run(args: argparse.Namespace) -> int:
    """Reproduce; print the closing lines; exit 0 when every unit trained, else 1."""
    result = reproduce(config_from(args))
    for line in result.lines():
        print(line)
    return 0 if result.ok else 1
