"""``uavbench bench TARGET ...``: performance benchmarks that print measured rates and ratios.

Speed targets are checked here, never by timed unit tests. ``TARGETS`` maps a target name to its
command module (``benchmark.commands.bench_*``: ``HELP``, ``add_arguments(parser)``,
``run(args) -> int``, optionally ``DESCRIPTION`` and ``FORMATTER`` for its ``--help`` and
``check_arguments(parser, args)``, which may end in ``parser.error``, exit 2). Modules
are imported only when their target runs. To add a target, add one line to ``TARGETS`` and
``TARGET_HELP``.
"""

from __future__ import annotations

import argparse
import importlib
from collections.abc import Sequence

from benchmark.errors import UsageError

TARGETS: dict[str, str] = {
    "simulate": "benchmark.commands.bench_simulate",
    "train": "benchmark.commands.bench_train",
    "model": "benchmark.commands.bench_model",
    "verify": "benchmark.commands.bench_verify",
    "ceiling": "benchmark.commands.bench_ceiling",
    "accelerator": "benchmark.commands.bench_accelerator",
    "ray": "benchmark.commands.bench_ray",
    "isa": "benchmark.commands.bench_isa",
    "allocator": "benchmark.commands.bench_allocator",
}

TARGET_HELP: dict[str, str] = {
    "simulate": "pairs/s at 96 and 224 px with all workers, and the time to build a city",
    "train": "training pairs/s fp32/bf16 (quick, paper model), x plain loop, % of conv ceiling",
    "model": "speed-ups of the shared-satellite encoding and channels_last, side by side",
    "verify": "cost of opening a dataset: size check, first sha256, cached sha256, side by side",
    "ceiling": "convolution throughput ceiling (GFLOP/s, fp32/bf16) of the device",
    "accelerator": "one-command accelerator check: smoke reproduction, train fp32/bf16, latency",
    "ray": "smoke reproduction through the process pool and a local Ray: wall times, ratio",
    "isa": "dataset manifest digest with each library's SIMD level forced down, side by side",
    "allocator": "matcher step and joint fusion: glibc's default allocator against uavbench's",
}

HELP = "performance benchmarks: " + ", ".join(f"bench {t}" for t in TARGETS)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.epilog = "targets:\n" + "\n".join(f"  {t:10s} {h}" for t, h in TARGET_HELP.items())
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("target", help=f"one of {sorted(TARGETS)}")
    parser.add_argument("rest", nargs=argparse.REMAINDER, help="arguments of the target (--help)")


def run_target(target: str, argv: Sequence[str]) -> int:
    """Parse ``argv`` with ``target``'s arguments and run it; its exit code (UsageError for bad
    input, as every command)."""
    if target not in TARGETS:
        raise UsageError(f"unknown bench target {target!r}; expected one of {sorted(TARGETS)}")
    module = importlib.import_module(TARGETS[target])
    parser = argparse.ArgumentParser(
        prog=f"uavbench bench {target}",
        description=getattr(module, "DESCRIPTION", module.HELP),
        formatter_class=getattr(module, "FORMATTER", argparse.HelpFormatter),
    )
    module.add_arguments(parser)
    args = parser.parse_args(list(argv))
    if hasattr(module, "check_arguments"):
        module.check_arguments(parser, args)
    return int(module.run(args) or 0)


def run(args: argparse.Namespace) -> int:
    return run_target(args.target, args.rest)
