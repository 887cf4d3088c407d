"""``uavbench bench simulate``: measured simulator throughput against the issue's targets.

Measures (and returns, for ``uavbench bench simulate`` to print) the time to build one city from
scratch (and to load it from the cache) with its number of illumination states and cache size, then
for each image size the pairs per second of the real shard pipeline (render + camera model + .npy
write) with all workers, on flights of the default flight spec; each flight has its own illumination
state (cycling through all of them, so the texture working set is a real dataset's) and fog
distance. A pair costs one UAV render; the satellite image is rendered once per centre and height (a
few dozen per dataset), so its time is reported separately rather than amortised. Targets (issue 3,
2 cores): >= 150 pairs/s at 96 px, >= 30 pairs/s at 224 px.
"""

from __future__ import annotations

import dataclasses
import math
import os
import tempfile
import time
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

if TYPE_CHECKING:
    from benchmark.sim import City

TARGETS_PAIRS_PER_S = {96: 150.0, 224: 30.0}


def bench_poses(city: City, n: int, seed: int, samples: int = 16) -> pd.DataFrame:
    """``n`` UAV poses on default-spec flights around the city's centres (no camera effects);
    flight k is lit by state ``k mod n_lights`` with a fog distance between 1.5 and 6 km."""
    from benchmark.sim import FlightSpec, generate_flight

    spec = FlightSpec(samples=samples)
    rows = []
    for k in range(math.ceil(n / samples)):
        centre = city.flight_centres[k % len(city.flight_centres)]
        f = generate_flight(city, tuple(centre), spec, seed=seed, group=99, flight=k)
        for i in range(samples):
            rows.append(
                dict(E=f.E[i], N=f.N[i], U=f.U[i], yaw=f.yaw[i], pitch=f.pitch[i], roll=f.roll[i])
            )
            rows[-1].update(
                light=k % getattr(city, "n_lights", 1),
                visibility_m=1500.0 + 4500.0 * ((k * 0.618) % 1),
            )
    df = pd.DataFrame(rows[:n])
    df.insert(0, "uav_index", np.arange(len(df), dtype=np.int64))
    df["city"] = getattr(city, "style", "bench")
    df["camera_effects"] = False
    return df


def _bench_cities(style: str, seed: int, cache: Path) -> dict[tuple[str, str], Any]:
    from benchmark.sim import build_city

    return {(style, "now"): build_city(style, seed, cache_dir=cache)}


@dataclasses.dataclass(frozen=True)
class SimulateBenchConfig:
    """``bench simulate``: ``workers`` rendering processes, image ``sizes`` (px), ``pairs`` per
    size (None: 800 below 150 px, else 240), the city ``style`` and ``seed``."""

    workers: int = 1
    sizes: tuple[int, ...] = (96, 224)
    pairs: int | None = None
    style: str = "oxford"
    seed: int = 0


@dataclasses.dataclass(frozen=True)
class SizeRate:
    """One image size's measurement: ``pairs_per_s`` over ``pairs`` UAV pairs rendered with
    ``supersample``, the satellite image's seconds (``sat_s``), the workers' start-up seconds (not
    counted in the rate) and the issue's ``target`` pairs/s (None: no target at this size)."""

    size: int
    pairs_per_s: float
    pairs: int
    supersample: int
    sat_s: float
    startup_s: float
    target: float | None

    @property
    def ok(self) -> bool:
        """The target is met (or there is none)."""
        return self.target is None or self.pairs_per_s >= self.target

    def line(self) -> str:
        """``  96 px:   160.3 pairs/s over 800 pairs, ... (target >= 150: OK, ratio 1.07); ...``"""
        verdict = ""
        if self.target is not None:
            word = "OK" if self.ok else "BELOW TARGET"
            ratio = self.pairs_per_s / self.target
            verdict = f" (target >= {self.target:.0f}: {word}, ratio {ratio:.2f})"
        return (
            f"{self.size:4d} px: {self.pairs_per_s:7.1f} pairs/s over {self.pairs} pairs, "
            f"supersample {self.supersample}"
            f"{verdict}; satellite image {1e3 * self.sat_s:.0f} ms; "
            f"worker start-up {self.startup_s:.1f} s (not counted)"
        )


@dataclasses.dataclass(frozen=True)
class SimulateBenchResult:
    """What :func:`bench_simulate` measured: the city ``style`` built from scratch in ``build_s``
    seconds (``n_lights`` illumination states) and loaded from its cache (``cache_mb`` MB) in
    ``load_s``, and one :class:`SizeRate` per image size."""

    style: str
    n_lights: int
    build_s: float
    load_s: float
    cache_mb: float
    rates: tuple[SizeRate, ...]

    @property
    def ok(self) -> bool:
        """Every size with a target met it."""
        return all(r.ok for r in self.rates)

    def lines(self) -> list[str]:
        """The city line, then one line per image size."""
        city = (
            f"city build ({self.style}, from scratch, {self.n_lights} illumination states): "
            f"{self.build_s:.2f} s; load from cache: {self.load_s:.2f} s; "
            f"cache {self.cache_mb:.0f} MB"
        )
        return [city, *(r.line() for r in self.rates)]


def bench_simulate(config: SimulateBenchConfig) -> SimulateBenchResult:
    """Measure the city build and each size's rendering rate; returns them (``ok``: every target
    met). The opening line (workers, cores, style) goes to :func:`benchmark.progress.status`.
    InputError: bad sizes or counts."""
    from benchmark.data.simulate import single_thread_env
    from benchmark.errors import InputError
    from benchmark.progress import status

    if (
        config.workers < 1
        or any(s < 8 for s in config.sizes)
        or (config.pairs is not None and config.pairs < 1)
    ):
        raise InputError(
            "bench simulate: SimulateBenchConfig.workers >= 1, every one of .sizes >= 8 and "
            f".pairs >= 1 expected, got workers {config.workers}, sizes {list(config.sizes)}, "
            f"pairs {config.pairs}"
        )
    single_thread_env()
    from benchmark.data.profiles import DATA_PROFILES
    from benchmark.data.render_pool import RenderContext, RenderPool, render_sat_rows
    from benchmark.sim import build_city, city_seed

    # Before the minutes of work, so the run says what it measures at once.
    status(
        f"uavbench bench simulate: {config.workers} workers, {os.cpu_count()} cores, "
        f"style {config.style}"
    )
    rates = []
    with tempfile.TemporaryDirectory(prefix="uavbench-bench-") as tmp:
        cache = Path(tmp) / "cities"
        seed = city_seed(config.seed, config.style)
        t0 = time.perf_counter()
        city = build_city(config.style, seed, cache_dir=cache)
        build_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        city = build_city(config.style, seed, cache_dir=cache)
        load_s = time.perf_counter() - t0
        cache_mb = sum(f.stat().st_size for f in cache.rglob("*") if f.is_file()) / 1e6

        for size in config.sizes:
            n = config.pairs or (800 if size < 150 else 240)
            base = DATA_PROFILES["paper" if size >= 150 else "quick"]
            shard = max(8, math.ceil(n / (config.workers * 6)))
            profile = dataclasses.replace(base, image_size=size, shard_size=shard)
            poses = bench_poses(city, n, config.seed)
            poses["city"] = config.style
            sat_rows = pd.DataFrame(
                [
                    dict(
                        city=config.style,
                        variant="now",
                        E=float(city.flight_centres[0][0]),
                        N=float(city.flight_centres[0][1]),
                        height_m=1000.0,
                        footprint_E_m=2000.0,
                        footprint_N_m=1000.0,
                        light=0,
                    )
                ]
            )
            ctx = RenderContext(
                Path(tmp) / f"out{size}",
                profile,
                config.seed,
                {(config.style, "now"): city},
                poses,
                sat_rows,
            )
            t0 = time.perf_counter()
            render_sat_rows(ctx, sat_rows)  # also compiles/loads the renderer in this process
            sat_s = time.perf_counter() - t0
            tasks = [("uav", k) for k in range(math.ceil(n / shard))]
            factory = partial(_bench_cities, config.style, seed, cache)
            with RenderPool(ctx, config.workers, factory) as pool:
                t0 = time.perf_counter()
                pool.warm_up()  # worker start-up (imports, city load) is not rendering
                startup_s = time.perf_counter() - t0
                t0 = time.perf_counter()
                done = sum(r.n for r in pool.imap(tasks))
                rate = done / (time.perf_counter() - t0)
            target = TARGETS_PAIRS_PER_S.get(size)
            rates.append(SizeRate(size, rate, done, profile.supersample, sat_s, startup_s, target))
    return SimulateBenchResult(config.style, city.n_lights, build_s, load_s, cache_mb, tuple(rates))
