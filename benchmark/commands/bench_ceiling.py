"""``uavbench bench ceiling [--device D] [--precision fp32,bf16] [--repeats N]``: the convolution
throughput ceiling of a device (:mod:`benchmark.bench.ceiling`)."""

from __future__ import annotations

import argparse

from benchmark.bench import ceiling as lib

HELP = "convolution throughput ceiling (GFLOP/s, fp32/bf16) of the device"
DESCRIPTION = lib.__doc__.split("\n")[0]


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--device", default="auto", help="auto, cpu, cuda, cuda:N or mps")
    p.add_argument("--precision", default=None, help="comma list of fp32,bf16 (default: both "
                   "where the device supports bf16)")  # fmt: skip
    p.add_argument("--repeats", type=int, default=3, help="timed runs per shape (median)")
    p.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    p.add_argument("--batch", type=int, default=None, help="images per convolution (default 24)")


def check_arguments(p: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    if args.repeats < 1 or (args.batch is not None and args.batch < 1):
        p.error("--repeats and --batch must be >= 1")


def run(args: argparse.Namespace) -> int:
    """Measure the ceiling and print the CPU's bf16 line, the notes, a line per precision;
    exit 0."""
    result = lib.bench_ceiling(args.device, args.precision, args.repeats, args.batch, args.threads)
    for line in result.lines():
        print(line)
    return 0
