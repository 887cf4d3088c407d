"""Offline UAV / satellite image simulator: procedural 2.5D cities and a numba ray caster.

Public API (paper Sec. 3.1 and 3.5; frames and conventions in DEVELOPERS.md):

``STYLES``
    ``("oxford", "cambridge", "london", "industrial")``: train on the first two, test on london
    (generalized split); industrial is the flight-test analogue.
``GENERATOR_VERSION``
    Bumped whenever generated pixels change; part of the city cache key and the dataset manifest.
``build_city(style, seed, *, cache_dir=None, size_m=(3584, 2560), metres_per_px=1.0) -> City``
    Deterministic; cached on disk under (style, seed, size, resolution, GENERATOR_VERSION).
``changed_city(city, seed) -> City``
    The same place at an earlier time: other sun and season, moved cars, demolished/added
    buildings, changed trees (for the flight-test satellite images).
``City``
    ``extent``, ``metres_per_px``, ``ground_height(E, N)``, ``surface_height(E, N)``,
    ``clearance(E, N)``, ``max_structure_height``, ``flight_centres`` (K, 2), ``ortho_image()``.
``Camera(width, height, fov_deg)``
    Pinhole, horizontal FOV, square pixels, pixel centres on integer (u, v).
``render_uav(city, position_enu, yaw, pitch, roll, camera, *, supersample=1) -> (H, W, 3) uint8``
``render_satellite(city, centre_en, *, height_m=1000, footprint_m=(2000, 1000), size) -> uint8``
``satellite_pose(city, centre_en, *, height_m=1000) -> (position (3,), (yaw, pitch, roll))``
``project_enu_to_pixel(points_enu, position_enu, yaw, pitch, roll, camera) -> (uv (N, 2), mask)``

Heights: ENU U is absolute (metres above the tile's mean terrain level); a UAV flying "100 m above
ground" is at ``U = city.ground_height(E, N) + 100``.
"""

from benchmark.sim.camera import Camera, euler_to_rotmat_np, project_enu_to_pixel
from benchmark.sim.render import render_satellite, render_uav, satellite_camera, satellite_pose
from benchmark.sim.world import GENERATOR_VERSION, STYLES, City, build_city, changed_city

__all__ = [
    "GENERATOR_VERSION",
    "STYLES",
    "Camera",
    "City",
    "build_city",
    "changed_city",
    "euler_to_rotmat_np",
    "project_enu_to_pixel",
    "render_satellite",
    "render_uav",
    "satellite_camera",
    "satellite_pose",
]
