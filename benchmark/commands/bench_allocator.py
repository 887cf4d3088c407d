"""``uavbench bench allocator``: the matcher's training step and the joint flight fusion under
glibc's default allocator policy and uavbench's, each in fresh processes, side by side
(:mod:`benchmark.bench.allocator`)."""

from __future__ import annotations

import argparse

from benchmark.bench import allocator as lib
from benchmark.errors import UsageError

HELP = "matcher step and joint fusion under glibc's default allocator and uavbench's, side by side"
DESCRIPTION = lib.__doc__
FORMATTER = argparse.RawDescriptionHelpFormatter


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--workloads", default=",".join(lib.WORKLOADS),
                   help=f"comma list of {','.join(lib.WORKLOADS)}")  # fmt: skip
    p.add_argument("--precision", default="fp32", help="comma list of fp32,bf16 (the matcher)")
    p.add_argument("--no-base", action="store_true", help="skip the matcher's base fp32 loop")
    p.add_argument("--rounds", type=int, default=2, help="fresh processes per side")
    p.add_argument("--steps", type=int, default=6, help="timed repetitions per process")
    p.add_argument("--warmup", type=int, default=2, help="untimed repetitions first")
    p.add_argument("--threads", type=int, default=1, help="torch threads")


def run(args: argparse.Namespace) -> int:
    try:
        config = lib.AllocatorBenchConfig(
            workloads=tuple(w.strip() for w in args.workloads.split(",") if w.strip()),
            precisions=tuple(p.strip() for p in args.precision.split(",") if p.strip()),
            base=not args.no_base,
            rounds=args.rounds,
            steps=args.steps,
            warmup=args.warmup,
            threads=args.threads,
        )
    except ValueError as err:
        raise UsageError(f"bench allocator: {err}") from err
    result = lib.bench_allocator(config, progress=lambda line: print(line, flush=True))
    for line in result.lines():
        print(line)
    return 0
