"""A small rendered scene for the reference tests: one town, two satellite images of different
places in it, UAV frames around the first place at the quick profile's 96 px.

The satellite images cover 600 m x 450 m (a 4:3 footprint squashed to a square image: anisotropic
ground sampling, as the dataset's 2:1) so that both fit in a 1.5 km x 1 km town that builds in a
few seconds; the geometry is the dataset's (``render_satellite``, ``satellite_pose``).

Each rendered pair is a :class:`View`, which keeps its whole true pose for the tests to compare
with; a reference is served ``view.frame_for(reference)``, which holds only what it is given.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from benchmark.references import Frame, Reference, SatelliteGrid, TrueValues
from benchmark.sim import (
    Camera,
    build_city,
    render_satellite,
    render_uav,
    satellite_pose,
    town_list,
)

SIZE = 96
FOOTPRINT_M = (600.0, 450.0)
SAT_HEIGHT_M = 1000.0
CENTRES = (np.array([-330.0, 0.0]), np.array([330.0, 0.0]))


@dataclass(frozen=True)
class View:
    """One rendered pair and its whole true pose (``position`` ``(3,)`` absolute ENU metres;
    ``yaw``, ``pitch``, ``roll`` radians)."""

    uav: np.ndarray
    sat: np.ndarray
    grid: SatelliteGrid
    camera: Camera
    position: np.ndarray
    yaw: float
    pitch: float
    roll: float

    def frame_for(self, reference: Reference) -> Frame:
        """The frame ``reference`` is served: the images and only its given true values."""
        e, n, u = (float(x) for x in self.position)
        pose = {"E": e, "N": n, "U": u, "yaw": self.yaw, "pitch": self.pitch, "roll": self.roll}
        truth = TrueValues.select(pose, reference.given_columns)
        return Frame(self.uav, self.sat, self.grid, self.camera, truth)


@dataclass
class Scene:
    frames: list[View]  # oblique UAV views around CENTRES[0], its own satellite image
    swapped: list[View]  # the same frames served the satellite image of CENTRES[1]
    steep: list[View]  # steeper oblique views (pitch -65 to -55 deg, 120-150 m)
    nadir: list[View]  # near-nadir views (pitch -80 deg, 500 m) lit as the satellite image was
    city: object
    grids: tuple[SatelliteGrid, SatelliteGrid]
    sats: tuple[np.ndarray, np.ndarray]


def build_scene(cache_dir, n_frames: int = 8, n_other: int = 5, seed: int = 5) -> Scene:
    """The scene; ``cache_dir`` holds the built town (a temporary directory in the tests)."""
    town = town_list((1, 0, 0, 0), seed)[0]
    # Two illumination states instead of eight: the town builds in a few seconds.
    city = build_city(
        town.style, town.seed, size_m=(1536.0, 1024.0), metres_per_px=2.0, n_lights=2,
        cache_dir=cache_dir,
    )  # fmt: skip
    camera = Camera.square(SIZE, 60.0)
    grids, sats = [], []
    for centre in CENTRES:
        pos, _ = satellite_pose(city, centre, height_m=SAT_HEIGHT_M)
        sats.append(
            render_satellite(
                city, centre, height_m=SAT_HEIGHT_M, footprint_m=FOOTPRINT_M, size=SIZE, light=0
            )
        )
        ground = float(pos[2]) - SAT_HEIGHT_M
        grids.append(SatelliteGrid((float(centre[0]), float(centre[1])), ground, FOOTPRINT_M, SIZE))
    rng = np.random.default_rng(seed)
    # (list, count, height above ground (m), pitch range (deg), roll range (deg), light)
    kinds = (
        ([], n_frames, (80.0, 120.0), (-45.0, -15.0), 5.0, 1),
        ([], n_other, (120.0, 150.0), (-65.0, -55.0), 5.0, 1),
        ([], n_other, (500.0, 500.0), (-80.0, -80.0), 0.0, 0),
    )
    for out, count, heights, pitches, rolls, light in kinds:
        while len(out) < count:
            e, n = CENTRES[0] + rng.uniform(-80.0, 80.0, 2)
            ground = float(city.ground_height(np.array([e]), np.array([n]))[0])
            position = np.array([e, n, ground + rng.uniform(*heights)])
            pitch = math.radians(rng.uniform(*pitches))
            roll = math.radians(rng.uniform(-rolls, rolls))
            yaw = rng.uniform(-math.pi, math.pi)
            try:
                uav = render_uav(city, position, yaw, pitch, roll, camera, light=light)
            except ValueError:  # inside a building: draw again
                continue
            out.append(View(uav, sats[0], grids[0], camera, position, yaw, pitch, roll))
    frames, steep, nadir = (k[0] for k in kinds)
    swapped = [dataclasses.replace(f, sat=sats[1]) for f in frames]
    return Scene(frames, swapped, steep, nadir, city, (grids[0], grids[1]), (sats[0], sats[1]))


def yaw_error_deg(R_bn: np.ndarray, yaw: float) -> float:
    """|wrapped yaw of R_b^n - yaw| in degrees (R_b^n = Rz(yaw) Rx(pitch) Ry(roll))."""
    # Rz(yaw) Rx(pitch) Ry(roll): column 1 (body forward) = (-sin y cos p, cos y cos p, sin p)
    est = math.atan2(-R_bn[0, 1], R_bn[1, 1])
    return abs(math.degrees(math.remainder(est - yaw, 2 * math.pi)))
