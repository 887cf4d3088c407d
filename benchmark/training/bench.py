"""``uavbench bench train``: training throughput, ours against a plain reference loop.

For each model (quick: 96 px, width 0.25; paper: 224 px, width 1.0; both Pd/Re-Net with AGTFM) it
times full SGD steps (forward, Algorithm 1 loss, backward, update) of

- ours: channels_last memory format and each distinct satellite image encoded once per batch
  (``sat_ids``), as ``benchmark.training`` trains;
- reference: the same architecture and initial weights in the default memory format, every
  satellite image encoded (no sharing): what a plain PyTorch loop would do,

alternating the two step by step (so machine load affects both alike), and prints pairs/s and the
ratio. Batches hold ``--distinct-sat`` different satellite images, as a shuffled batch of the
dataset does (a few dozen satellite images serve thousands of pairs).
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Sequence

import torch

MODELS = {"quick": (96, 0.25), "paper": (224, 1.0)}


def _parser() -> argparse.ArgumentParser:
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
    return p


def _batch(size: int, batch: int, distinct: int) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(0)
    sats = torch.rand(distinct, 3, size, size, generator=g)
    sat_ids = torch.arange(batch) % distinct
    R = torch.linalg.qr(torch.randn(batch, 3, 3, generator=g)).Q
    R = R * torch.linalg.det(R).sign()[:, None, None]  # det +1
    return {
        "uav": torch.rand(batch, 3, size, size, generator=g),
        "sat": sats[sat_ids],
        "sat_id": sat_ids,
        "R": R,
        "T": torch.randn(batch, 3, generator=g) * 50,
    }


def _step(model, optimizer, batch, share: bool) -> float:
    start = time.perf_counter()
    out = model(batch["uav"], batch["sat"], batch["sat_id"] if share else None)
    loss = model.loss(out, batch["R"], batch["T"])["total"]
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    optimizer.step()
    return time.perf_counter() - start


def measure(size: int, width: float, args: argparse.Namespace) -> tuple[float, float]:
    """Median pairs/s of (ours, reference) for one model."""
    from benchmark.models import create_model

    def build(channels_last: bool):
        torch.manual_seed(0)
        m = create_model(
            width=width,
            input_size=size,
            attitude=args.attitude,
            variant=args.variant,
            channels_last=channels_last,
        )
        m.translation_head.set_statistics(torch.zeros(3), torch.full((3,), 50.0))
        return m.train(), torch.optim.SGD(m.parameters(), lr=1e-3, momentum=0.9)

    ours, ref = build(True), build(False)
    batch = _batch(size, args.batch_size, args.distinct_sat)
    for _ in range(args.warmup):
        _step(*ours, batch, True)
        _step(*ref, batch, False)
    t_ours, t_ref = [], []
    for _ in range(args.steps):
        t_ours.append(_step(*ours, batch, True))
        t_ref.append(_step(*ref, batch, False))
    n = args.batch_size
    return n / statistics.median(t_ours), n / statistics.median(t_ref)


def main(argv: Sequence[str]) -> int:
    from benchmark.errors import UsageError

    args = _parser().parse_args(list(argv))
    names = [m.strip() for m in args.models.split(",") if m.strip()]
    unknown = [m for m in names if m not in MODELS]
    if unknown or not names:
        raise UsageError(f"--models {args.models!r}: expected a comma list of {sorted(MODELS)}")
    for name in ("batch_size", "distinct_sat", "steps"):
        if getattr(args, name) < 1:
            raise UsageError(f"--{name.replace('_', '-')} must be >= 1")
    if args.distinct_sat > args.batch_size:
        raise UsageError("--distinct-sat cannot exceed --batch-size")
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    print(
        f"bench train: {args.attitude} ({args.variant}), batch {args.batch_size} with "
        f"{args.distinct_sat} distinct satellite images, {args.steps} timed steps, "
        f"{torch.get_num_threads()} torch threads"
    )
    print(
        f"{'model':8s} {'px':>4s} {'width':>5s} {'ours pairs/s':>13s} {'plain pairs/s':>14s} ratio"
    )
    for name in names:
        size, width = MODELS[name]
        size = args.size or size
        width = args.width or width
        ours, ref = measure(size, width, args)
        print(f"{name:8s} {size:4d} {width:5.2f} {ours:13.2f} {ref:14.2f} {ours / ref:5.2f}x")
    return 0
