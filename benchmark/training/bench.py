"""``uavbench bench train``: training throughput per precision, against a plain reference loop.

For each model (quick: 96 px, width 0.25; paper: 224 px, width 1.0; both Pd/Re-Net with AGTFM) it
times full SGD steps (forward, Algorithm 1 loss, backward, update) of

- plain: the same architecture and initial weights in the default memory format, every satellite
  image encoded (no sharing), float32: what a plain PyTorch loop would do;
- ours fp32: channels_last memory format and each distinct satellite image encoded once per batch
  (``sat_ids``), as ``benchmark.training`` trains;
- ours bf16: the same under ``torch.autocast`` bf16 (weights, optimiser state and the loss stay
  float32; the heads' outputs are cast back to float32 before the loss, as training does),

plus, once per round, one training pass (forward + both gradients) of each ceiling convolution
(``benchmark.models.bench_ceiling``) in each precision. Everything alternates step by step, so
machine load affects every column alike. It prints pairs/s, the ratio to plain and to our fp32,
the step's convolution/matmul rate and its share of the ceiling of the same precision.

FLOPs of a step are counted, not estimated: ``torch.utils.flop_counter.FlopCounterMode`` runs one
whole step (forward and backward) and counts 2 x multiply-adds of every convolution and matrix
product, including their input and weight gradients (about 3x the forward; the first convolution
computes no input gradient). Normalisation, activations, pooling and the optimiser are not counted.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch

MODELS = {"quick": (96, 0.25), "paper": (224, 1.0)}


@dataclass(frozen=True)
class LoopResult:
    """One timed loop: ``pairs_per_s`` (median step), ``step_gflop`` (counted FLOPs of a step,
    in 10^9), ``gflops`` (counted FLOPs / median step time) and ``ceiling_share`` (``gflops`` /
    the ceiling of this precision; None without a ceiling)."""

    loop: str  # "plain fp32", "ours fp32", "ours bf16"
    precision: str
    pairs_per_s: float
    step_gflop: float
    gflops: float
    ceiling_share: float | None


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="uavbench bench train", description=__doc__.split("\n")[0])
    p.add_argument("--models", default="quick,paper", help="comma list of quick,paper")
    p.add_argument("--batch-size", type=int, default=20, help="pairs per step (paper: 20)")
    p.add_argument("--distinct-sat", type=int, default=4, help="distinct satellite images/batch")
    p.add_argument("--steps", type=int, default=5, help="timed steps per loop and model")
    p.add_argument("--warmup", type=int, default=1, help="untimed steps first")
    p.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    p.add_argument("--size", type=int, help="override the image size of every model")
    p.add_argument("--width", type=float, help="override the width of every model")
    p.add_argument("--attitude", default="pd_re_net")
    p.add_argument("--variant", default="a-f")
    p.add_argument("--device", default="auto", help="auto (CUDA, else MPS, else CPU), cpu, cuda, "
                   "cuda:N or mps")  # fmt: skip
    p.add_argument("--precision", default=None, help="comma list of fp32,bf16 (default: both "
                   "where the device supports bf16, else fp32 and the reason)")  # fmt: skip
    p.add_argument("--no-plain", action="store_true", help="skip the plain reference loop")
    p.add_argument("--no-ceiling", action="store_true", help="skip the convolution ceiling")
    p.add_argument("--profile", type=int, default=0, metavar="N", help="after timing, profile "
                   "one step of each of our loops and print its N top ops (self time)")  # fmt: skip
    p.add_argument("--ceiling-batch", type=int, default=None, help="images per ceiling "
                   "convolution (default 24: 20 pairs over 4 satellite images)")  # fmt: skip
    return p


def batch_of(
    size: int, batch: int, distinct: int, device: torch.device | None = None
) -> dict[str, torch.Tensor]:
    """A random batch of ``batch`` pairs over ``distinct`` satellite images (same bytes for the
    same arguments): ``uav, sat (B, 3, size, size)`` in [0, 1], ``sat_id (B,)``, ``R (B, 3, 3)``
    rotations, ``T (B, 3)`` metres; on ``device`` (default CPU)."""
    g = torch.Generator().manual_seed(0)
    sats = torch.rand(distinct, 3, size, size, generator=g)
    sat_ids = torch.arange(batch) % distinct
    R = torch.linalg.qr(torch.randn(batch, 3, 3, generator=g)).Q
    R = R * torch.linalg.det(R).sign()[:, None, None]  # det +1
    out = {
        "uav": torch.rand(batch, 3, size, size, generator=g),
        "sat": sats[sat_ids],
        "sat_id": sat_ids,
        "R": R,
        "T": torch.randn(batch, 3, generator=g) * 50,
    }
    return {k: v.to(device) for k, v in out.items()} if device is not None else out


def make_step(
    model, optimizer, batch: dict[str, torch.Tensor], share: bool, device, precision: str
) -> Callable[[], float]:
    """A function running one SGD step of ``model`` on ``batch`` and returning its seconds
    (device synchronised before each clock reading)."""
    from benchmark.models.bench_ceiling import synchronize
    from benchmark.models.device import autocast, outputs_to_float

    def step() -> float:
        synchronize(device)
        start = time.perf_counter()
        with autocast(device, precision):
            out = model(batch["uav"], batch["sat"], batch["sat_id"] if share else None)
        if precision != "fp32":
            out = outputs_to_float(out)  # losses in float32, as training computes them
        loss = model.loss(out, batch["R"], batch["T"])["total"]
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        synchronize(device)
        return time.perf_counter() - start

    return step


def count_step_flops(step: Callable[[], float]) -> int:
    """FLOPs (2 x multiply-adds of convolutions and matrix products, forward and backward) of
    one call of ``step`` (which then also updates the weights: count before timing)."""
    from torch.utils.flop_counter import FlopCounterMode

    with FlopCounterMode(display=False) as counter:
        step()
    return int(counter.get_total_flops())


def build(size: int, width: float, args: argparse.Namespace, channels_last: bool, device):
    """The benchmarked model (seed 0: every loop starts from the same weights) and its SGD."""
    from benchmark.models import create_model

    torch.manual_seed(0)
    m = create_model(
        width=width,
        input_size=size,
        attitude=args.attitude,
        variant=args.variant,
        channels_last=channels_last,
    )
    m.translation_head.set_statistics(torch.zeros(3), torch.full((3,), 50.0))
    m = m.to(device).train()
    return m, torch.optim.SGD(m.parameters(), lr=1e-3, momentum=0.9)


def measure(
    size: int,
    width: float,
    args: argparse.Namespace,
    device: torch.device,
    precisions: Sequence[str],
) -> tuple[list[LoopResult], dict[str, float]]:
    """Time the loops of one model side by side; ``(loops, ceiling GFLOP/s per precision)``."""
    from benchmark.models.bench_ceiling import SHAPES, CeilingResult, conv_job

    batch = batch_of(size, args.batch_size, args.distinct_sat, device)
    loops: dict[str, tuple[str, Callable[[], float]]] = {}
    if not args.no_plain:
        loops["plain fp32"] = ("fp32", make_step(*build(size, width, args, False, device),
                                                 batch, False, device, "fp32"))  # fmt: skip
    for precision in precisions:
        model, opt = build(size, width, args, True, device)
        loops[f"ours {precision}"] = (
            precision,
            make_step(model, opt, batch, True, device, precision),
        )
    flops = {name: count_step_flops(step) for name, (_, step) in loops.items()}
    convs: dict[tuple[str, str], tuple[Callable[[], float], int]] = {}
    if not args.no_ceiling:
        for precision in precisions:
            for shape_name, shape in SHAPES.items():
                convs[precision, shape_name] = conv_job(shape, device, precision,
                                                        args.ceiling_batch)  # fmt: skip
    jobs = {**{k: v[1] for k, v in loops.items()}, **{k: v[0] for k, v in convs.items()}}
    for _ in range(args.warmup + 1):  # +1: the conv jobs' first run picks kernels
        for run in jobs.values():
            run()
    times: dict[object, list[float]] = {key: [] for key in jobs}
    for _ in range(args.steps):  # round robin: load affects every loop alike
        for key, run in jobs.items():
            times[key].append(run())
    ceilings = {}
    for precision in precisions if convs else ():
        rates = {
            shape: convs[precision, shape][1] / statistics.median(times[precision, shape]) / 1e9
            for shape in SHAPES
        }
        ceilings[precision] = CeilingResult.of(precision, rates).gflops
    results = []
    for name, (precision, _) in loops.items():
        seconds = statistics.median(times[name])
        gflops = flops[name] / seconds / 1e9
        share = gflops / ceilings[precision] if precision in ceilings else None
        results.append(
            LoopResult(name, precision, args.batch_size / seconds, flops[name] / 1e9, gflops, share)
        )
    if getattr(args, "profile", 0):
        for name, (_, step) in loops.items():
            if name.startswith("ours"):
                print(f"profile of one step, {size} px width {width:g}, {name}:")
                print(profile_step(step, args.profile))
    return results, ceilings


def profile_step(step: Callable[[], float], rows: int) -> str:
    """``torch.profiler``'s table of one call of ``step``: the ``rows`` ops of most self time
    (on CUDA the device's time too)."""
    from torch.profiler import ProfilerActivity, profile

    activities = [ProfilerActivity.CPU]
    if torch.cuda.is_available():
        activities.append(ProfilerActivity.CUDA)
    with profile(activities=activities) as prof:
        step()
    key = "self_cuda_time_total" if len(activities) > 1 else "self_cpu_time_total"
    return prof.key_averages().table(sort_by=key, row_limit=rows)


def check_args(args: argparse.Namespace) -> list[str]:
    """The model names of ``--models``; UsageError naming the bad flag otherwise."""
    from benchmark.errors import UsageError

    names = [m.strip() for m in args.models.split(",") if m.strip()]
    unknown = [m for m in names if m not in MODELS]
    if unknown or not names:
        raise UsageError(f"--models {args.models!r}: expected a comma list of {sorted(MODELS)}")
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
    return names


def resolve(args: argparse.Namespace) -> tuple[torch.device, list[str], list[str]]:
    """``(device, precisions, notes)`` of ``--device`` / ``--precision`` (UsageError if bad)."""
    from benchmark.errors import UsageError
    from benchmark.models.device import resolve_device
    from benchmark.models.precision_support import precision_plan

    try:
        device = resolve_device(args.device)
        precisions, notes = precision_plan(device, args.precision)
    except ValueError as error:
        raise UsageError(str(error)) from None
    return device, precisions, notes


def format_rows(name: str, size: int, width: float, results: list[LoopResult]) -> list[str]:
    """One line per loop: pairs/s, x plain, x our fp32, GFLOP/s, % of the ceiling."""
    by = {r.loop: r for r in results}
    plain, fp32 = by.get("plain fp32"), by.get("ours fp32")
    rows = []
    for r in results:
        vs_plain = f"{r.pairs_per_s / plain.pairs_per_s:7.2f}x" if plain else f"{'-':>8s}"
        ours = r.loop.startswith("ours") and fp32
        vs_fp32 = f"{r.pairs_per_s / fp32.pairs_per_s:7.2f}x" if ours else f"{'-':>8s}"
        share = f"{100 * r.ceiling_share:8.0f}%" if r.ceiling_share is not None else f"{'-':>9s}"
        rows.append(
            f"{name:7s} {size:4d} {width:5.2f} {r.loop:11s} {r.pairs_per_s:8.2f} {vs_plain} "
            f"{vs_fp32} {r.step_gflop:10.3f} {r.gflops:8.2f} {share}"
        )
    return rows


HEADER = (
    f"{'model':7s} {'px':>4s} {'width':>5s} {'loop':11s} {'pairs/s':>8s} {'x plain':>8s} "
    f"{'x fp32':>8s} {'GFLOP/step':>10s} {'GFLOP/s':>8s} {'%ceiling':>9s}"
)


def load_text() -> str:
    """The 1/5/15-minute load averages (runnable processes; compare to the core count)."""
    try:
        loads = " ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        return "load unknown"
    return f"load {loads} on {os.cpu_count()} cores"


def main(argv: Sequence[str]) -> int:
    from benchmark.models.device import accelerator_name

    args = parser().parse_args(list(argv))
    names = check_args(args)
    device, precisions, notes = resolve(args)
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    print(
        f"bench train: {args.attitude} ({args.variant}), batch {args.batch_size} with "
        f"{args.distinct_sat} distinct satellite images, {args.steps} timed steps, device "
        f"{device} ({accelerator_name(device)}), {torch.get_num_threads()} torch threads; "
        f"{load_text()}"
    )
    for note in notes:
        print(note)
    print(HEADER)
    for name in names:
        size, width = MODELS[name]
        size, width = args.size or size, args.width or width
        results, ceilings = measure(size, width, args, device, precisions)
        print("\n".join(format_rows(name, size, width, results)), flush=True)
        for precision, gflops in ceilings.items():
            print(f"{'':7s} conv ceiling {precision}: {gflops:.1f} GFLOP/s (best of "
                  "bench_ceiling.SHAPES, timed in the same rounds)")  # fmt: skip
    print(f"end: {load_text()}")
    return 0
