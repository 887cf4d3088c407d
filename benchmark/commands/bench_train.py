"""``uavbench bench train``: training throughput per precision, against a plain reference loop
(:mod:`benchmark.bench.train`)."""

from __future__ import annotations

import argparse
from collections.abc import Sequence

from benchmark.bench import train as lib
from benchmark.bench.train import BENCH_ENCODERS, ENCODERS, MODELS, OPTIMIZERS
from benchmark.errors import UsageError

HELP = "training pairs/s fp32/bf16 (quick, paper model), x plain loop, % of conv ceiling"
DESCRIPTION = lib.__doc__.split("\n")[0]


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--models", default="quick,paper", help="comma list of quick,paper")
    p.add_argument("--encoders", default=",".join(ENCODERS), help="comma list of "
                   f"{','.join(BENCH_ENCODERS)}, timed in the same rounds (default "
                   f"{','.join(ENCODERS)}; matching_alt3: the matching encoder with altitude "
                   "hypotheses -12/0/+12 m)")  # fmt: skip
    p.add_argument("--batch-size", type=int, default=20, help="pairs per step (paper: 20)")
    p.add_argument("--distinct-sat", type=int, default=4, help="distinct satellite images/batch")
    p.add_argument("--steps", type=int, default=5, help="timed steps per loop and model")
    p.add_argument("--warmup", type=int, default=1, help="untimed steps first")
    p.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    p.add_argument("--size", type=int, help="override the image size of every model")
    p.add_argument("--width", type=float, help="override the width of every model")
    p.add_argument("--attitude", default="pd_re_net")
    p.add_argument("--variant", default="a-f", help="GoogLeNet's variant (matching: '/')")
    p.add_argument("--device", default="auto", help="auto (CUDA, else MPS, else CPU), cpu, cuda, "
                   "cuda:N or mps")  # fmt: skip
    p.add_argument("--precision", default=None, help="comma list of fp32,bf16 (default: both "
                   "where the device supports bf16, else fp32 and the reason)")  # fmt: skip
    p.add_argument("--no-plain", action="store_true", help="skip the plain reference loop")
    p.add_argument("--no-base", action="store_true", help="skip the base rows (ours fp32 "
                   "before the encoder's last speed change: the matching encoder's 2-D DFT "
                   "correlation before issue 40; GoogLeNet's per-tensor optimiser loop before "
                   "issue 20, with --optimizer adam)")  # fmt: skip
    p.add_argument("--optimizer", choices=sorted(OPTIMIZERS), default="sgd", help="sgd: the "
                   "paper's SGD, momentum 0.9, lr 1e-3 (default); adam: the quick profile's Adam, "
                   "lr 3e-4, gradient norm clipped at 10")  # fmt: skip
    p.add_argument("--no-ceiling", action="store_true", help="skip the convolution ceiling")
    p.add_argument("--profile", type=int, default=0, metavar="N", help="after timing, profile "
                   "one step of each of our loops: time by kind of work and its N top ops (self "
                   "time)")  # fmt: skip
    p.add_argument("--ceiling-batch", type=int, default=None, help="images per ceiling "
                   "convolution (default 24: 20 pairs over 4 satellite images)")  # fmt: skip


def _comma_list(text: str) -> tuple[str, ...]:
    return tuple(item.strip() for item in text.split(",") if item.strip())


def config_from(args: argparse.Namespace) -> lib.TrainBenchConfig:
    """The bench's config of the parsed flags; UsageError naming the bad flag."""
    names = _comma_list(args.models)
    if not names or [m for m in names if m not in MODELS]:
        raise UsageError(f"--models {args.models!r}: expected a comma list of {sorted(MODELS)}")
    encoders = _comma_list(args.encoders)
    if not encoders or len(set(encoders)) != len(encoders) or set(encoders) - set(BENCH_ENCODERS):
        raise UsageError(f"--encoders {args.encoders!r}: expected a comma list of distinct "
                         f"{', '.join(BENCH_ENCODERS)}")  # fmt: skip
    for name in ("batch_size", "distinct_sat", "steps"):
        if getattr(args, name) < 1:
            raise UsageError(f"--{name.replace('_', '-')} must be >= 1")
    if args.warmup < 0:
        raise UsageError("--warmup must be >= 0")
    if args.profile < 0:
        raise UsageError("--profile must be >= 0 (rows of the op table)")
    if args.ceiling_batch is not None and args.ceiling_batch < 1:
        raise UsageError("--ceiling-batch must be >= 1")
    if args.distinct_sat > args.batch_size:
        raise UsageError("--distinct-sat cannot exceed --batch-size")
    return lib.TrainBenchConfig(
        models=names,
        encoders=encoders,
        batch_size=args.batch_size,
        distinct_sat=args.distinct_sat,
        steps=args.steps,
        warmup=args.warmup,
        threads=args.threads,
        size=args.size,
        width=args.width,
        attitude=args.attitude,
        variant=args.variant,
        device=args.device,
        precision=args.precision,
        plain=not args.no_plain,
        base=not args.no_base,
        optimizer=args.optimizer,
        ceiling=not args.no_ceiling,
        profile=args.profile,
        ceiling_batch=args.ceiling_batch,
    )


def parse(argv: Sequence[str]) -> lib.TrainBenchConfig:
    """The config of a ``bench train`` command line (tests, ``bench accelerator``)."""
    parser = argparse.ArgumentParser(prog="uavbench bench train", description=DESCRIPTION)
    add_arguments(parser)
    return config_from(parser.parse_args(list(argv)))


def run(args: argparse.Namespace) -> int:
    """Time the models and print the table, then the allocator policy every loop ran under
    (the base row too: ``bench allocator`` times the base as it ran before); exit 0."""
    from benchmark.allocator import allocator_status

    result = lib.bench_train(config_from(args))  # prints its set-up and CPU lines as it starts
    print(f"{allocator_status().detail} (every loop; bench allocator compares the policies)")
    for line in result.lines():
        print(line)
    return 0
