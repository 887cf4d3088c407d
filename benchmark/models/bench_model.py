"""``uavbench bench model``: measured speed of the pair model and of its two optimisations.

Prints, for one configuration (default: the paper's Pd/Re-Net with AGTFM at 224 px):
  - training step (forward + Algorithm 1 loss + backward + SGD step) of a batch of ``--batch`` pairs
    over ``--sats`` distinct satellite images, without and with the shared-satellite path
    (``sat_ids``), and their ratio;
  - eval forward of the same batch in contiguous and channels_last memory format, and their ratio;
  - the resulting training and inference throughput in pairs/s.
Each time is the median of ``--repeats`` runs after one warm-up run.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import torch
from scipy.spatial.transform import Rotation

from benchmark.models.pair import create_model


def _median_time(fn: Callable[[], object], repeats: int) -> float:
    fn()  # warm-up: allocator, oneDNN kernel selection
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="uavbench bench model", description=__doc__)
    p.add_argument("--head", default="pd_re_net")
    p.add_argument("--variant", default="a-f")
    p.add_argument("--width", type=float, default=1.0)
    p.add_argument("--size", type=int, default=224)
    p.add_argument("--batch", type=int, default=20, help="pairs per batch (paper: 20)")
    p.add_argument("--sats", type=int, default=2, help="distinct satellite images in the batch")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args(argv)
    if min(args.batch, args.sats, args.repeats, args.threads) < 1 or args.sats > args.batch:
        p.error("need batch, sats, repeats, threads >= 1 and sats <= batch")
    return args


def main(argv: list[str]) -> int:
    args = parse_args(argv)
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    kwargs = {"variant": args.variant, "width": args.width, "input_size": args.size}
    kwargs["attitude"] = args.head
    model = create_model(**kwargs)
    n, s = args.batch, args.size
    uav = torch.rand(n, 3, s, s)
    ids = torch.arange(n) % args.sats
    sat = torch.rand(args.sats, 3, s, s)[ids]
    R = torch.tensor(Rotation.random(n, random_state=0).as_matrix(), dtype=torch.float32)
    T = torch.randn(n, 3) * 100
    optimizer = torch.optim.SGD(model.parameters(), lr=1e-6, momentum=0.9)

    def train_step(sat_ids: torch.Tensor | None) -> None:
        model.train()
        loss = model.loss(model(uav, sat, sat_ids), R, T)["total"]
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()

    plain = _median_time(lambda: train_step(None), args.repeats)
    shared = _median_time(lambda: train_step(ids), args.repeats)

    def eval_forward(m: torch.nn.Module) -> None:
        with torch.inference_mode():
            m.eval()(uav, sat, ids)

    fast = _median_time(lambda: eval_forward(model), args.repeats)
    torch.manual_seed(0)
    contiguous = create_model(**kwargs, channels_last=False)
    slow = _median_time(lambda: eval_forward(contiguous), args.repeats)

    print(
        f"model: {args.head}, variant {args.variant!r}, width {args.width:g}, {s} px; batch {n} "
        f"pairs over {args.sats} satellite images; {args.threads} thread(s), "
        f"median of {args.repeats}"
    )
    print(
        f"train step   plain {plain:.2f} s, shared satellite {shared:.2f} s: {plain / shared:.2f}x"
    )
    print(f"eval forward contiguous {slow:.2f} s, channels_last {fast:.2f} s: {slow / fast:.2f}x")
    print(f"throughput   training {n / shared:.1f} pairs/s, inference {n / fast:.1f} pairs/s")
    return 0
