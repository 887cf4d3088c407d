"""Offline UAV / satellite image simulator: procedural 2.5D cities and a numba ray caster.

Public API (paper Sec. 3.1 and 3.5; frames and conventions in DEVELOPERS.md):

``STYLES``
    ``("oxford", "cambridge", "london", "industrial")``: train on the first two, test on london
    (generalized split); industrial is the flight-test analogue.
``GENERATOR_VERSION``
    Bumped whenever generated pixels change; part of the city cache key and the dataset manifest.
``source_digest(modules=None) -> str``
    sha256 (12 hex) of the simulator's source; the city-building modules' digest is part of the
    city cache key, the whole package's is part of the dataset config, so neither a cached city
    nor a dataset outlives the code that made it.
``build_city(style, seed, *, cache_dir=None, size_m=(3584, 2560), metres_per_px=1.0,
n_lights=8, progress=False) -> City``
    Deterministic; cached on disk under (style, seed, size, resolution, K, GENERATOR_VERSION) in
    ``cache_dir`` (default ``$UAVBENCH_CACHE`` or ``~/.cache/uavbench/cities``; False: no cache).
    About 20 s and 1.7 GB peak to build a full tile with its 8 illumination states; cached cities
    load memory-mapped (400 MB; costs in world.py).
``changed_city(city, seed, *, cache_dir=None) -> City``
    The same place at an earlier time (Sec. 3.5): another season with its own low suns (autumn
    colours or bare winter trees), re-drawn cars, trailers, containers and trains, demolished and
    added buildings, changed trees, solar panels not yet installed.
``City``
    ``extent`` (E_min, E_max, N_min, N_max), ``origin``, ``metres_per_px``,
    ``ground_height(E, N)`` (terrain), ``surface_height(E, N)`` (terrain + structures),
    ``clearance(E, N)`` (max surface height within 8 m), ``max_structure_height``,
    ``flight_centres`` (6, 2), ``ortho_image(light=0)`` (north-up), ``with_rasters(...)``
    (edited copy). Illumination states: ``n_lights`` (K), ``light_suns`` (K, 3) unit ENU vectors
    towards the sun, ``light_angles(k)`` (azimuth clockwise from north in [0, 2 pi), elevation),
    radians, ``light_ortho(k)``; ``sun`` and ``ortho`` are state 0's.
``Camera(width, height, fov_deg)``, ``Camera.square(size, fov_deg)``
    Pinhole, horizontal FOV, square pixels, pixel centres on integer (u, v).
``render_uav(city, position_enu, yaw, pitch, roll, camera, *, supersample=1, light=0,
visibility_m=None) -> (H, W, 3) uint8``
    Lit by illumination state ``light`` (texture and facade sun), fog distance ``visibility_m``
    (None: 2600 m). About 25-30 ms per 224 px and 6-8 ms per 96 px frame on one core (CPU time).
``render_satellite(city, centre_en, *, height_m=1000, footprint_m=(2000, 1000), size=224,
light=0)``
    North-up nadir perspective view squashed to ``size x size`` (INTER_AREA), ~0.2 s; no haze.
``satellite_pose(city, centre_en, *, height_m=1000) -> (position (3,), (yaw, pitch, roll))``
``project_enu_to_pixel(points_enu, position_enu, yaw, pitch, roll, camera) -> (uv (N, 2), mask)``
``detmath``
    The ISA-independent primitives every float computation of the simulator and the camera model
    goes through (libm transcendentals, fixed-order matrix products and filters): the same dataset
    bytes on every x86-64 CPU with FMA (issue 20; ``benchmark/sim/detmath.py`` says why).

``FlightSpec``, ``generate_flight(...)``
    Flight curves around a centre (``benchmark.sim.flights``).
``make_plan(profile, cities, seed) -> Plan``, ``city_seed(seed, style)``, ``sample_seed(seed, i)``
    The dataset plan (flights, splits, labels; ``benchmark.sim.splits``, imported on first use, it
    pulls in pandas and scipy) and the seeds of worlds and renders (``benchmark.sim.seeds``).
``CONFIRM_SPLITS``, ``CONFIRMS``
    The confirmation draw's splits, and the test split each one repeats (``standard/test`` ->
    ``confirm/standard``, ...; issue 38).
``LONG_SPLITS``
    ``("long/standard", "long/towns", "long/london")``: test-only flights of >= 60 s for the
    flight-fusion curves (issue 39; ``benchmark.sim.splits``).
``ODOMETRY_COLUMNS``, ``OdometryNoise``, ``odometry_noise(profile)``, ``flight_odometry(E, N, U,
yaw, time_s, *, noise, rng) -> (K, 4)``, ``odometry_rng(seed, flight)``, ``plan_odometry(...)``
    The odometry every UAV sample carries (``odo_dyaw`` rad, ``odo_dx odo_dy odo_dz`` m in the
    levelled heading frame of the previous sample; NaN on a flight's first sample) and its noise
    model (``benchmark.sim.odometry``; imported on first use).
``town_list(n_towns, seed) -> [Town]``, ``build_town(town, size_m=, metres_per_px=)``
    The many-towns family (``benchmark.sim.towns``; imported on first use).

Heights: ENU U is absolute (metres, zero = the tile's mean terrain level); a UAV flying "100 m
above ground" is at ``U = city.ground_height(E, N) + 100``. The satellite camera is ``height_m``
above the terrain at its centre.
"""

import os
from typing import Any

# numba may vectorise libm calls in our kernels with Intel SVML when the icc_rt package is
# installed; SVML's last bits differ from glibc's. Off unless the user asks (before numba loads).
os.environ.setdefault("NUMBA_DISABLE_INTEL_SVML", "1")

from benchmark.sim import detmath
from benchmark.sim.camera import Camera, euler_to_rotmat_np, project_enu_to_pixel
from benchmark.sim.flights import FlightSpec, generate_flight
from benchmark.sim.render import render_satellite, render_uav, satellite_camera, satellite_pose
from benchmark.sim.seeds import city_seed, sample_seed
from benchmark.sim.world import (
    GENERATOR_VERSION,
    STYLES,
    City,
    build_city,
    changed_city,
    source_digest,
)

__all__ = [
    "CONFIRMS",
    "CONFIRM_SPLITS",
    "GENERATOR_VERSION",
    "LONG_SPLITS",
    "ODOMETRY_COLUMNS",
    "STYLES",
    "TOWN_ROLES",
    "Camera",
    "City",
    "FlightSpec",
    "OdometryNoise",
    "Town",
    "build_city",
    "build_town",
    "changed_city",
    "city_seed",
    "detmath",
    "euler_to_rotmat_np",
    "flight_odometry",
    "generate_flight",
    "make_plan",
    "odometry_noise",
    "odometry_rng",
    "plan_odometry",
    "project_enu_to_pixel",
    "render_satellite",
    "render_uav",
    "sample_seed",
    "satellite_camera",
    "satellite_pose",
    "source_digest",
    "town_list",
]

# Imported on first access (PEP 562): render workers import this package and need none of them.
_FROM_SPLITS = ("CONFIRMS", "CONFIRM_SPLITS", "LONG_SPLITS", "make_plan")
_FROM_TOWNS = ("TOWN_ROLES", "Town", "build_town", "town_list")
_FROM_ODOMETRY = (
    "ODOMETRY_COLUMNS",
    "OdometryNoise",
    "flight_odometry",
    "odometry_noise",
    "odometry_rng",
    "plan_odometry",
)


def __getattr__(name: str) -> Any:
    if name in _FROM_SPLITS:
        from benchmark.sim import splits

        return getattr(splits, name)
    if name in _FROM_TOWNS:
        from benchmark.sim import towns

        return getattr(towns, name)
    if name in _FROM_ODOMETRY:
        from benchmark.sim import odometry

        return getattr(odometry, name)
    raise AttributeError(f"module 'benchmark.sim' has no attribute {name!r}")
