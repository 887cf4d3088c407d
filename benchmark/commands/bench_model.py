"""``uavbench bench model``: measured speed of the pair model and of its two optimisations
(:mod:`benchmark.bench.model`)."""

from __future__ import annotations

import argparse

from benchmark.bench import model as lib

HELP = "speed-ups of the shared-satellite encoding and channels_last, side by side"
DESCRIPTION = lib.__doc__


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--head", default="pd_re_net")
    p.add_argument("--variant", default="a-f")
    p.add_argument("--width", type=float, default=1.0)
    p.add_argument("--size", type=int, default=224)
    p.add_argument("--batch", type=int, default=20, help="pairs per batch (paper: 20)")
    p.add_argument("--sats", type=int, default=2, help="distinct satellite images in the batch")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--threads", type=int, default=1)


def check_arguments(p: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    if min(args.batch, args.sats, args.repeats, args.threads) < 1 or args.sats > args.batch:
        p.error("need batch, sats, repeats, threads >= 1 and sats <= batch")


def run(args: argparse.Namespace) -> int:
    """Time the model's two optimisations and print the four lines; exit 0."""
    config = lib.ModelBenchConfig(
        head=args.head,
        variant=args.variant,
        width=args.width,
        size=args.size,
        batch=args.batch,
        sats=args.sats,
        repeats=args.repeats,
        threads=args.threads,
    )
    for line in lib.bench_model(config).lines():
        print(line)
    return 0
