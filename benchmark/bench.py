"""``uavbench bench TARGET ...``: performance benchmarks that print measured rates and ratios.

Speed targets are checked here, never by timed unit tests. ``TARGETS`` maps a target name to
``"module:function"``; the function takes the remaining command-line arguments
(``list[str]``) and returns the exit code. Modules are imported only when their target runs.
To add a target (e.g. ``bench train``), add one line to ``TARGETS`` and ``TARGET_HELP``.
"""

from __future__ import annotations

import argparse
import importlib

from benchmark.errors import UsageError

TARGETS: dict[str, str] = {
    "simulate": "benchmark.data.bench_simulate:main",
    "train": "benchmark.training.bench:main",
    "model": "benchmark.models.bench_model:main",
    "verify": "benchmark.data.bench_verify:main",
    "ceiling": "benchmark.models.bench_ceiling:main",
    "accelerator": "benchmark.bench_accelerator:main",
    "ray": "benchmark.runner.bench_ray:main",
    "isa": "benchmark.data.bench_isa:main",
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
}

HELP = "performance benchmarks: " + ", ".join(f"bench {t}" for t in TARGETS)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.epilog = "targets:\n" + "\n".join(f"  {t:10s} {h}" for t, h in TARGET_HELP.items())
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("target", help=f"one of {sorted(TARGETS)}")
    parser.add_argument("rest", nargs=argparse.REMAINDER, help="arguments of the target (--help)")


def run(args: argparse.Namespace) -> int:
    if args.target not in TARGETS:
        raise UsageError(f"unknown bench target {args.target!r}; expected one of {sorted(TARGETS)}")
    module, func = TARGETS[args.target].split(":")
    return int(getattr(importlib.import_module(module), func)(list(args.rest)) or 0)
