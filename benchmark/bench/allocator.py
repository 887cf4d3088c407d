"""``uavbench bench allocator``: the same work under glibc's default allocator policy and under the
one uavbench sets at start-up (:mod:`benchmark.allocator`), side by side.

The policy is process-wide and glibc reads it when a process starts, so each side runs in a
fresh interpreter (:func:`~benchmark.bench.fresh_process.run_fresh`): ``default`` with
``UAVBENCH_ALLOCATOR=default`` and no ``MALLOC_*`` variables, ``tuned`` with them. Rounds
alternate the order (default first, then tuned first, ...) so that a drifting load falls on
both sides. Workloads:

- ``matcher``: training steps of the quick matching encoder with Pd/Re-Net, batch 20 over 4
  satellite images, one thread: ``bench train``'s loops, "ours" in each ``precision`` and (with
  ``base``) its "base fp32", the matcher's correlation before issue 40;
- ``joint``: the joint (heading, E, N) filter and smoother of one synthetic 32-sample flight on
  the quick fusion's grid (120 heading bins x a 2 km x 1 km plane of 20 m cells), float64.

Each side reports the median seconds of its timed repetitions (after ``warmup``) per round; the
ratio is default over tuned of the medians over rounds (> 1: the tuned policy is faster). With
the base loop, one more ratio, measured in the same run: the base loop under glibc's default
policy (the matcher as it ran before issue 40) over "ours fp32" under uavbench's (as it runs now).
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from benchmark.allocator import ALLOCATOR_ENV, ENV_SWITCH

WORKLOADS = ("matcher", "joint")
SIDES = ("default", "tuned")


@dataclass(frozen=True)
class AllocatorBenchConfig:
    """``rounds`` fresh processes per side and workload; ``steps`` timed repetitions after
    ``warmup`` in each; ``precisions`` of the matcher's "ours" loops, ``base`` its base loop
    too; ``threads`` torch threads."""

    workloads: tuple[str, ...] = WORKLOADS
    precisions: tuple[str, ...] = ("fp32",)
    base: bool = True
    rounds: int = 2
    steps: int = 6
    warmup: int = 2
    threads: int = 1

    def __post_init__(self) -> None:
        unknown = [w for w in self.workloads if w not in WORKLOADS]
        if unknown or not self.workloads:
            raise ValueError(f"workloads must be some of {WORKLOADS}, got {self.workloads!r}")
        bad = [p for p in self.precisions if p not in ("fp32", "bf16")]
        if bad or not self.precisions:
            raise ValueError(f"precisions must be some of fp32, bf16, got {self.precisions!r}")
        for name in ("rounds", "steps", "threads"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)!r}")
        if self.warmup < 0:
            raise ValueError(f"warmup must be >= 0, got {self.warmup!r}")


def _matcher_seconds(loop: str, steps: int, warmup: int) -> list[float]:
    """Seconds of ``steps`` training steps of the quick matcher in ``bench train``'s ``loop``
    ("base fp32", "ours fp32", "ours bf16")."""
    import torch

    from benchmark.bench.train import TrainBenchConfig, batch_of, build, loop_specs, make_step

    device = torch.device("cpu")
    specs = loop_specs(["fp32", "bf16"], device, False, True, encoder="matching")
    spec = next(s for s in specs if s.name == loop)
    precision = spec.precision
    model, optimizer = build(96, 0.25, TrainBenchConfig(), spec, device, encoder="matching")
    step = make_step(model, optimizer, batch_of(96, 20, 4), spec.share, device, precision)
    for _ in range(warmup):
        step()
    return [step() for _ in range(steps)]


def _joint_seconds(steps: int, warmup: int) -> list[float]:
    """Seconds of the joint filter and smoother of one synthetic 32-sample flight, ``steps``
    times (the same flight: seeded beliefs and odometry)."""
    import time

    import torch

    from benchmark.evaluation.fusion_grid import CircularGrid, PlanarGrid
    from benchmark.evaluation.fusion_joint import JointFlight, JointGrid, filter_and_smooth_joint
    from benchmark.evaluation.fusion_odometry import OdometryNoise

    g = torch.Generator().manual_seed(0)
    grid = JointGrid(CircularGrid(120), PlanarGrid(-1000.0, -500.0, 20.0, 101, 51))
    k = 32
    logits = torch.randn(k, *grid.shape, generator=g, dtype=torch.float64)

    def belief(sample: int, psi: torch.Tensor) -> torch.Tensor:
        return logits[sample]

    flight = JointFlight(
        belief,
        dyaw=0.02 * torch.randn(k - 1, generator=g, dtype=torch.float64),
        steps=torch.stack([torch.zeros(k - 1), torch.full((k - 1,), 15.0)], 1).double(),
        yaw_sigma=torch.full((k - 1,), math.radians(0.5), dtype=torch.float64),
    )
    noise = OdometryNoise()
    times = []
    for i in range(warmup + steps):
        start = time.perf_counter()
        filter_and_smooth_joint(flight, grid, noise)
        if i >= warmup:
            times.append(time.perf_counter() - start)
    return times


def _child(workload: str, loop: str, steps: int, warmup: int, threads: int) -> dict:
    """One side's run in its fresh process: the policy as the environment says, then the
    workload. Returns the policy line and the seconds."""
    import torch

    from benchmark.allocator import tune_allocator

    status = tune_allocator()
    torch.set_num_threads(threads)
    if workload == "matcher":
        seconds = _matcher_seconds(loop, steps, warmup)
    else:
        seconds = _joint_seconds(steps, warmup)
    return {"allocator": status.detail, "tuned": status.tuned, "seconds": seconds}


def side_environment(side: str) -> tuple[dict[str, str], tuple[str, ...]]:
    """``(env, unset)`` of a side's fresh process: ``default`` unsets the ``MALLOC_*`` figures
    and sets ``UAVBENCH_ALLOCATOR=default``; ``tuned`` sets both figures and ``tuned``."""
    if side == "default":
        return {ENV_SWITCH: "default"}, tuple(ALLOCATOR_ENV)
    if side == "tuned":
        return {ENV_SWITCH: "tuned", **ALLOCATOR_ENV}, ()
    raise ValueError(f"side must be one of {SIDES}, got {side!r}")


@dataclass
class AllocatorRow:
    """One workload (and loop): per side, the median seconds of each round."""

    workload: str
    loop: str
    rounds: dict[str, list[float]] = field(default_factory=lambda: {s: [] for s in SIDES})
    policies: dict[str, str] = field(default_factory=dict)

    def median(self, side: str) -> float:
        return statistics.median(self.rounds[side])

    @property
    def ratio(self) -> float:
        """Default over tuned seconds (> 1: tuned is faster)."""
        return self.median("default") / self.median("tuned")


@dataclass
class AllocatorBenchResult:
    rows: list[AllocatorRow]

    def lines(self) -> list[str]:
        out = ["workload  loop       default s  tuned s  default/tuned  rounds (default | tuned)"]
        for row in self.rows:
            each = " ".join(f"{s:.3f}" for s in row.rounds["default"])
            each += " | " + " ".join(f"{s:.3f}" for s in row.rounds["tuned"])
            out.append(
                f"{row.workload:9s} {row.loop:10s} {row.median('default'):8.3f} "
                f"{row.median('tuned'):8.3f} {row.ratio:13.2f}x  {each}"
            )
        loops = {row.loop: row for row in self.rows if row.workload == "matcher"}
        if "base fp32" in loops and "ours fp32" in loops:
            base, ours = loops["base fp32"], loops["ours fp32"]
            out.append(
                f"matcher: ours fp32 (tuned) over base fp32 (default), the same run: "
                f"{base.median('default') / ours.median('tuned'):.2f}x (code alone, both "
                f"default: {base.median('default') / ours.median('default'):.2f}x)"
            )
        for side in SIDES:
            seen = sorted({row.policies.get(side, "?") for row in self.rows})
            out.append(f"{side}: {'; '.join(seen)}")
        return out


def bench_allocator(
    config: AllocatorBenchConfig, progress: Callable[[str], None] | None = None
) -> AllocatorBenchResult:
    """Every workload (the matcher once per loop) under both policies, ``config.rounds`` fresh
    processes each, alternating which side goes first; ``progress`` gets a line per process."""
    from benchmark.bench.fresh_process import run_fresh

    loops = (["base fp32"] if config.base else []) + [f"ours {p}" for p in config.precisions]
    jobs: Sequence[tuple[str, str]] = [
        (w, loop) for w in config.workloads for loop in (loops if w == "matcher" else ["fp64"])
    ]
    rows = [AllocatorRow(w, p) for w, p in jobs]
    for r in range(config.rounds):
        order = SIDES if r % 2 == 0 else SIDES[::-1]
        for row in rows:
            for side in order:
                env, unset = side_environment(side)
                got = run_fresh(
                    _child, row.workload, row.loop, config.steps, config.warmup,
                    config.threads, env=env, unset=unset,
                )  # fmt: skip
                row.rounds[side].append(statistics.median(got["seconds"]))
                row.policies[side] = got["allocator"]
                if progress is not None:
                    progress(
                        f"round {r + 1}/{config.rounds} {row.workload} {row.loop} {side}: "
                        f"{row.rounds[side][-1]:.3f} s"
                    )
    return AllocatorBenchResult(rows)


__all__ = [
    "SIDES",
    "WORKLOADS",
    "AllocatorBenchConfig",
    "AllocatorBenchResult",
    "AllocatorRow",
    "bench_allocator",
    "side_environment",
]
