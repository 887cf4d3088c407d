"""``uavbench model-info``: parameters, size, FLOPs and CPU latency of a pair model (paper Table 6;
what is counted and timed: :mod:`benchmark.models.info`)."""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict
from typing import Any

from benchmark.config import ConfigError, parse_scalar, split_assignment
from benchmark.errors import UsageError
from benchmark.models.info import OPTION_FIELDS

HELP = "parameters, size, MFLOPs and CPU latency per pair of a model (paper Table 6)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--head", default="pd_re_net", help="attitude head (default pd_re_net)")
    parser.add_argument("--translation", default="regression", help="translation head")
    parser.add_argument("--encoder", default="googlenet", help="encoder (default googlenet)")
    parser.add_argument("--variant", default="a-f", help="'/', 'a', 'f' or 'a-f' (default a-f)")
    parser.add_argument("--width", type=float, default=1.0, help="width multiplier (default 1.0)")
    parser.add_argument("--size", type=int, default=224, help="input side in px (default 224)")
    parser.add_argument("--repeats", type=int, default=10, help="timed runs (default 10)")
    parser.add_argument("--warmup", type=int, default=3, help="untimed runs first (default 3)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    parser.add_argument(
        "--device", default="cpu", help="latency on: cpu (default, Table 6), auto, cuda[:N], mps"
    )
    parser.add_argument(
        "--precision",
        choices=("auto", "fp32", "bf16", "fp16"),
        default="fp32",
        help="autocast precision of the timed passes (default fp32)",
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object instead")
    parser.add_argument(
        "--set",
        dest="options",
        action="append",
        default=[],
        metavar="FIELD.OPTION=VALUE",
        help="a head or encoder option, e.g. --set attitude_options.hidden=512 (fields: "
        f"{', '.join(OPTION_FIELDS)}; repeatable)",
    )


def parse_options(items: list[str]) -> dict[str, dict[str, Any]]:
    """``["attitude_options.hidden=512"]`` -> ``{"attitude_options": {"hidden": 512}}`` (values
    read as YAML scalars; the head's signature types them). ValueError naming a bad item."""
    out: dict[str, dict[str, Any]] = {}
    for item in items:
        try:
            key, value = split_assignment(item, "attitude_options.hidden=512")
        except ConfigError:
            key, value = "", ""  # named below, with the fields it may set
        field, dot, option = key.partition(".")
        if not dot or not option or field not in OPTION_FIELDS:
            raise ValueError(
                f"--set {item!r}: expected FIELD.OPTION=VALUE with FIELD one of "
                f"{', '.join(OPTION_FIELDS)}, e.g. attitude_options.hidden=512"
            )
        out.setdefault(field, {})[option] = parse_scalar(value)
    return out


def run(args: argparse.Namespace) -> int:
    import torch

    from benchmark.models.device import resolve_placement
    from benchmark.models.info import format_info, model_info

    if args.repeats < 1 or args.warmup < 0 or args.threads < 1:
        raise UsageError(
            f"need --repeats >= 1, --warmup >= 0, --threads >= 1; got {args.repeats}, "
            f"{args.warmup}, {args.threads}"
        )
    torch.set_num_threads(args.threads)
    try:
        options = parse_options(args.options)
        # As training and evaluation: bf16 on a CPU without native bf16 only when allowed.
        placement = resolve_placement(args.device, args.precision)
        info = model_info(
            head=args.head,
            encoder=args.encoder,
            variant=args.variant,
            width=args.width,
            input_size=args.size,
            translation=args.translation,
            repeats=args.repeats,
            warmup=args.warmup,
            options=options,
            placement=placement,
        )
    except ValueError as err:  # bad configuration: unknown head/encoder/variant, size, width
        raise UsageError(str(err)) from None
    print(json.dumps(asdict(info)) if args.json else format_info(info))
    return 0
