"""The ``uavbench`` command line: the subcommand table and the dispatcher (the console script).

Each subcommand lives in its own module of ``benchmark.commands``, which exposes::

    HELP: str                                  # one line for ``uavbench --help``
    def add_arguments(parser: argparse.ArgumentParser) -> None
    def run(args: argparse.Namespace) -> int   # the exit code

Modules are imported only when their subcommand runs, so ``uavbench --help`` stays fast and a
heavy dependency (mlflow, numba) is loaded only by the commands that need it.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from benchmark import __version__
from benchmark.allocator import tune_allocator
from benchmark.errors import InputError

# subcommand -> module path. Order is the pipeline order shown in --help.
COMMANDS: dict[str, str] = {
    "simulate": "benchmark.commands.simulate",
    "preview": "benchmark.commands.preview",
    "verify": "benchmark.commands.verify",
    "bench": "benchmark.commands.bench",
    "continuity": "benchmark.commands.continuity",
    "heading-cue": "benchmark.commands.heading_cue",
    "model-info": "benchmark.commands.model_info",
    "train": "benchmark.commands.train",
    "evaluate": "benchmark.commands.evaluate",
    "reference": "benchmark.commands.reference",
    "ui": "benchmark.commands.ui",
    "sync": "benchmark.commands.sync",
    "reproduce": "benchmark.commands.reproduce",
    "compare": "benchmark.commands.compare",
}

# Loaded lazily, but --help needs the one-line descriptions without importing torch.
COMMAND_HELP: dict[str, str] = {
    "simulate": "render the UAV/satellite pair dataset (smoke/quick/paper; resumable, parallel)",
    "preview": "write a contact sheet PNG of UAV/satellite pairs with their poses",
    "verify": "check every file of a dataset against its manifest (sha256, shapes, counts)",
    "bench": "performance benchmarks (bench simulate: pairs/s and city build time)",
    "continuity": "reproduce paper Fig. 2: continuity of attitude representations vs heading",
    "heading-cue": "audit: how well image-wide UAV statistics alone read the yaw (issue 9)",
    "model-info": "parameters, size, MFLOPs and CPU latency per pair of a model (Table 6)",
    "train": "train one variant from a config (--set a.b=value), evaluate it, track it in MLflow",
    "evaluate": "evaluate a trained checkpoint on dataset splits: per-sample CSV and metrics",
    "reference": "evaluate a non-learned reference (oracle, template, feature+PnP) like a model",
    "ui": "serve the MLflow UI for the tracking store on 127.0.0.1 (Ctrl-C stops it)",
    "sync": "copy runs kept locally (./tracking-fallback) into an MLflow store; idempotent",
    "reproduce": "reproduce the paper's tables and figures: simulate, train, evaluate, report",
    "compare": "compare two workdirs' units on the same frames: paired differences, equivalence",
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="uavbench",
        description="Benchmark for UAV absolute pose estimation from a satellite image.",
    )
    parser.add_argument("--version", action="version", version=f"uavbench {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        sub.add_parser(name, help=COMMAND_HELP.get(name, ""), add_help=False)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    if not argv or argv[0] not in COMMANDS:
        parser.parse_args(argv)  # handles --help / --version / unknown command (exit 2)
        parser.print_help()
        return 2
    name = argv[0]
    try:  # before any tensor exists: freed blocks stay warm (benchmark.allocator)
        tune_allocator()
    except ValueError as err:
        print(f"uavbench {name}: error: {err}", file=sys.stderr)
        return 2
    module = importlib.import_module(COMMANDS[name])
    cmd_parser = argparse.ArgumentParser(prog=f"uavbench {name}", description=module.HELP)
    module.add_arguments(cmd_parser)
    args = cmd_parser.parse_args(argv[1:])
    try:
        return int(module.run(args) or 0)
    except InputError as err:  # UsageError (a flag) or the library's refusal of an input
        print(f"uavbench {name}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"uavbench {name}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
