"""Procedural cities: ``build_city(style, seed)`` -> ``City``, cached on disk; ``changed_city``.

A ``City`` is a 2.5D tile: an ortho texture (sun shading and shadows baked in) with its mip pyramid,
an absolute surface height map (terrain + buildings + trees + cars) with its max-mip pyramid, a
material grid, a facade palette and a coarse terrain grid, all on a regular grid of
``metres_per_px`` texels centred on the ENU origin. The renderer mirror-tiles it to infinity.

Sizes: the default tile is 3584 m x 2560 m (E x N) at 1 m/px, which holds the 2.8 km x 1.4 km
satellite footprint of a 1400 m shooting height around every flight centre. ``size_m`` and
``metres_per_px`` make smaller cities for tests (e.g. ``size_m=(512, 512)``); the grid is rounded up
to a multiple of 256 texels (the max-mip pyramid needs exact halvings).

Cache: ``<cache_dir>/<style>-<seed>-c<change>-<W>x<H>-<mpp>-v<GENERATOR_VERSION>/`` with one
``.npy``
per array (loaded memory-mapped, so worker processes share the pages) and ``meta.json``. The default
cache directory is ``$UAVBENCH_CACHE`` or ``~/.cache/uavbench/cities``; ``cache_dir=None`` in
``build_city`` means that default, ``cache_dir=False`` disables caching.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from benchmark.sim.city_layout import generate, rng_for
from benchmark.sim.render_core import MAT_BUILDING, MAT_WATER
from benchmark.sim.textures import bake_lighting, max_pyramid, mean_pyramid
from benchmark.sim.world_styles import STYLES, get_style

GENERATOR_VERSION = "5"
DEFAULT_SIZE_M = (3584.0, 2560.0)
SAT_MARGIN_M = (1400.0, 700.0)  # half of the largest satellite footprint (1400 m sweep)
GROUND_SCALE = 4  # texels per cell of the coarse terrain grid
_ARRAYS = (
    "height",
    "ground",
    "ortho",
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


@dataclass
class City:
    """A generated city tile. Arrays are indexed ``[j, i]``, j northwards (row 0 = southern edge).

    Attributes:
        style, seed: what was generated; ``change`` is 0 for the city as flown and the change seed
            for an earlier-time version (``changed_city``); ``season`` and ``sun`` (unit ENU vector
            towards the sun) describe the lighting baked into ``ortho``.
        metres_per_px: texel size; ``shape`` ``(H, W)`` in texels.
        height: ``(H, W)`` float32 absolute surface height, metres. ``ground``: ``(H/4, W/4)``
            float32 terrain height (4-texel cells). ``ortho``: ``(H, W, 3)`` uint8 shaded texture.
        max_structure_height: tallest building/tree above its ground, metres.
        flight_centres: ``(K, 2)`` float64 (E, N) centres such that the largest satellite
            footprint (2.8 km x 1.4 km) around each one stays inside the tile.
    """

    style: str
    seed: int
    change: int
    season: str
    sun: np.ndarray
    metres_per_px: float
    height: np.ndarray
    ground: np.ndarray
    ortho: np.ndarray
    mat: np.ndarray
    orient: np.ndarray
    palette: np.ndarray
    hpyr: np.ndarray
    hoff: np.ndarray
    hdims: np.ndarray
    tex: np.ndarray
    toff: np.ndarray
    tdims: np.ndarray
    flight_centres: np.ndarray
    clear: np.ndarray  # (H/8, W/8) float32: max height within >= 8 m of each 8 x 8 cell
    max_structure_height: float
    meta: dict = field(default_factory=dict)

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.height.shape[0]), int(self.height.shape[1]))

    @property
    def height_range(self) -> tuple[float, float]:
        """``(min, max)`` of the surface height, metres (cached)."""
        if "_hrange" not in self.__dict__:
            self.__dict__["_hrange"] = (float(self.height.min()), float(self.height.max()))
        return self.__dict__["_hrange"]

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """``(E_min, E_max, N_min, N_max)`` of the tile, metres (ENU, origin at its centre)."""
        H, W = self.shape
        hw, hh = 0.5 * W * self.metres_per_px, 0.5 * H * self.metres_per_px
        return (-hw, hw, -hh, hh)

    @property
    def origin(self) -> tuple[float, float]:
        """``(E0, N0)``: ENU of the south-west corner of texel [0, 0]."""
        e0, _, n0, _ = self.extent
        return (e0, n0)

    def ortho_image(self) -> np.ndarray:
        """The ortho texture north-up (row 0 = north), ``(H, W, 3)`` uint8, for viewing."""
        return np.ascontiguousarray(self.ortho[::-1])

    def with_rasters(
        self,
        *,
        height: np.ndarray | None = None,
        ortho: np.ndarray | None = None,
        mat: np.ndarray | None = None,
        ground: np.ndarray | None = None,
    ) -> City:
        """A copy with some rasters replaced (same shapes) and the pyramids rebuilt.

        For tests and experiments (markers, flat worlds); ``ground`` is the (H/4, W/4) grid.
        """
        height = self.height if height is None else np.asarray(height, np.float32)
        ortho = self.ortho if ortho is None else np.asarray(ortho, np.uint8)
        mat = self.mat if mat is None else np.asarray(mat, np.uint8)
        ground = self.ground if ground is None else np.asarray(ground, np.float32)
        for name, a, shp in (
            ("height", height, self.height.shape),
            ("ortho", ortho, self.ortho.shape),
            ("mat", mat, self.mat.shape),
            ("ground", ground, self.ground.shape),
        ):
            if a.shape != shp:
                raise ValueError(f"{name} must have shape {shp}, got {a.shape}")
        levels = len(self.hoff) - 1
        hpyr, hoff, hdims = max_pyramid(height, levels)
        tex, toff, tdims = mean_pyramid(ortho, levels)
        H, W = self.shape
        c8 = height.reshape(H // 8, 8, W // 8, 8).max(axis=(1, 3))
        clear = _dilate3(c8)
        return replace(
            self,
            height=height,
            ortho=ortho,
            mat=mat,
            ground=ground,
            hpyr=hpyr,
            hoff=hoff,
            hdims=hdims,
            tex=tex,
            toff=toff,
            tdims=tdims,
            clear=clear,
        )

    def _grid(self, E, N, scale: float):
        e0, n0 = self.origin
        return (np.asarray(E, np.float64) - e0) / scale, (np.asarray(N, np.float64) - n0) / scale

    def ground_height(self, E, N) -> np.ndarray:
        """Terrain height (metres, no buildings or trees) at ENU ``(E, N)``, vectorised, float64.

        Bilinear on the 4-texel terrain grid, mirror-extended beyond the tile like the renderer.
        """
        x, y = self._grid(E, N, self.metres_per_px * GROUND_SCALE)
        return _bilinear_mirror(self.ground, x - 0.5, y - 0.5)

    def surface_height(self, E, N) -> np.ndarray:
        """Height of the surface (terrain + structures) of the texel containing ``(E, N)``."""
        x, y = self._grid(E, N, self.metres_per_px)
        H, W = self.shape
        i = _mirror_index(np.floor(x).astype(np.int64), W)
        j = _mirror_index(np.floor(y).astype(np.int64), H)
        return self.height[j, i].astype(np.float64)

    def clearance(self, E, N) -> np.ndarray:
        """Conservative maximum surface height (metres, absolute) within at least 8 m of (E, N).

        A camera at height ``U > clearance(E, N)`` is outside all geometry within 8 m horizontally.
        """
        x, y = self._grid(E, N, self.metres_per_px * 8)
        hh, ww = self.clear.shape
        i = _mirror_index(np.floor(x).astype(np.int64), ww)
        j = _mirror_index(np.floor(y).astype(np.int64), hh)
        return self.clear[j, i].astype(np.float64)


def _dilate3(a: np.ndarray) -> np.ndarray:
    """3 x 3 maximum filter with mirror borders, float32."""
    from scipy.ndimage import maximum_filter

    return maximum_filter(a, size=3, mode="mirror").astype(np.float32)


def _mirror_index(i: np.ndarray, n: int) -> np.ndarray:
    m = np.mod(i, 2 * n)
    return np.where(m >= n, 2 * n - 1 - m, m)


def _bilinear_mirror(a: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    H, W = a.shape
    x0 = np.floor(x)
    y0 = np.floor(y)
    fx = x - x0
    fy = y - y0
    i0 = _mirror_index(x0.astype(np.int64), W)
    i1 = _mirror_index(x0.astype(np.int64) + 1, W)
    j0 = _mirror_index(y0.astype(np.int64), H)
    j1 = _mirror_index(y0.astype(np.int64) + 1, H)
    a = a.astype(np.float64)
    top = a[j0, i0] * (1 - fx) + a[j0, i1] * fx
    bot = a[j1, i0] * (1 - fx) + a[j1, i1] * fx
    return top * (1 - fy) + bot * fy


def default_cache_dir() -> Path:
    return Path(os.environ.get("UAVBENCH_CACHE", Path.home() / ".cache" / "uavbench" / "cities"))


def _grid_shape(size_m, mpp: float) -> tuple[int, int]:
    w = math.ceil(float(size_m[0]) / mpp / 256.0) * 256
    h = math.ceil(float(size_m[1]) / mpp / 256.0) * 256
    return h, w


def _sun(style: str, seed: int, change: int) -> tuple[np.ndarray, str]:
    """Sun direction and season: summer mid-morning to mid-afternoon for the flown city; a changed
    city gets another azimuth and a lower winter/autumn sun."""
    r = rng_for(style, seed * 7 + 1 + change, "sun")
    if change == 0:
        az, el, season = r.uniform(120, 240), r.uniform(38, 58), "summer"
    else:
        season = "winter" if r.uniform() < 0.5 else "autumn"
        az = r.uniform(120, 240)
        el = r.uniform(14, 24) if season == "winter" else r.uniform(24, 34)
    az_r, el_r = math.radians(az), math.radians(el)  # azimuth clockwise from north
    sun = np.array(
        [math.sin(az_r) * math.cos(el_r), math.cos(az_r) * math.cos(el_r), math.sin(el_r)]
    )
    return sun, season


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


def _assemble(style: str, seed: int, change: int, shape, mpp: float) -> City:
    S = get_style(style)
    sun, season = _sun(style, seed, change)
    R = generate(S, seed, shape, mpp, change, season)
    ortho = bake_lighting(R.albedo, R.height, mpp, sun, ambient=0.55, diffuse=0.6)
    H, W = shape
    g = math.gcd(H, W)
    levels = min(9, (g & -g).bit_length() - 1)  # exact halvings only
    hpyr, hoff, hdims = max_pyramid(R.height, levels)
    tex, toff, tdims = mean_pyramid(ortho, levels)
    ground = R.ground.reshape(H // 4, 4, W // 4, 4).mean(axis=(1, 3)).astype(np.float32)
    c8 = R.height.reshape(H // 8, 8, W // 8, 8).max(axis=(1, 3))
    clear = _dilate3(c8)
    struct = np.where(R.mat != MAT_WATER, R.height - R.ground, 0.0)
    return City(
        style=style,
        seed=int(seed),
        change=int(change),
        season=season,
        sun=sun,
        metres_per_px=float(mpp),
        height=R.height,
        ground=ground,
        ortho=ortho,
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


def _key(style, seed, change, shape, mpp) -> str:
    return f"{style}-{seed}-c{change}-{shape[1]}x{shape[0]}-{mpp:g}-v{GENERATOR_VERSION}"


def _save(city: City, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=path.name + ".tmp", dir=path.parent))
    for name in _ARRAYS:
        np.save(tmp / f"{name}.npy", np.ascontiguousarray(getattr(city, name)))
    np.save(tmp / "sun.npy", city.sun)
    meta = {
        "style": city.style,
        "seed": city.seed,
        "change": city.change,
        "season": city.season,
        "metres_per_px": city.metres_per_px,
        "max_structure_height": city.max_structure_height,
        "generator_version": GENERATOR_VERSION,
        **city.meta,
    }
    (tmp / "meta.json").write_text(json.dumps(meta, indent=1))
    try:
        os.replace(tmp, path)  # atomic: concurrent builders of the same key are both fine
    except OSError:
        shutil.rmtree(tmp, ignore_errors=True)


def _load(path: Path) -> City:
    meta = json.loads((path / "meta.json").read_text())
    arrays = {n: np.asarray(np.load(path / f"{n}.npy", mmap_mode="r")) for n in _ARRAYS}
    extra = {
        k: v
        for k, v in meta.items()
        if k
        not in (
            "style",
            "seed",
            "change",
            "season",
            "metres_per_px",
            "max_structure_height",
            "generator_version",
        )
    }
    return City(
        style=meta["style"],
        seed=meta["seed"],
        change=meta["change"],
        season=meta["season"],
        sun=np.load(path / "sun.npy"),
        metres_per_px=meta["metres_per_px"],
        max_structure_height=meta["max_structure_height"],
        meta=extra,
        **arrays,
    )


def _build(style, seed, change, size_m, mpp, cache_dir) -> City:
    get_style(style)
    if not (isinstance(seed, (int, np.integer)) and seed >= 0):
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    if not (math.isfinite(mpp) and 0.1 <= mpp <= 4.0):
        raise ValueError(f"metres_per_px must be in [0.1, 4], got {mpp!r}")
    if len(size_m) != 2 or not all(math.isfinite(float(s)) and s >= 128 for s in size_m):
        raise ValueError(f"size_m must be two sizes >= 128 m (E, N), got {size_m!r}")
    shape = _grid_shape(size_m, mpp)
    if cache_dir is False:
        return _assemble(style, int(seed), int(change), shape, mpp)
    root = default_cache_dir() if cache_dir is None else Path(cache_dir)
    path = root / _key(style, int(seed), int(change), shape, mpp)
    if (path / "meta.json").exists():
        return _load(path)
    city = _assemble(style, int(seed), int(change), shape, mpp)
    _save(city, path)
    return _load(path) if (path / "meta.json").exists() else city


def build_city(
    style: str,
    seed: int,
    *,
    cache_dir: str | Path | bool | None = None,
    size_m: tuple[float, float] = DEFAULT_SIZE_M,
    metres_per_px: float = 1.0,
) -> City:
    """Generate (or load from the cache) the city ``(style, seed)``; deterministic.

    Raises ValueError for an unknown style (listing ``STYLES``), a negative seed or bad sizes.
    """
    return _build(style, seed, 0, tuple(size_m), float(metres_per_px), cache_dir)


def changed_city(city: City, seed: int, *, cache_dir: str | Path | bool | None = None) -> City:
    """The same place at an earlier time (paper Sec. 3.5): other sun and season, cars re-drawn,
    ~5-10 % of buildings demolished and some gaps built on, some open blocks developed, 20 % of the
    trees gone and 15 % new ones. ``seed`` (>= 0) selects the change; the result is cached like
    ``build_city``.
    """
    if not (isinstance(seed, (int, np.integer)) and seed >= 0):
        raise ValueError(f"change seed must be a non-negative integer, got {seed!r}")
    H, W = city.shape
    size = (W * city.metres_per_px, H * city.metres_per_px)
    out = _build(city.style, city.seed, int(seed) + 1, size, city.metres_per_px, cache_dir)
    return replace(out, flight_centres=city.flight_centres.copy())


__all__ = ["DEFAULT_SIZE_M", "GENERATOR_VERSION", "STYLES", "City", "build_city", "changed_city"]
