"""Procedural cities: ``build_city(style, seed)`` -> ``City``, cached on disk; ``changed_city``.

A ``City`` is a 2.5D tile: K illumination states (each a sun direction and the ortho texture with
that sun's shading and shadows baked in, as a mip pyramid), an absolute surface height map
(terrain + buildings + trees + cars) with its max-mip pyramid, a material grid, a facade palette
and a coarse terrain grid, all on a regular grid of ``metres_per_px`` texels centred on the ENU
origin. The renderer mirror-tiles it to infinity.

Illumination (issue 9): ``K = N_LIGHTS = 8`` states per city (``build_city(n_lights=...)``
changes it), so every flight and every satellite image can pick its own time of day
(``render_uav(..., light=k)``, ``render_satellite(..., light=k)``). The flown city has summer suns
stratified over the full circle of azimuths and, independently, over elevations 15-65 deg
(lighting.py says why not only the southern sky); ``changed_city`` has its own K low winter
(12-24 deg) or autumn (20-34 deg) suns. State order is shuffled per city; ``city.sun`` is state 0's.

Cost of K = 8 (measured on the 2-core machine, CPU time of one process): baking the 8 states takes
6.3 s for a full 3584 x 2560 m tile at 1 m/px (one state 1.1 s: shadow sweep 0.3-0.6 s, shading,
pyramid; the former single-sun march took 4.1 s), so a full city builds in about 20 s (layout about
14 s). Its cache is 400 MB (8 texture pyramids of 36.7 MB + 107 MB of the rest; the former
single-sun cache: 171 MB). A 2048 x 1280 m town at 2 m/px (grid 1024 x 768) builds in 1.8 s CPU and
caches 34 MB (K = 1: 0.8 s, 12 MB; former single-sun build: 1.3 s, 15 MB). Rendering cost does not
change (same kernel, one texture per frame): ``uavbench bench simulate`` gave 239-240 pairs/s at 96
px with 2 workers against 244-248 before, within the run-to-run noise.

Sizes: the default tile is 3584 m x 2560 m (E x N) at 1 m/px, which holds the 2.8 km x 1.4 km
satellite footprint of a 1400 m shooting height around every flight centre. ``size_m`` and
``metres_per_px`` make smaller cities for tests (e.g. ``size_m=(512, 512)``); the grid is rounded up
to a multiple of 256 texels (the max-mip pyramid needs exact halvings).

Cache: ``<cache_dir>/<style>-<seed>-c<change>-<W>x<H>-<mpp>-L<K>-v<GENERATOR_VERSION>-<source>/``
with one ``.npy`` per array (loaded memory-mapped, so worker processes share the pages) and
``meta.json``.
The default cache directory is ``$UAVBENCH_CACHE`` or ``~/.cache/uavbench/cities``;
``cache_dir=None`` in ``build_city`` means that default, ``cache_dir=False`` disables caching.
``<source>`` is :func:`source_digest` of the modules that build a city: a cache never outlives the
code that built it, even when a change forgot to bump GENERATOR_VERSION (issue 10 traced numbers
that differed between machines to exactly such stale caches being possible).
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import os
import shutil
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from benchmark.progress import Progress
from benchmark.sim.city_layout import generate, rng_for
from benchmark.sim.lighting import N_LIGHTS, bake_light_states, sample_suns
from benchmark.sim.render_core import MAT_BUILDING, MAT_WATER
from benchmark.sim.textures import max_pyramid
from benchmark.sim.world_city import City, dilate3
from benchmark.sim.world_styles import STYLES, get_style

GENERATOR_VERSION = "17"  # 17: detmath (issue 20), float32 city maths through libm
# The modules whose code decides a city's arrays (world.py and everything it builds with).
CITY_MODULES = (
    "city_blocks", "city_details", "city_districts", "city_industry", "city_layout",
    "city_nature", "lighting", "render_core", "textures", "world", "world_city", "world_styles",
)  # fmt: skip


@functools.cache
def source_digest(modules: tuple[str, ...] | None = None) -> str:
    """First 12 hex digits of the sha256 of the simulator's source: the named ``benchmark.sim``
    modules (default: every module of the package), in sorted order, name and bytes.

    Any edit of that code, comments included, changes the digest: cached cities and datasets are
    rebuilt rather than silently mixed with the output of other code."""
    folder = Path(__file__).resolve().parent
    names = sorted(modules) if modules is not None else sorted(p.stem for p in folder.glob("*.py"))
    digest = hashlib.sha256()
    for name in names:
        path = folder / f"{name}.py"
        if not path.is_file():
            raise ValueError(f"source_digest: no module {path}")
        digest.update(name.encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()[:12]


DEFAULT_SIZE_M = (3584.0, 2560.0)
SAT_MARGIN_M = (1400.0, 700.0)  # half of the largest satellite footprint (1400 m sweep)
_ARRAYS = (
    "light_suns",
    "height",
    "ground",
    "mat",
    "orient",
    "palette",
    "hpyr",
    "hoff",
    "hdims",
    "tex",
    "toff",
    "tdims",
    "flight_centres",
    "clear",
)


def default_cache_dir() -> Path:
    return Path(os.environ.get("UAVBENCH_CACHE", Path.home() / ".cache" / "uavbench" / "cities"))


def _grid_shape(size_m, mpp: float) -> tuple[int, int]:
    w = math.ceil(float(size_m[0]) / mpp / 256.0) * 256
    h = math.ceil(float(size_m[1]) / mpp / 256.0) * 256
    return h, w


def _suns(style: str, seed: int, change: int, n_lights: int) -> tuple[np.ndarray, str]:
    """``(K, 3)`` sun vectors of the illumination states and the season: summer morning to
    afternoon for the flown city; a changed city gets its own, lower winter or autumn suns."""
    r = rng_for(style, seed * 7 + 1 + change, "sun")
    season = "summer" if change == 0 else ("winter" if r.uniform() < 0.5 else "autumn")
    return sample_suns(r, n_lights, season), season


def _flight_centres(style: str, seed: int, shape, mpp: float) -> np.ndarray:
    """Six centres on a jittered 3 x 2 lattice inside the region where the largest satellite
    footprint still fits in the tile (or the central half of a small test tile)."""
    H, W = shape
    half_e = 0.5 * W * mpp - SAT_MARGIN_M[0] - 30.0
    half_n = 0.5 * H * mpp - SAT_MARGIN_M[1] - 30.0
    if half_e < 50.0 or half_n < 50.0:
        half_e, half_n = 0.25 * W * mpp, 0.25 * H * mpp
    r = rng_for(style, seed, "centres")
    pts = []
    for a in range(3):
        for b in range(2):
            e = (-half_e + (a + 0.5) * 2 * half_e / 3) + r.uniform(-0.25, 0.25) * 2 * half_e / 3
            n = (-half_n + (b + 0.5) * half_n) + r.uniform(-0.25, 0.25) * half_n
            pts.append((e, n))
    return np.asarray(pts, np.float64)


def _assemble(
    style: str, seed: int, change: int, shape, mpp: float, n_lights: int, progress: bool
) -> City:
    S = get_style(style)
    suns, season = _suns(style, seed, change, n_lights)
    what = f"city {style} seed {seed}" + (f" change {change - 1}" if change else "")
    H, W = shape
    g = math.gcd(H, W)
    levels = min(9, (g & -g).bit_length() - 1)  # exact halvings only
    with Progress(2, what, unit="step", enabled=progress) as bar:
        R = generate(S, seed, shape, mpp, change, season)
        bar.update(1, postfix="layout")
        tex, toff, tdims = bake_light_states(R.albedo, R.height, mpp, suns, levels)
        city = _finish(style, seed, change, shape, mpp, R, (tex, toff, tdims), suns, season)
        bar.update(1, postfix=f"{n_lights} illumination states")
    return city


def _finish(style, seed, change, shape, mpp, R, texture, suns, season) -> City:
    H, W = shape
    tex, toff, tdims = texture
    hpyr, hoff, hdims = max_pyramid(R.height, len(toff) - 1)
    ground = R.ground.reshape(H // 4, 4, W // 4, 4).mean(axis=(1, 3)).astype(np.float32)
    c8 = R.height.reshape(H // 8, 8, W // 8, 8).max(axis=(1, 3))
    clear = dilate3(c8)
    struct = np.where(R.mat != MAT_WATER, R.height - R.ground, 0.0)
    return City(
        style=style,
        seed=int(seed),
        change=int(change),
        season=season,
        light_suns=suns,
        metres_per_px=float(mpp),
        height=R.height,
        ground=ground,
        mat=R.mat,
        orient=R.orient,
        palette=R.palette,
        hpyr=hpyr,
        hoff=hoff,
        hdims=hdims,
        tex=tex,
        toff=toff,
        tdims=tdims,
        flight_centres=_flight_centres(style, seed, shape, mpp),
        clear=clear,
        max_structure_height=float(struct.max()),
        meta={"buildings_fraction": float((R.mat >= MAT_BUILDING).mean())},
    )


def _key(style, seed, change, shape, mpp, n_lights) -> str:
    size = f"{shape[1]}x{shape[0]}-{mpp:g}"
    source = source_digest(CITY_MODULES)
    return f"{style}-{seed}-c{change}-{size}-L{n_lights}-v{GENERATOR_VERSION}-{source}"


def _save(city: City, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=path.name + ".tmp", dir=path.parent))
    for name in _ARRAYS:
        np.save(tmp / f"{name}.npy", np.ascontiguousarray(getattr(city, name)))
    meta = {
        "style": city.style,
        "seed": city.seed,
        "change": city.change,
        "season": city.season,
        "metres_per_px": city.metres_per_px,
        "max_structure_height": city.max_structure_height,
        "n_lights": city.n_lights,
        "generator_version": GENERATOR_VERSION,
        **city.meta,
    }
    (tmp / "meta.json").write_text(json.dumps(meta, indent=1))
    try:
        os.replace(tmp, path)  # atomic: concurrent builders of the same key are both fine
    except OSError:
        shutil.rmtree(tmp, ignore_errors=True)


_META_KEYS = (
    "style",
    "seed",
    "change",
    "season",
    "metres_per_px",
    "max_structure_height",
    "n_lights",
    "generator_version",
)


def _load(path: Path) -> City:
    """Load a cached city (memory-mapped); ValueError naming the file if anything is off."""
    try:
        meta = json.loads((path / "meta.json").read_text())
        missing = [k for k in _META_KEYS if k not in meta]
        if missing:
            raise ValueError(f"missing keys {missing}")
        if meta["generator_version"] != GENERATOR_VERSION:
            raise ValueError(f"generator_version {meta['generator_version']!r}")
    except (OSError, ValueError) as e:
        raise ValueError(f"corrupt city cache {path / 'meta.json'}: {e}; delete {path}") from e
    arrays = {}
    for n in _ARRAYS:
        f = path / f"{n}.npy"
        try:
            arrays[n] = np.asarray(np.load(f, mmap_mode="r"))
        except (OSError, ValueError) as e:
            raise ValueError(f"corrupt city cache file {f}: {e}; delete {path}") from e
    H, W = arrays["height"].shape
    K = int(meta["n_lights"])
    n_tex = int(arrays["toff"][-1] + arrays["tdims"][-1].prod()) if len(arrays["toff"]) else -1
    expect = {
        "light_suns": (K, 3),
        "tex": (K, n_tex, 3),
        "mat": (H, W),
        "orient": (H, W),
        "ground": (H // 4, W // 4),
    }
    for n, shape in expect.items():
        if arrays[n].shape != shape:
            raise ValueError(
                f"corrupt city cache file {path / (n + '.npy')}: shape {arrays[n].shape}, "
                f"expected {shape}; delete {path}"
            )
    if n_tex < H * W:
        raise ValueError(f"corrupt city cache file {path / 'toff.npy'}: bad offsets; delete {path}")
    extra = {k: v for k, v in meta.items() if k not in _META_KEYS}
    return City(
        style=meta["style"],
        seed=meta["seed"],
        change=meta["change"],
        season=meta["season"],
        metres_per_px=meta["metres_per_px"],
        max_structure_height=meta["max_structure_height"],
        meta=extra,
        **arrays,
    )


def _build(style, seed, change, size_m, mpp, n_lights, cache_dir, progress=False) -> City:
    get_style(style)
    if not (
        isinstance(n_lights, (int, np.integer))
        and not isinstance(n_lights, bool)
        and 1 <= n_lights <= 64
    ):
        raise ValueError(f"n_lights must be an integer in [1, 64], got {n_lights!r}")
    n_lights = int(n_lights)
    if not (isinstance(seed, (int, np.integer)) and seed >= 0):
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    if not (math.isfinite(mpp) and 0.1 <= mpp <= 4.0):
        raise ValueError(f"metres_per_px must be in [0.1, 4], got {mpp!r}")
    if len(size_m) != 2 or not all(math.isfinite(float(s)) and s >= 128 for s in size_m):
        raise ValueError(f"size_m must be two sizes >= 128 m (E, N), got {size_m!r}")
    shape = _grid_shape(size_m, mpp)
    if cache_dir is False:
        return _assemble(style, int(seed), int(change), shape, mpp, n_lights, progress)
    root = default_cache_dir() if cache_dir is None else Path(cache_dir)
    path = root / _key(style, int(seed), int(change), shape, mpp, n_lights)
    if (path / "meta.json").exists():
        return _load(path)
    city = _assemble(style, int(seed), int(change), shape, mpp, n_lights, progress)
    _save(city, path)
    return _load(path) if (path / "meta.json").exists() else city


def build_city(
    style: str,
    seed: int,
    *,
    cache_dir: str | Path | bool | None = None,
    size_m: tuple[float, float] = DEFAULT_SIZE_M,
    metres_per_px: float = 1.0,
    n_lights: int = N_LIGHTS,
    progress: bool = False,
) -> City:
    """Generate (or load from the cache) the city ``(style, seed)``; deterministic.

    ``n_lights`` illumination states are baked (default ``N_LIGHTS``; cost in the module
    docstring); ``progress=True`` prints a bar. Loading from the cache is instant (memory-mapped).
    Raises ValueError for an unknown style (listing ``STYLES``), a negative seed, bad sizes or a
    bad ``n_lights``.
    """
    mpp = float(metres_per_px)
    return _build(style, seed, 0, tuple(size_m), mpp, n_lights, cache_dir, progress)


def changed_city(
    city: City, seed: int, *, cache_dir: str | Path | bool | None = None, progress: bool = False
) -> City:
    """The same place at an earlier time (paper Sec. 3.5): another season (winter or autumn) with
    its own ``city.n_lights`` low suns, cars re-drawn, ~5-10 % of buildings demolished and some
    gaps built on, some open blocks developed, 20 % of the trees gone and 15 % new ones. ``seed``
    (>= 0) selects the change; the result is cached like ``build_city``.
    """
    if not (isinstance(seed, (int, np.integer)) and seed >= 0):
        raise ValueError(f"change seed must be a non-negative integer, got {seed!r}")
    H, W = city.shape
    size = (W * city.metres_per_px, H * city.metres_per_px)
    mpp, k = city.metres_per_px, city.n_lights
    out = _build(city.style, city.seed, int(seed) + 1, size, mpp, k, cache_dir, progress)
    return replace(out, flight_centres=city.flight_centres.copy())


__all__ = [
    "DEFAULT_SIZE_M",
    "GENERATOR_VERSION",
    "N_LIGHTS",
    "STYLES",
    "City",
    "build_city",
    "changed_city",
    "source_digest",
]
