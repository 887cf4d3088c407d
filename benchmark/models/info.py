"""``uavbench model-info``: parameters, size, FLOPs and CPU latency of a pair model (paper Table 6).

FLOPs are counted by ``torch.utils.flop_counter.FlopCounterMode`` on one UAV/satellite pair at the
given input size, with the formulas of ``benchmark.models.flop_count`` (complex matrix products,
the spectra's products and bilinear sampling of the matching encoder). It counts the matrix
products and convolutions only (normalisation, activations, pooling and softmax are not counted,
as in most published FLOP figures) and reports FLOPs = 2 x multiply-adds. A pair encoder gets a
synthetic ``context`` with the quick dataset's geometry (``benchmark.models.bench_inputs``).
"Inference" runs the model in eval mode (the fusion variants' auxiliary branches and heads are
skipped, as at test time); "training forward" includes them. The dense share (real ``addmm``/
``mm``/``bmm``) is printed separately: the paper's Table 6 figures (Re-Net 24.43, Pd/Re-Net with
AGTFM 90.96 MFLOPs) are far below any GoogLeNet at 224 px (~1.6 G multiply-adds per image), and of
the order of the dense layers alone.

Size is float32 parameters (4 bytes each) in MB = 10^6 bytes (MiB in brackets). Latency is the
median wall time of one pair (batch 1, eval mode, no grad) over ``--repeats`` timed runs after
``--warmup`` untimed ones, with ``--threads`` torch threads, on the CPU in fp32 unless
``--device`` / ``--precision`` say otherwise (``benchmark.models.device``). bf16 is refused as in
training on a CPU without native bf16 (``device.check_precision_supported``: a one-line usage
error) unless ``UAVBENCH_ALLOW_SLOW_BF16=1``. Head and encoder
options are set as in ``uavbench train``: ``--set attitude_options.hidden=512``
(``benchmark.models.ModelConfig``).
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

import torch
from torch import nn

from benchmark.models.bench_inputs import synthetic_labels
from benchmark.models.flop_count import count_flops_by_kind
from benchmark.models.model_config import parse_scalar
from benchmark.models.pair import PoseModel, create_model

OPTION_FIELDS = ("attitude_options", "translation_options", "encoder_options")

HELP = "parameters, size, MFLOPs and CPU latency per pair of a model (paper Table 6)"

# Paper Table 6 (for reference in the printout).
PAPER_TABLE6 = {"Re-Net": (65.60, 24.43), "Pd/Re-Net with AGTFM": (95.60, 90.96)}


@dataclass
class ModelInfo:
    head: str
    translation: str
    encoder: str
    variant: str
    width: float
    input_size: int
    parameters: int
    size_mb: float
    size_mib: float
    mflops_inference: float
    mflops_dense_inference: float
    mflops_training_forward: float
    mflops_dense_training_forward: float
    latency_ms: float
    latency_repeats: int
    threads: int
    device: str = "cpu"  # where the latency was measured
    precision: str = "fp32"
    accelerator: str = ""  # the GPU's name or the CPU model


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


def count_flops(model: PoseModel, input_size: int, training: bool = False) -> tuple[int, int]:
    """``(total, dense)`` FLOPs (2 x multiply-adds) of one pair at ``input_size`` px; dense: the
    real matrix products (``flop_count`` kind ``matmul``: the heads' and fusion's layers)."""
    was_training = model.training
    model.train(training)
    dtype = next(model.parameters()).dtype
    x = torch.rand(1, 3, input_size, input_size, dtype=dtype)
    context = synthetic_labels(1)[2]  # read by pair encoders only

    def forward() -> None:
        with torch.no_grad():
            model(x, x.clone(), context=context)

    try:
        flops = count_flops_by_kind(forward)
    finally:
        model.train(was_training)
    return flops["total"], flops["matmul"]


def measure_latency(
    model: PoseModel,
    input_size: int,
    repeats: int = 10,
    warmup: int = 3,
    device: torch.device | str = "cpu",
    precision: str = "fp32",
) -> list[float]:
    """Wall times (seconds) of ``repeats`` batch-1 forward passes plus decoding in eval mode on
    ``device`` (the model is moved there) under ``precision``'s autocast (resolved: fp32, bf16 or
    fp16). On CUDA each pass is synchronised before its clock stops (kernels run asynchronously)."""
    from benchmark.models.device import autocast, outputs_to_float

    device = torch.device(device)
    model.to(device).eval()
    uav = torch.rand(1, 3, input_size, input_size).to(device)
    sat = torch.rand(1, 3, input_size, input_size).to(device)
    context = {k: v.to(device) for k, v in synthetic_labels(1)[2].items()}  # pair encoders'

    def sync() -> None:
        if device.type == "cuda":
            torch.cuda.synchronize(device)

    times = []
    with torch.inference_mode():
        for i in range(warmup + repeats):
            sync()
            start = time.perf_counter()
            with autocast(device, precision):
                out = model(uav, sat, context=context)
            if precision != "fp32":
                out = outputs_to_float(out)
            model.decode(out)
            sync()
            if i >= warmup:
                times.append(time.perf_counter() - start)
    return times


def model_info(
    head: str = "pd_re_net",
    encoder: str = "googlenet",
    variant: str = "a-f",
    width: float = 1.0,
    input_size: int = 224,
    translation: str = "regression",
    repeats: int = 10,
    warmup: int = 3,
    options: Mapping[str, Mapping[str, Any]] | None = None,
    device: str = "cpu",
    precision: str = "fp32",
) -> ModelInfo:
    """Measure one model; ``options`` maps ``attitude_options`` / ``translation_options`` /
    ``encoder_options`` to the options of that head or encoder (``ModelConfig``). FLOPs are
    counted on the CPU; the latency is measured on ``device`` in ``precision``
    (``benchmark.models.device`` names; ``auto`` resolved). Defaults: the CPU in fp32 (Table 6)."""
    from benchmark.models.device import (
        accelerator_name,
        check_precision_supported,
        resolve_device,
        resolve_precision,
    )

    where = resolve_device(device)
    precision = resolve_precision(precision, where)
    # As training and evaluation: bf16 on a CPU without native bf16 only when allowed.
    check_precision_supported(precision, where)
    model = create_model(
        encoder=encoder,
        variant=variant,
        width=width,
        input_size=input_size,
        attitude=head,
        translation=translation,
        **{k: dict(v) for k, v in (options or {}).items()},
    )
    n_params = count_parameters(model)
    flops, dense = count_flops(model, input_size, training=False)
    flops_train, dense_train = count_flops(model, input_size, training=True)
    times = measure_latency(model, input_size, repeats, warmup, where, precision)
    return ModelInfo(
        head=head,
        translation=translation,
        encoder=encoder,
        variant=variant,
        width=width,
        input_size=input_size,
        parameters=n_params,
        size_mb=n_params * 4 / 1e6,
        size_mib=n_params * 4 / 2**20,
        mflops_inference=flops / 1e6,
        mflops_dense_inference=dense / 1e6,
        mflops_training_forward=flops_train / 1e6,
        mflops_dense_training_forward=dense_train / 1e6,
        latency_ms=1e3 * statistics.median(times),
        latency_repeats=repeats,
        threads=torch.get_num_threads(),
        device=str(where),
        precision=precision,
        accelerator=accelerator_name(where),
    )


def format_info(info: ModelInfo) -> str:
    lines = [
        f"model        {info.head} + {info.translation}, encoder {info.encoder} "
        f"variant {info.variant!r}, width {info.width:g}, {info.input_size} px",
        f"parameters   {info.parameters:,}",
        f"size         {info.size_mb:.2f} MB float32 ({info.size_mib:.2f} MiB)",
        f"MFLOPs/pair  {info.mflops_inference:.1f} inference "
        f"(dense layers {info.mflops_dense_inference:.2f}), "
        f"{info.mflops_training_forward:.1f} training forward "
        f"(dense {info.mflops_dense_training_forward:.2f}); FLOPs = 2 x multiply-adds",
        f"latency      {info.latency_ms:.1f} ms per pair (batch 1, {_where(info)}, "
        f"median of {info.latency_repeats})",
        "paper Table 6: "
        + "; ".join(f"{k} {mb:.2f} MB / {mf:.2f} MFLOPs" for k, (mb, mf) in PAPER_TABLE6.items()),
    ]
    return "\n".join(lines)


def _where(info: ModelInfo) -> str:
    if info.device == "cpu":
        where = f"CPU, {info.threads} thread(s)"
    else:
        where = f"{info.device} ({info.accelerator})"
    return where if info.precision == "fp32" else f"{where}, {info.precision} autocast"


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
        key, sep, value = item.partition("=")
        field, dot, option = key.strip().partition(".")
        if not sep or not dot or not option or field not in OPTION_FIELDS:
            raise ValueError(
                f"--set {item!r}: expected FIELD.OPTION=VALUE with FIELD one of "
                f"{', '.join(OPTION_FIELDS)}, e.g. attitude_options.hidden=512"
            )
        out.setdefault(field, {})[option] = parse_scalar(value)
    return out


def run(args: argparse.Namespace) -> int:
    from benchmark.errors import UsageError

    if args.repeats < 1 or args.warmup < 0 or args.threads < 1:
        raise UsageError(
            f"need --repeats >= 1, --warmup >= 0, --threads >= 1; got {args.repeats}, "
            f"{args.warmup}, {args.threads}"
        )
    torch.set_num_threads(args.threads)
    try:
        options = parse_options(args.options)
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
            device=args.device,
            precision=args.precision,
        )
    except ValueError as err:  # bad configuration: unknown head/encoder/variant, size, width
        raise UsageError(str(err)) from None
    print(json.dumps(asdict(info)) if args.json else format_info(info))
    return 0
