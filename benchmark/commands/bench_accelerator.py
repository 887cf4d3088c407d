"""``uavbench bench accelerator``: does this machine's accelerator run the benchmark, and how fast
(:mod:`benchmark.bench.accelerator`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from benchmark.bench import accelerator as lib
from benchmark.errors import UsageError

HELP = "one-command accelerator check: smoke reproduction, train fp32/bf16, latency"
DESCRIPTION = lib.__doc__
FORMATTER = argparse.RawDescriptionHelpFormatter


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--device", default="auto", help="auto, cpu, cuda, cuda:N or mps (bench/latency)"
    )
    p.add_argument("--precision", default=None, help="comma list of fp32,bf16 (default: both "
                   "where supported)")  # fmt: skip
    p.add_argument("--table", default="table3", help="the table the smoke reproduction makes")
    p.add_argument("--data", type=Path, default=None, help="an existing smoke dataset to reuse")
    p.add_argument("--keep", type=Path, default=None, help="keep the reproduction's files here")
    p.add_argument("--no-reproduce", action="store_true", help="skip the smoke reproduction")
    p.add_argument("--steps", type=int, default=3, help="timed training steps per loop")
    p.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    p.add_argument("--fast", action="store_true", help="tiny bench and latency sizes (tests)")


def run(args: argparse.Namespace) -> int:
    """Run the check and print a line per figure; exit 0, or 1 when the reproduction failed."""
    if args.steps < 1:
        raise UsageError("--steps must be >= 1")
    if args.data is not None and not args.data.is_dir():
        raise UsageError(f"--data {args.data}: not a directory (a smoke dataset expected)")
    config = lib.AcceleratorBenchConfig(
        device=args.device,
        precision=args.precision,
        table=args.table,
        data=args.data,
        keep=args.keep,
        reproduce=not args.no_reproduce,
        steps=args.steps,
        threads=args.threads,
        fast=args.fast,
    )
    result = lib.bench_accelerator(config)
    for line in result.lines():
        print(line)
    return 0 if result.ok else 1
