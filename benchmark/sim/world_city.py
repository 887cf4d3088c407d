"""The ``City`` container: rasters of one generated city tile and its geometric queries.

Arrays are indexed ``[j, i]`` with j northwards (row 0 = southern edge) and i eastwards; texel
``[j, i]`` covers ``E in [E0 + i mpp, E0 + (i+1) mpp)``, ``N in [N0 + j mpp, N0 + (j+1) mpp)`` with
``(E0, N0) = City.origin``. Queries outside the tile use the same mirror tiling as the renderer.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike

from benchmark.sim.lighting import sun_angles
from benchmark.sim.textures import max_pyramid, mean_pyramid

GROUND_SCALE = 4  # texels per cell of the coarse terrain grid


@dataclass
class City:
    """A generated city tile. Arrays are indexed ``[j, i]``, j northwards (row 0 = southern edge).

    Attributes:
        style, seed: what was generated; ``change`` is 0 for the city as flown and the change seed
            for an earlier-time version (``changed_city``); ``season`` its season.
        light_suns: ``(K, 3)`` float64 unit ENU vectors towards the sun of the K illumination
            states (``n_lights``); ``light_angles(k)`` gives (azimuth, elevation) radians.
        tex, toff, tdims: ``tex`` ``(K, N, 3)`` uint8, per state the flattened mip pyramid of the
            ortho texture with that state's shading and shadows baked in; ``toff`` ``(L+1,)`` and
            ``tdims`` ``(L+1, 2)`` its level offsets and (rows, cols), shared by all states.
            ``ortho`` is state 0's full-resolution texture ``(H, W, 3)`` (a view of ``tex``),
            ``light_ortho(k)`` state k's; ``sun`` is ``light_suns[0]``.
        metres_per_px: texel size; ``shape`` ``(H, W)`` in texels.
        height: ``(H, W)`` float32 absolute surface height, metres. ``ground``: ``(H/4, W/4)``
            float32 terrain height (4-texel cells).
        max_structure_height: tallest building/tree above its ground, metres.
        flight_centres: ``(K, 2)`` float64 (E, N) centres such that the largest satellite
            footprint (2.8 km x 1.4 km) around each one stays inside the tile.
    """

    style: str
    seed: int
    change: int
    season: str
    light_suns: np.ndarray
    metres_per_px: float
    height: np.ndarray
    ground: np.ndarray
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

    @property
    def n_lights(self) -> int:
        """K, the number of illumination states."""
        return int(self.light_suns.shape[0])

    def check_light(self, light: int) -> int:
        """``light`` as an int if it is an integer in [0, K); ValueError naming it otherwise."""
        ok = isinstance(light, (int, np.integer)) and not isinstance(light, bool)
        if not (ok and 0 <= light < self.n_lights):
            raise ValueError(
                f"light must be an integer in [0, {self.n_lights}) (the city's illumination "
                f"states), got {light!r}"
            )
        return int(light)

    def light_angles(self, k: int) -> tuple[float, float]:
        """``(azimuth, elevation)`` radians of state k's sun; azimuth clockwise from north in
        [0, 2 pi), elevation above the horizon."""
        return sun_angles(self.light_suns[self.check_light(k)])

    @property
    def sun(self) -> np.ndarray:
        """``(3,)`` unit ENU vector towards the sun of illumination state 0."""
        return self.light_suns[0]

    def light_ortho(self, k: int) -> np.ndarray:
        """State k's full-resolution ortho texture ``(H, W, 3)`` uint8 (a view, row 0 south)."""
        H, W = self.shape
        return self.tex[self.check_light(k), : H * W].reshape(H, W, 3)

    @property
    def ortho(self) -> np.ndarray:
        """State 0's ortho texture ``(H, W, 3)`` uint8 (row 0 = southern edge)."""
        return self.light_ortho(0)

    def ortho_image(self, light: int = 0) -> np.ndarray:
        """The ortho texture of state ``light`` north-up (row 0 = north), ``(H, W, 3)`` uint8."""
        return np.ascontiguousarray(self.light_ortho(light)[::-1])

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
        ``ortho`` is ``(H, W, 3)`` (the same texture for every illumination state) or
        ``(K, H, W, 3)`` (one per state); lighting is not re-baked.
        """
        H, W = self.shape
        K = self.n_lights
        height = self.height if height is None else np.asarray(height, np.float32)
        mat = self.mat if mat is None else np.asarray(mat, np.uint8)
        ground = self.ground if ground is None else np.asarray(ground, np.float32)
        if ortho is not None:
            ortho = np.asarray(ortho, np.uint8)
            if ortho.shape not in ((H, W, 3), (K, H, W, 3)):
                raise ValueError(
                    f"ortho must have shape {(H, W, 3)} or {(K, H, W, 3)}, got {ortho.shape}"
                )
        for name, a, shp in (
            ("height", height, self.height.shape),
            ("mat", mat, self.mat.shape),
            ("ground", ground, self.ground.shape),
        ):
            if a.shape != shp:
                raise ValueError(f"{name} must have shape {shp}, got {a.shape}")
        levels = len(self.hoff) - 1
        hpyr, hoff, hdims = max_pyramid(height, levels)
        tex, toff, tdims = self.tex, self.toff, self.tdims
        if ortho is not None and ortho.ndim == 3:  # one pyramid, copied to every state
            flat, toff, tdims = mean_pyramid(ortho, levels)
            tex = np.repeat(flat[None], K, axis=0)
        elif ortho is not None:
            pyrs = [mean_pyramid(o, levels) for o in ortho]
            tex = np.stack([p[0] for p in pyrs])
        c8 = height.reshape(H // 8, 8, W // 8, 8).max(axis=(1, 3))
        clear = dilate3(c8)
        return replace(
            self,
            height=height,
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

    def ground_height(self, E: ArrayLike, N: ArrayLike) -> np.ndarray:
        """Terrain height (metres, no buildings or trees) at ENU ``(E, N)``, vectorised, float64.

        Bilinear on the 4-texel terrain grid, mirror-extended beyond the tile like the renderer.
        """
        x, y = self._grid(E, N, self.metres_per_px * GROUND_SCALE)
        return _bilinear_mirror(self.ground, x - 0.5, y - 0.5)

    def surface_height(self, E: ArrayLike, N: ArrayLike) -> np.ndarray:
        """Height of the surface (terrain + structures) of the texel containing ``(E, N)``."""
        x, y = self._grid(E, N, self.metres_per_px)
        H, W = self.shape
        i = _mirror_index(np.floor(x).astype(np.int64), W)
        j = _mirror_index(np.floor(y).astype(np.int64), H)
        return self.height[j, i].astype(np.float64)

    def clearance(self, E: ArrayLike, N: ArrayLike) -> np.ndarray:
        """Conservative maximum surface height (metres, absolute) within at least 8 m of (E, N).

        A camera at height ``U > clearance(E, N)`` is outside all geometry within 8 m horizontally.
        """
        x, y = self._grid(E, N, self.metres_per_px * 8)
        hh, ww = self.clear.shape
        i = _mirror_index(np.floor(x).astype(np.int64), ww)
        j = _mirror_index(np.floor(y).astype(np.int64), hh)
        return self.clear[j, i].astype(np.float64)


def dilate3(a: np.ndarray) -> np.ndarray:
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
