"""``uavbench bench train``: training throughput per precision, against a plain reference loop.

For each model (quick: 96 px, width 0.25; paper: 224 px, width 1.0; Pd/Re-Net) and each encoder of
``--encoders`` (default both, side by side in the same rounds: ``googlenet``, the paper's Siamese
GoogLeNet with AGTFM, ``--variant``; ``matching``, issue 21's matching encoder with its default
options, variant ``/``, the width ignored; ``matching_alt3`` on request, the same with three
altitude hypotheses, ``altitude_offsets_m`` -12/0/+12 m) it times full training steps (forward,
Algorithm 1 loss plus the encoder's own loss, backward, optimiser update) of

- plain: the same architecture and initial weights in the default memory format, every satellite
  image encoded (no sharing), float32: what a plain PyTorch loop would do;
- ours fp32: channels_last memory format and each distinct satellite image encoded once per batch
  (``sat_ids``), as ``benchmark.training`` trains;
- ours bf16: the same under ``torch.autocast`` bf16 (weights, optimiser state and the loss stay
  float32; the heads' outputs are cast back to float32 before the loss, as training does),
- base fp32: ours fp32 before the encoder's last speed change, side by side: for the matching
  encoders, the correlation before issue 40 (the 2-D DFT by complex matrix products,
  ``correlation="dft"``; ours is ``"xdft"``); for GoogLeNet (CPU, ``--optimizer adam``) before
  issue 20, the optimiser's per-tensor Python loop (torch's CPU default) instead of
  ``make_optimizer``'s ``foreach`` (same weights bit for bit; ``loop.CPU_FOREACH``),

plus, once per round, one training pass (forward + both gradients) of each ceiling convolution
(``benchmark.bench.ceiling``) in each precision. Everything alternates step by step (both encoders'
loops too), so machine load affects every column alike. It reports (returns, for the command to
print) pairs/s, the ratio to plain and to our fp32, the step's counted rate and its share of the
convolution ceiling of the same precision; per model, the matching encoder beside GoogLeNet (pairs/s
and FLOPs per step, loop by loop; ``matching_alt3`` beside ``matching``) and each encoder's FLOPs by
kind; with bf16 beside fp32, a table of bf16/fp32 and bf16/plain per model and encoder (the issue's
layout). On the CPU a line says whether bf16 is native (``avx512_bf16`` / ``amx_bf16``) and which
ISA and kernels ran a training convolution in each precision (``ceiling.cpu_bf16_line``).

The batch (``batch_of``): random pixels, labels and ``context`` with the quick dataset's geometry
(``benchmark.models.synthetic_inputs``: the matching encoder's templates land as on real pairs).
The optimiser is the paper's SGD with momentum (lr 1e-3, as the issue measured) or, with
``--optimizer adam``, the quick profile's Adam (lr 3e-4, gradient norm clipped at 10), both built by
``make_optimizer`` as training builds them. ``--profile N`` adds, per "ours" loop, where one step's
time goes by kind of work (``train_breakdown``) and torch.profiler's N top ops.

FLOPs of a step are counted, not estimated: ``torch.utils.flop_counter.FlopCounterMode`` runs one
whole step (forward and backward) and counts 2 x multiply-adds of every convolution and matrix
product, including their input and weight gradients (about 3x the forward; the first convolution
computes no input gradient), with ``benchmark.models.flop_count``'s formulas for what torch
miscounts or skips: complex matrix products (the base matcher's 2-D DFT correlation: 8 real
FLOPs per complex multiply-add, not 2; kind ``dft``), the spectra's complex elementwise products,
and bilinear ``grid_sample`` (the bird's-eye templates and the satellite grid). The default
correlation's real GEMMs (``correlate_xdft``) count as ``matmul``. Normalisation, activations,
pooling, softmax, the losses and the optimiser are not counted (FFTs neither). The share of the
convolution ceiling compares every counted FLOP (complex GEMMs included) with the best training
convolution's rate.
"""

from __future__ import annotations

import os
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import torch

if TYPE_CHECKING:
    from benchmark.models import PoseModel
    from benchmark.training.config import OptimConfig

MODELS = {"quick": (96, 0.25), "paper": (224, 1.0)}
# --encoders: a bench name -> (registry name, encoder options). ``matching_alt3`` is the matching
# encoder with three altitude hypotheses 12 m apart (``altitude_offsets_m``, off by default; the
# setting measured in DEVELOPERS, issue 21 stop 34): timed beside ``matching`` it shows what the
# scale dimension costs a training step.
BENCH_ENCODERS: dict[str, tuple[str, dict[str, Any]]] = {
    "googlenet": ("googlenet", {}),
    "matching": ("matching", {}),
    "matching_alt3": ("matching", {"altitude_offsets_m": (-12.0, 0.0, 12.0)}),
}
ENCODERS = ("googlenet", "matching")  # the default: the two registered encoders as they are
ENCODER_COLUMN = max(map(len, BENCH_ENCODERS))
# --optimizer: OptimConfig fields (benchmark.training.config); "adam" is the quick profile's
# (benchmark.runner.plan.repro_profiles, which training may not import), "sgd" the
# paper's (Sec. 3.3).
OPTIMIZERS: dict[str, dict[str, object]] = {
    "sgd": {"name": "sgd", "lr": 1e-3, "momentum": 0.9},
    "adam": {"name": "adam", "lr": 3e-4, "grad_clip": 10.0},
}


@dataclass(frozen=True)
class LoopSpec:
    """One timed loop: ``channels_last`` and ``share`` (encode each distinct satellite image
    once) as our model runs, ``foreach`` the optimiser's (None: ``make_optimizer``'s choice,
    False: torch's per-tensor loop, the plain/base setting)."""

    name: str
    precision: str
    channels_last: bool
    share: bool
    foreach: bool | None
    # encoder options over the bench encoder's own (the matcher's base row: its correlation)
    encoder_options: tuple[tuple[str, Any], ...] = ()


# The base row of each encoder, the code before the change it measures: GoogLeNet before issue 20
# (torch's per-tensor optimiser loop; only where make_optimizer chooses otherwise), the matching
# encoder before issue 40 (the 2-D DFT correlation by complex matrix products).
MATCHER_BASE_OPTIONS: tuple[tuple[str, Any], ...] = (("correlation", "dft"),)
BASE_CHANGES = {
    "googlenet": "optimiser foreach, issue 20",
    "matching": "correlation by row DFT and one GEMM, issue 40",
}


def loop_specs(
    precisions: Sequence[str],
    device: torch.device,
    plain: bool,
    base: bool,
    optimizer: str = "sgd",
    encoder: str = "googlenet",
) -> list[LoopSpec]:
    """The loops of one encoder (a :data:`BENCH_ENCODERS` name), in print order: plain fp32,
    base fp32, ours in each precision. Plain uses torch's default optimiser loop. Base is
    ``encoder``'s code before its last speed change: for the matching encoders the correlation
    before issue 40 (:data:`MATCHER_BASE_OPTIONS`, always); for GoogLeNet torch's default
    optimiser loop, only where ``make_optimizer`` chooses otherwise (on the CPU for Adam:
    ``loop.CPU_FOREACH``)."""
    from benchmark.training.loop import CPU_FOREACH

    default = False if device.type == "cpu" else None  # torch's own default on that device
    specs = [LoopSpec("plain fp32", "fp32", False, False, default)] if plain else []
    if base and "fp32" in precisions:
        if BENCH_ENCODERS[encoder][0] == "matching":
            specs.append(LoopSpec("base fp32", "fp32", True, True, None, MATCHER_BASE_OPTIONS))
        elif device.type == "cpu" and CPU_FOREACH.get(OPTIMIZERS[optimizer]["name"]) is True:
            specs.append(LoopSpec("base fp32", "fp32", True, True, False))
    specs += [LoopSpec(f"ours {p}", p, True, True, None) for p in precisions]
    return specs


@dataclass(frozen=True)
class LoopResult:
    """One timed loop: ``pairs_per_s`` (median step), ``step_gflop`` (counted FLOPs of a step,
    in 10^9), ``gflops`` (counted FLOPs / median step time) and ``ceiling_share`` (``gflops`` /
    the ceiling of this precision; None without a ceiling); ``encoder`` the encoder's registry
    name and ``gflop_by_kind`` the step's counted FLOPs per ``flop_count.KINDS`` (10^9)."""

    loop: str  # "plain fp32", "base fp32", "ours fp32", "ours bf16"
    precision: str
    pairs_per_s: float
    step_gflop: float
    gflops: float
    ceiling_share: float | None
    encoder: str = "googlenet"
    gflop_by_kind: dict[str, float] = field(default_factory=dict)  # flop_count.KINDS, 10^9


@dataclass(frozen=True)
class TrainBenchConfig:
    """``bench train``: the ``models`` (names of :data:`MODELS`) and ``encoders`` timed side by
    side; ``batch_size`` pairs over ``distinct_sat`` satellite images; ``steps`` timed steps after
    ``warmup``; ``threads`` torch threads (None: torch's); ``size``/``width`` override every
    model's; the ``attitude`` head, GoogLeNet's ``variant``; ``device`` and ``precision`` (comma
    list; None: fp32 and bf16 where supported) by name, resolved by :func:`resolve`; which loops
    (``plain``, ``base``) and the ``ceiling`` run; the ``optimizer`` (:data:`OPTIMIZERS`);
    ``profile`` top ops per loop (0: none); ``ceiling_batch`` images per ceiling convolution
    (None: 24)."""

    models: tuple[str, ...] = ("quick", "paper")
    encoders: tuple[str, ...] = ENCODERS
    batch_size: int = 20
    distinct_sat: int = 4
    steps: int = 5
    warmup: int = 1
    threads: int | None = None
    size: int | None = None
    width: float | None = None
    attitude: str = "pd_re_net"
    variant: str = "a-f"
    device: str = "auto"
    precision: str | None = None
    plain: bool = True
    base: bool = True
    optimizer: str = "sgd"
    ceiling: bool = True
    profile: int = 0
    ceiling_batch: int | None = None


def batch_of(
    size: int, batch: int, distinct: int, device: torch.device | None = None
) -> dict[str, Any]:
    """A random batch of ``batch`` pairs over ``distinct`` satellite images (same bytes for the
    same arguments): ``uav, sat (B, 3, size, size)`` in [0, 1], ``sat_id (B,)``, labels
    ``R (B, 3, 3)`` and ``T (B, 3)`` metres and the ``context`` dict (a pair encoder's geometry),
    drawn from the quick dataset's ranges (``synthetic_inputs.synthetic_labels``); on ``device``
    (default CPU)."""
    from benchmark.models.synthetic_inputs import synthetic_labels

    g = torch.Generator().manual_seed(0)
    sats = torch.rand(distinct, 3, size, size, generator=g)
    sat_ids = torch.arange(batch) % distinct
    uav = torch.rand(batch, 3, size, size, generator=g)
    R, T, context = synthetic_labels(batch, g)
    out = {"uav": uav, "sat": sats[sat_ids], "sat_id": sat_ids, "R": R, "T": T}
    if device is not None:
        out = {k: v.to(device) for k, v in out.items()}
        context = {k: v.to(device) for k, v in context.items()}
    return {**out, "context": context}


def make_step(
    model: torch.nn.Module,
    optimizer: torch.optim.Optimizer,
    batch: dict[str, torch.Tensor],
    share: bool,
    device: torch.device,
    precision: str,
    grad_clip: float | None = None,
) -> Callable[[], float]:
    """A function running one optimiser step of ``model`` on ``batch`` (gradient norm clipped at
    ``grad_clip`` first, as training does) and returning its seconds (device synchronised before
    each clock reading)."""
    from benchmark.bench.ceiling import synchronize
    from benchmark.bench.train_breakdown import CLIP_LABEL
    from benchmark.models.device import autocast, outputs_to_float

    def step() -> float:
        synchronize(device)
        start = time.perf_counter()
        with autocast(device, precision):
            out = model(
                batch["uav"], batch["sat"], batch["sat_id"] if share else None,
                context=batch["context"],
            )  # fmt: skip
        if precision != "fp32":
            out = outputs_to_float(out)  # losses in float32, as training computes them
        loss = model.loss(out, batch["R"], batch["T"])["total"]
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if grad_clip is not None:
            with torch.profiler.record_function(CLIP_LABEL):  # "optimizer" in the breakdown
                torch.nn.utils.clip_grad_norm_(model.parameters(), grad_clip)
        optimizer.step()
        synchronize(device)
        return time.perf_counter() - start

    return step


def step_flops(step: Callable[[], float]) -> dict[str, int]:
    """FLOPs (2 x multiply-adds, forward and backward) of one call of ``step`` (which then also
    updates the weights: count before timing): ``total`` and each kind of
    ``benchmark.models.flop_count.KINDS``: ``convolution`` (forward and both gradients),
    ``matmul`` (real mm, addmm, bmm, ...: the dense layers), ``dft`` (complex matrix products),
    ``spectrum`` (complex elementwise products) and ``sampling`` (``grid_sample``)."""
    from benchmark.models.flop_count import count_flops_by_kind

    return count_flops_by_kind(step)


def count_step_flops(step: Callable[[], float]) -> int:
    """FLOPs (2 x multiply-adds of convolutions and matrix products, forward and backward) of
    one call of ``step`` (which then also updates the weights: count before timing)."""
    return step_flops(step)["total"]


def optim_config(config: TrainBenchConfig) -> OptimConfig:
    """The ``OptimConfig`` of ``config.optimizer`` (batch size ``config.batch_size``)."""
    from benchmark.training.config import OptimConfig

    return OptimConfig(**OPTIMIZERS[config.optimizer], batch_size=config.batch_size)  # type: ignore[arg-type]


def build(
    size: int,
    width: float,
    config: TrainBenchConfig,
    spec: LoopSpec,
    device: torch.device,
    encoder: str = "googlenet",
) -> tuple[PoseModel, torch.optim.Optimizer]:
    """The benchmarked model (seed 0: every loop of an encoder starts from the same weights) and
    its optimiser, built by training's ``make_optimizer`` (``spec.foreach``). ``encoder`` is a
    name of :data:`BENCH_ENCODERS` (its registry name and options). GoogLeNet takes
    ``config.variant``; the matching encoder has one level (variant ``/``)."""
    from benchmark.models import create_model
    from benchmark.training.config import TrainConfig
    from benchmark.training.loop import make_optimizer

    registered, options = BENCH_ENCODERS[encoder]
    torch.manual_seed(0)
    m = create_model(
        encoder=registered,
        encoder_options={**options, **dict(spec.encoder_options)},
        width=width,
        input_size=size,
        attitude=config.attitude,
        variant=config.variant if registered == "googlenet" else "/",
        channels_last=spec.channels_last,
    )
    m.translation_head.set_statistics(torch.zeros(3), torch.full((3,), 50.0))
    m = m.to(device).train()
    cfg = TrainConfig(optim=optim_config(config))
    return m, make_optimizer(cfg, m, foreach=spec.foreach)


@dataclass(frozen=True)
class StepProfile:
    """One profiled step of an "ours" loop (``config.profile``): the ``encoder``'s ``loop`` at
    ``size`` px and ``width``, its time by kind of work (``breakdown``,
    ``train_breakdown.breakdown_line``) and torch.profiler's top ops (``table``)."""

    size: int
    width: float
    encoder: str
    loop: str
    breakdown: str
    table: str

    def lines(self) -> list[str]:
        """The heading, the breakdown line and the op table."""
        return [
            f"profile of one step, {self.size} px width {self.width:g}, {self.encoder} "
            f"{self.loop}:",
            self.breakdown,
            *self.table.splitlines(),
        ]


def measure_profiled(
    size: int,
    width: float,
    config: TrainBenchConfig,
    device: torch.device,
    precisions: Sequence[str],
    encoders: Sequence[str] = ("googlenet",),
) -> tuple[list[LoopResult], dict[str, float], list[StepProfile]]:
    """Time the loops of one model side by side, every encoder's in the same rounds, then
    (``config.profile`` > 0) profile one step of each "ours" loop; ``(loops, ceiling GFLOP/s per
    precision, profiles)``."""
    from benchmark.bench.ceiling import SHAPES, CeilingResult, conv_job
    from benchmark.models.flop_count import KINDS

    batch = batch_of(size, config.batch_size, config.distinct_sat, device)
    clip = optim_config(config).grad_clip
    loops: dict[tuple[str, str], tuple[str, Callable[[], float]]] = {}
    for encoder in encoders:
        specs = loop_specs(precisions, device, config.plain, config.base, config.optimizer,
                           encoder)  # fmt: skip
        for spec in specs:
            model, opt = build(size, width, config, spec, device, encoder)
            step = make_step(model, opt, batch, spec.share, device, spec.precision, clip)
            loops[encoder, spec.name] = (spec.precision, step)
    flops = {key: step_flops(step) for key, (_, step) in loops.items()}
    convs: dict[tuple[str, str], tuple[Callable[[], float], int]] = {}
    if config.ceiling:
        for precision in precisions:
            for shape_name, shape in SHAPES.items():
                convs[precision, shape_name] = conv_job(shape, device, precision,
                                                        config.ceiling_batch)  # fmt: skip
    jobs = {**{k: v[1] for k, v in loops.items()}, **{("conv", *k): v[0] for k, v in convs.items()}}
    for _ in range(config.warmup + 1):  # +1: the conv jobs' first run picks kernels
        for run in jobs.values():
            run()
    times: dict[tuple[str, ...], list[float]] = {key: [] for key in jobs}
    for _ in range(config.steps):  # round robin: load affects every loop alike
        for key, run in jobs.items():
            times[key].append(run())
    ceilings = {}
    for precision in precisions if convs else ():
        rates = {
            shape: convs[precision, shape][1]
            / statistics.median(times["conv", precision, shape])
            / 1e9
            for shape in SHAPES
        }
        ceilings[precision] = CeilingResult.of(precision, rates).gflops
    results = []
    for (encoder, name), (precision, _) in loops.items():
        seconds = statistics.median(times[encoder, name])
        total = flops[encoder, name]["total"]
        gflops = total / seconds / 1e9
        share = gflops / ceilings[precision] if precision in ceilings else None
        kinds = {k: flops[encoder, name][k] / 1e9 for k in KINDS}
        results.append(LoopResult(name, precision, config.batch_size / seconds, total / 1e9,
                                  gflops, share, encoder, kinds))  # fmt: skip
    profiles = []
    if config.profile:
        from benchmark.bench.train_breakdown import breakdown_line, profile_step

        for (encoder, name), (precision, step) in loops.items():
            if name.startswith("ours"):
                table, kinds = profile_step(step, config.profile)
                line = breakdown_line(kinds, flops[encoder, name], ceilings.get(precision))
                profiles.append(StepProfile(size, width, encoder, name, line, table))
    return results, ceilings, profiles


def resolve(
    device_name: str = "auto", precision: str | None = None
) -> tuple[torch.device, list[str], list[str]]:
    """``(device, precisions, notes)`` of ``--device`` / ``--precision`` (``precision``: a comma
    list; InputError if bad).

    The bench measures bf16 by default wherever oneDNN has bf16 kernels, and anywhere on an
    explicit ``--precision`` (measuring how slow it is is its job); training and ``model-info``
    refuse bf16 on a CPU without native bf16 (``device.check_precision_supported``). Where the two
    differ a note says so, with training's reason and its way out."""
    from benchmark.errors import InputError
    from benchmark.models.device import resolve_device
    from benchmark.models.precision_support import (
        ALLOW_SLOW_BF16_ENV,
        bf16_unsupported_reason,
        precision_plan,
        slow_bf16_allowed,
    )

    try:
        device = resolve_device(device_name)
        precisions, notes = precision_plan(device, precision)
    except ValueError as error:
        raise InputError(str(error)) from None
    if "bf16" in precisions and device.type == "cpu" and not slow_bf16_allowed():
        reason = bf16_unsupported_reason(device, native=True)
        if reason is not None:
            notes.append(
                f"bf16 is measured for comparison only: training and model-info refuse "
                f"precision=bf16 here unless {ALLOW_SLOW_BF16_ENV}=1 ({reason})"
            )
    return device, precisions, notes


def format_rows(name: str, size: int, width: float, results: list[LoopResult]) -> list[str]:
    """One line per loop: encoder, pairs/s, x plain and x our fp32 (of the same encoder),
    GFLOP/step, GFLOP/s, % of the ceiling. The matching encoder ignores the width (``-``)."""
    by = {(r.encoder, r.loop): r for r in results}
    rows = []
    for r in results:
        plain, fp32 = by.get((r.encoder, "plain fp32")), by.get((r.encoder, "ours fp32"))
        vs_plain = f"{r.pairs_per_s / plain.pairs_per_s:7.2f}x" if plain else f"{'-':>8s}"
        ours = r.loop.startswith(("ours", "base")) and fp32
        vs_fp32 = f"{r.pairs_per_s / fp32.pairs_per_s:7.2f}x" if ours else f"{'-':>8s}"
        share = f"{100 * r.ceiling_share:8.0f}%" if r.ceiling_share is not None else f"{'-':>9s}"
        w = f"{width:5.2f}" if r.encoder == "googlenet" else f"{'-':>5s}"
        rows.append(
            f"{name:7s} {r.encoder:{ENCODER_COLUMN}s} {size:4d} {w} {r.loop:11s} "
            f"{r.pairs_per_s:8.2f} {vs_plain} {vs_fp32} {r.step_gflop:10.3f} {r.gflops:8.2f} "
            f"{share}"
        )
    return rows


def change_line(name: str, results: list[LoopResult], encoder: str = "googlenet") -> str | None:
    """Before/after of the change the base row measures (base fp32 -> ours fp32,
    :data:`BASE_CHANGES`) for ``encoder``: pairs/s and share of the ceiling; None without both
    rows."""
    by = {r.loop: r for r in results if r.encoder == encoder}
    base, ours = by.get("base fp32"), by.get("ours fp32")
    if base is None or ours is None:
        return None
    shares = ""
    if base.ceiling_share is not None and ours.ceiling_share is not None:
        shares = f", {100 * base.ceiling_share:.0f}% -> {100 * ours.ceiling_share:.0f}% of ceiling"
    return (
        f"{'':7s} {encoder}: before -> after (base fp32 -> ours fp32: "
        f"{BASE_CHANGES[BENCH_ENCODERS[encoder][0]]}): "
        f"{base.pairs_per_s:.2f} -> {ours.pairs_per_s:.2f} pairs/s "
        f"({ours.pairs_per_s / base.pairs_per_s:.2f}x{shares})"
    )


def encoder_line(
    name: str, results: list[LoopResult], encoder: str = "matching", other: str = "googlenet"
) -> str | None:
    """``encoder`` beside ``other`` (bench names), loop by loop (same rounds): ratio of pairs/s
    and of counted FLOPs per step; None without both encoders."""
    by = {(r.encoder, r.loop): r for r in results}
    parts = []
    for r in results:
        reference = by.get((other, r.loop))
        if r.encoder == encoder and reference is not None:
            parts.append(
                f"{r.loop} {r.pairs_per_s / reference.pairs_per_s:.2f}x pairs/s, "
                f"{r.step_gflop / reference.step_gflop:.2f}x GFLOP/step"
            )
    if not parts:
        return None
    return f"{'':7s} {encoder} / {other} (same rounds): " + "; ".join(parts)


def kinds_line(result: LoopResult) -> str:
    """The counted GFLOP of one step by kind (``flop_count.KINDS``), kinds with none left out."""
    kinds = ", ".join(f"{k} {v:.3f}" for k, v in result.gflop_by_kind.items() if v > 0)
    return f"{'':7s} {result.encoder} {result.loop}: GFLOP/step by kind: {kinds or 'none'}"


def bf16_table(rows: list[tuple[str, list[LoopResult]]]) -> list[str]:
    """bf16 beside fp32 per model and encoder (the issue's layout): fp32 and bf16 pairs/s (ours),
    bf16/fp32, bf16/plain; empty when no model has both."""
    lines = []
    for name, results in rows:
        for encoder in dict.fromkeys(r.encoder for r in results):
            by = {r.loop: r for r in results if r.encoder == encoder}
            fp32, bf16, plain = by.get("ours fp32"), by.get("ours bf16"), by.get("plain fp32")
            if fp32 is None or bf16 is None:
                continue
            vs_plain = f"{bf16.pairs_per_s / plain.pairs_per_s:9.2f}x" if plain else f"{'-':>10s}"
            lines.append(
                f"{name:7s} {encoder:{ENCODER_COLUMN}s} {fp32.pairs_per_s:12.2f} "
                f"{bf16.pairs_per_s:12.2f} {bf16.pairs_per_s / fp32.pairs_per_s:9.2f}x {vs_plain}"
            )
    if not lines:
        return []
    head = f"{'model':7s} {'encoder':{ENCODER_COLUMN}s} {'fp32 pairs/s':>12s} "
    head += f"{'bf16 pairs/s':>12s} {'bf16/fp32':>10s} {'bf16/plain':>10s}"
    return ["bf16 beside fp32 (ours, same rounds):", head, *lines]


HEADER = (
    f"{'model':7s} {'encoder':{ENCODER_COLUMN}s} {'px':>4s} {'width':>5s} {'loop':11s} "
    f"{'pairs/s':>8s} {'x plain':>8s} {'x fp32':>8s} {'GFLOP/step':>10s} {'GFLOP/s':>8s} "
    f"{'%ceiling':>9s}"
)


def load_text() -> str:
    """The 1/5/15-minute load averages (runnable processes; compare to the core count)."""
    try:
        loads = " ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        return "load unknown"
    return f"load {loads} on {os.cpu_count()} cores"


@dataclass(frozen=True)
class ModelRows:
    """One model of :func:`bench_train`: its ``name`` (:data:`MODELS`) at ``size`` px and
    ``width``, every timed loop (``loops``), the convolution ceilings timed in the same rounds
    (GFLOP/s per precision) and the profiled steps (``config.profile``)."""

    name: str
    size: int
    width: float
    loops: tuple[LoopResult, ...]
    ceilings: dict[str, float]
    profiles: tuple[StepProfile, ...] = ()

    def lines(self, encoders: Sequence[str], first_precision: str) -> list[str]:
        """The profiles, one row per loop, the ceilings, then the before/after, encoder and
        FLOPs-by-kind lines (``encoders`` as timed; kinds of the ``first_precision`` loops)."""
        results = list(self.loops)
        lines = [line for profile in self.profiles for line in profile.lines()]
        lines += format_rows(self.name, self.size, self.width, results)
        lines += [
            f"{'':7s} conv ceiling {precision}: {gflops:.1f} GFLOP/s (best of ceiling.SHAPES, "
            "timed in the same rounds)"
            for precision, gflops in self.ceilings.items()
        ]
        more = [change_line(self.name, results, encoder) for encoder in encoders]
        more += [encoder_line(self.name, results)]
        more += [encoder_line(self.name, results, e, "matching") for e in encoders
                 if e.startswith("matching_")]  # fmt: skip
        more += [kinds_line(r) for r in results if r.loop == f"ours {first_precision}"]
        return lines + [line for line in more if line]


@dataclass(frozen=True)
class TrainBenchResult:
    """What :func:`bench_train` measured on ``device`` in ``precisions`` for ``encoders``: one
    :class:`ModelRows` per model; ``notes`` of the precision plan (also in the opening lines) and
    the load averages when it ended (``end_load``, :func:`load_text`)."""

    device: torch.device
    precisions: tuple[str, ...]
    encoders: tuple[str, ...]
    notes: tuple[str, ...]
    models: tuple[ModelRows, ...]
    end_load: str

    def lines(self) -> list[str]:
        """The table: the column heading, each model's lines, the bf16 table and the end load."""
        lines = [HEADER]
        for model in self.models:
            lines += model.lines(self.encoders, self.precisions[0])
        lines += bf16_table([(m.name, list(m.loops)) for m in self.models])
        return [*lines, f"end: {self.end_load}"]


def bench_train(config: TrainBenchConfig) -> TrainBenchResult:
    """Time every model of ``config``; returns the rows, ceilings and profiles. The opening lines
    (the configuration, the device's bf16 support and the precision notes) go to
    :func:`benchmark.progress.status` before the minutes of timing. InputError: a device or
    precision this machine lacks."""
    from benchmark.bench.ceiling import cpu_bf16_line
    from benchmark.models.device import accelerator_name
    from benchmark.models.precision_support import bf16_support_label
    from benchmark.progress import status

    names, encoders = config.models, config.encoders
    device, precisions, notes = resolve(config.device, config.precision)
    if config.threads is not None:
        torch.set_num_threads(config.threads)
    status(
        f"bench train: {config.attitude} on {', '.join(encoders)} (googlenet variant "
        f"{config.variant}), batch {config.batch_size} with "
        f"{config.distinct_sat} distinct satellite images, {config.steps} timed steps, optimizer "
        f"{config.optimizer}, device {device} ({accelerator_name(device)}), "
        f"{torch.get_num_threads()} torch threads; {load_text()}"
    )
    if device.type == "cpu":
        status(cpu_bf16_line(("fp32", "bf16")))
    else:
        status(f"bf16 on {device}: {bf16_support_label(device)}")
    for note in notes:
        status(note)
    measured = []
    for name in names:
        size, width = MODELS[name]
        size, width = config.size or size, config.width or width
        results, ceilings, profiles = measure_profiled(size, width, config, device, precisions,
                                                       encoders)  # fmt: skip
        measured.append(ModelRows(name, size, width, tuple(results), ceilings, tuple(profiles)))
    return TrainBenchResult(device, tuple(precisions), tuple(encoders), tuple(notes),
                            tuple(measured), load_text())  # fmt: skip
