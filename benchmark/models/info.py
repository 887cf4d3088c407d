"""``uavbench model-info``: parameters, size, FLOPs and CPU latency of a pair model (paper Table 6).

FLOPs are counted by ``torch.utils.flop_counter.FlopCounterMode`` on one UAV/satellite pair at the
given input size, with the formulas of ``benchmark.models.flop_count`` (complex matrix products,
the spectra's products and bilinear sampling of the matching encoder). It counts the matrix
products and convolutions only (normalisation, activations, pooling and softmax are not counted,
as in most published FLOP figures) and reports FLOPs = 2 x multiply-adds. A pair encoder gets a
synthetic ``context`` with the quick dataset's geometry (``benchmark.models.synthetic_inputs``).
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

import statistics
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import torch
from torch import nn

from benchmark.models.device import Placement
from benchmark.models.flop_count import count_flops_by_kind
from benchmark.models.pair import PoseModel, create_model
from benchmark.models.synthetic_inputs import synthetic_labels

OPTION_FIELDS = ("attitude_options", "translation_options", "encoder_options")


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
    placement: Placement | None = None,
) -> ModelInfo:
    """Measure one model; ``options`` maps ``attitude_options`` / ``translation_options`` /
    ``encoder_options`` to the options of that head or encoder (``ModelConfig``). FLOPs are
    counted on the CPU; the latency is measured on ``placement`` (resolved and checked by the
    caller: ``device.resolve_placement``). Default: the CPU in fp32 (Table 6)."""
    from benchmark.models.device import accelerator_name

    placement = placement or Placement(torch.device("cpu"), "fp32")
    where, precision = placement.device, placement.precision
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
