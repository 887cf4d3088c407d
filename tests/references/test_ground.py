"""Ground-plane geometry against the camera model (benchmark/sim/camera.py is the truth)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from benchmark.references import SatelliteGrid, cast_uav_pixels, rotate_offsets
from benchmark.sim import Camera, project_enu_to_pixel, satellite_camera


class TestSatelliteGrid:
    @pytest.mark.parametrize(
        ("footprint", "size", "metres_per_px"),
        [((2000.0, 1000.0), 96, 1.0), ((2000.0, 1000.0), 32, 2.0), ((600.0, 450.0), 96, 2.0)],
    )
    def test_lift_agrees_with_project_enu_to_pixel(self, footprint, size, metres_per_px):
        # The satellite render: a nadir pinhole of w x h square pixels (render_satellite's sizes),
        # then INTER_AREA to size x size: destination x <-> source (x + 0.5) w / size - 0.5.
        height, centre, ground = 1000.0, (123.0, -45.0), 17.5
        gsd = max(metres_per_px, footprint[0] / (4.0 * size))
        w, h, f = satellite_camera(footprint, height, gsd)
        fov = math.degrees(2.0 * math.atan(0.5 * w / f))
        cam = Camera(w, h, fov)
        grid = SatelliteGrid(centre, ground, footprint, size)
        rng = np.random.default_rng(0)
        xy = rng.uniform(0, size - 1, (50, 2))
        points = grid.pixel_to_enu(xy[:, 0], xy[:, 1])
        assert np.allclose(points[:, 2], ground)
        sat_pos = np.array([centre[0], centre[1], ground + height])
        uv, front = project_enu_to_pixel(points, sat_pos, 0.0, -math.pi / 2, 0.0, cam)
        assert front.all()
        x = (uv[:, 0] + 0.5) * size / w - 0.5
        y = (uv[:, 1] + 0.5) * size / h - 0.5
        assert np.allclose(x, xy[:, 0], atol=1e-6)
        assert np.allclose(y, xy[:, 1], atol=1e-6)
        back = grid.enu_to_pixel(points[:, 0], points[:, 1])
        assert np.allclose(np.stack(back, 1), xy, atol=1e-9)

    def test_convention_north_up_anisotropic(self):
        grid = SatelliteGrid((0.0, 0.0), 0.0, (2000.0, 1000.0), 96)
        assert grid.metres_per_px == pytest.approx((2000 / 96, 1000 / 96))
        x0, y0 = grid.offset_to_pixel(np.array(0.0), np.array(0.0))
        x1, y1 = grid.offset_to_pixel(np.array(100.0), np.array(100.0))  # north-east
        assert x1 - x0 == pytest.approx(100 / (2000 / 96))  # east = right
        assert y1 - y0 == pytest.approx(-100 / (1000 / 96))  # north = up

    def test_bad_footprint_is_named(self):
        with pytest.raises(ValueError, match="footprint_m"):
            SatelliteGrid((0.0, 0.0), 0.0, (0.0, 1000.0), 96)


class TestCastUavPixels:
    @pytest.mark.parametrize(
        ("yaw", "pitch", "roll"),
        [(0.3, -0.2, 0.05), (-2.5, -0.7, -0.08), (math.pi, -0.05, 0.0), (1.2, -1.2, 0.1)],
    )
    def test_round_trip_through_project_enu_to_pixel(self, yaw, pitch, roll):
        cam = Camera.square(96, 60.0)
        position, ground = np.array([10.0, -20.0, 130.0]), 30.0
        cast = cast_uav_pixels(cam, pitch, roll, position[2] - ground, max_range_m=2000.0)
        assert len(cast.rows) > 100
        de, dn = rotate_offsets(cast.offsets, np.array([yaw]))
        points = np.stack(
            [position[0] + de[0], position[1] + dn[0], np.full(de.shape[1], ground)], axis=1
        )
        uv, front = project_enu_to_pixel(points, position, yaw, pitch, roll, cam)
        assert front.all()
        assert np.allclose(uv[:, 0], cast.cols, atol=1e-6)
        assert np.allclose(uv[:, 1], cast.rows, atol=1e-6)
        assert np.allclose(np.hypot(de[0], dn[0]), cast.ranges)
        assert cast.ranges.max() <= 2000.0

    def test_level_camera_sees_ground_below_the_principal_row_only(self):
        cam = Camera.square(96, 60.0)
        cast = cast_uav_pixels(cam, 0.0, 0.0, 100.0)
        assert cast.rows.min() > cam.principal_point[1]  # the horizon is the middle row
        assert len(cast.rows) == 48 * 96

    def test_convention_yaw_plus_90_looks_west(self):
        cam = Camera.square(32, 60.0)
        cast = cast_uav_pixels(cam, -0.5, 0.0, 100.0)
        de, dn = rotate_offsets(cast.offsets, np.array([0.0, math.pi / 2]))
        assert dn[0].mean() > 0 and abs(de[0].mean()) < 1e-9  # yaw 0: north
        assert de[1].mean() < 0 and abs(dn[1].mean()) < 1e-9  # yaw +90 deg: west

    def test_max_range(self):
        cam = Camera.square(32, 60.0)
        cast = cast_uav_pixels(cam, -0.1, 0.0, 100.0, max_range_m=300.0)
        assert cast.ranges.max() <= 300.0

    def test_uav_below_the_plane_is_named(self):
        with pytest.raises(ValueError, match="height_above_ground_m"):
            cast_uav_pixels(Camera.square(32), -0.3, 0.0, -5.0)
