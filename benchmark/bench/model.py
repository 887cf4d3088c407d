"""``uavbench bench model``: measured speed of the pair model and of its two optimisations.

Measures (and returns, for ``uavbench bench model`` to print), for one configuration (default: the
paper's Pd/Re-Net with AGTFM at 224 px):
  - training step (forward + Algorithm 1 loss + backward + SGD step) of a batch of ``--batch`` pairs
    over ``--sats`` distinct satellite images, without and with the shared-satellite path
    (``sat_ids``), and their ratio;
  - eval forward of the same batch in contiguous and channels_last memory format, and their ratio;
  - the resulting training and inference throughput in pairs/s.
Each time is the median of ``--repeats`` runs after one warm-up run.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass

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


@dataclass(frozen=True)
class ModelBenchConfig:
    """``bench model``: the model (attitude ``head``, GoogLeNet ``variant``, ``width``, ``size``
    px), ``batch`` pairs over ``sats`` distinct satellite images (``sats <= batch``), the median
    of ``repeats`` runs on ``threads`` torch threads."""

    head: str = "pd_re_net"
    variant: str = "a-f"
    width: float = 1.0
    size: int = 224
    batch: int = 20
    sats: int = 2
    repeats: int = 3
    threads: int = 1


@dataclass(frozen=True)
class ModelBenchResult:
    """What :func:`bench_model` measured on ``config``'s model, median seconds: a training step
    without (``train_plain``) and with (``train_shared``) the shared-satellite path, and an eval
    forward in contiguous (``eval_contiguous``) and channels_last (``eval_channels_last``)
    memory format."""

    config: ModelBenchConfig
    train_plain: float
    train_shared: float
    eval_contiguous: float
    eval_channels_last: float

    def lines(self) -> list[str]:
        """The configuration, the two ratios and the resulting throughput, a line each."""
        c, n = self.config, self.config.batch
        plain, shared = self.train_plain, self.train_shared
        slow, fast = self.eval_contiguous, self.eval_channels_last
        return [
            f"model: {c.head}, variant {c.variant!r}, width {c.width:g}, {c.size} px; "
            f"batch {n} pairs over {c.sats} satellite images; {c.threads} thread(s), "
            f"median of {c.repeats}",
            f"train step   plain {plain:.2f} s, shared satellite {shared:.2f} s: "
            f"{plain / shared:.2f}x",
            f"eval forward contiguous {slow:.2f} s, channels_last {fast:.2f} s: {slow / fast:.2f}x",
            f"throughput   training {n / shared:.1f} pairs/s, inference {n / fast:.1f} pairs/s",
        ]


def bench_model(config: ModelBenchConfig) -> ModelBenchResult:
    """Time the two optimisations of ``config``'s model; returns the median times."""
    torch.set_num_threads(config.threads)
    torch.manual_seed(0)
    kwargs = {"variant": config.variant, "width": config.width, "input_size": config.size}
    kwargs["attitude"] = config.head
    model = create_model(**kwargs)
    n, s = config.batch, config.size
    uav = torch.rand(n, 3, s, s)
    ids = torch.arange(n) % config.sats
    sat = torch.rand(config.sats, 3, s, s)[ids]
    R = torch.tensor(Rotation.random(n, random_state=0).as_matrix(), dtype=torch.float32)
    T = torch.randn(n, 3) * 100
    optimizer = torch.optim.SGD(model.parameters(), lr=1e-6, momentum=0.9)

    def train_step(sat_ids: torch.Tensor | None) -> None:
        model.train()
        loss = model.loss(model(uav, sat, sat_ids), R, T)["total"]
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()

    plain = _median_time(lambda: train_step(None), config.repeats)
    shared = _median_time(lambda: train_step(ids), config.repeats)

    def eval_forward(m: torch.nn.Module) -> None:
        with torch.inference_mode():
            m.eval()(uav, sat, ids)

    fast = _median_time(lambda: eval_forward(model), config.repeats)
    torch.manual_seed(0)
    contiguous = create_model(**kwargs, channels_last=False)
    slow = _median_time(lambda: eval_forward(contiguous), config.repeats)
    return ModelBenchResult(config, plain, shared, slow, fast)
