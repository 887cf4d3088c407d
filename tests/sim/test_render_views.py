"""Tests of the renderer against closed forms and the geometry core.

References are independent of the renderer: scipy's Rotation and ``benchmark.geometry`` for the
attitude, the pinhole closed form for projections, ``v = cy + f tan(pitch)`` for the horizon row,
``gsd = H / f`` for the satellite and ``r H / (H - h)`` for relief displacement. Markers are
magenta boxes written into the city rasters (``City.with_rasters``), found by colour in the image.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from benchmark.geometry import euler_to_rotmat
from benchmark.sim import (
    Camera,
    build_city,
    euler_to_rotmat_np,
    project_enu_to_pixel,
    render_satellite,
    render_uav,
    satellite_pose,
)
from benchmark.sim.render_core import MAT_BUILDING

MAGENTA = np.array([255, 0, 255], np.uint8)


@pytest.fixture(scope="module")
def city():
    return build_city("oxford", 11, cache_dir=False, size_m=(512.0, 512.0))


@pytest.fixture(scope="module")
def flat(city):
    """The same city flattened to U = 0 everywhere (no relief, no buildings), textures kept."""
    return city.with_rasters(
        height=np.zeros_like(city.height),
        mat=np.zeros_like(city.mat),
        ground=np.zeros_like(city.ground),
    )


def add_box(city, e, n, half, top, *, building=True):
    """A box of half-width ``half`` metres centred at (e, n) with a magenta top at U = ``top``."""
    e0, n0 = city.origin
    i0 = round((e - half - e0) / city.metres_per_px)
    i1 = round((e + half - e0) / city.metres_per_px)
    j0 = round((n - half - n0) / city.metres_per_px)
    j1 = round((n + half - n0) / city.metres_per_px)
    height = city.height.copy()
    ortho = city.ortho.copy()
    mat = city.mat.copy()
    height[j0:j1, i0:i1] = top
    ortho[j0:j1, i0:i1] = MAGENTA
    if building:
        mat[j0:j1, i0:i1] = MAT_BUILDING
    centre = (e0 + 0.5 * (i0 + i1) * city.metres_per_px, n0 + 0.5 * (j0 + j1) * city.metres_per_px)
    return city.with_rasters(height=height, ortho=ortho, mat=mat), centre


def magenta_centroid(img):
    m = (img[..., 0] > 200) & (img[..., 1] < 70) & (img[..., 2] > 200)
    assert m.sum() >= 3, "marker not visible"
    rows, cols = np.nonzero(m)
    return np.array([cols.mean(), rows.mean()]), int(m.sum())


class TestProjectEnuToPixel:
    @pytest.mark.parametrize("seed", [0, 1, 2])
    def test_matches_geometry_core_and_scipy(self, seed):
        rng = np.random.default_rng(seed)
        yaw, pitch, roll = rng.uniform(-3, 3), rng.uniform(-0.9, 0.2), rng.uniform(-0.2, 0.2)
        pos = rng.uniform(-50, 50, 3)
        pts = pos + rng.normal(0, 80, (20, 3))
        cam = Camera(96, 64, 70.0)
        uv, front = project_enu_to_pixel(pts, pos, yaw, pitch, roll, cam)
        R_core = euler_to_rotmat(
            torch.tensor(yaw, dtype=torch.float64),
            torch.tensor(pitch, dtype=torch.float64),
            torch.tensor(roll, dtype=torch.float64),
        ).numpy()
        R_scipy = Rotation.from_euler("ZXY", [yaw, pitch, roll]).as_matrix()
        np.testing.assert_allclose(euler_to_rotmat_np(yaw, pitch, roll), R_core, atol=1e-12)
        np.testing.assert_allclose(R_core, R_scipy, atol=1e-12)
        body = (pts - pos) @ R_scipy
        f = 48.0 / math.tan(math.radians(35.0))
        exp = np.stack([47.5 + f * body[:, 0] / body[:, 1], 31.5 - f * body[:, 2] / body[:, 1]], 1)
        np.testing.assert_array_equal(front, body[:, 1] > 0)
        np.testing.assert_allclose(uv[front], exp[front], atol=1e-9)
        assert np.all(np.isnan(uv[~front]))

    def test_convention_yaw_zero_looks_north_yaw_90_west(self):
        cam = Camera.square(64, 60.0)
        pos = np.zeros(3)
        north = np.array([[0.0, 100.0, 0.0]])
        west = np.array([[-100.0, 0.0, 0.0]])
        uv, front = project_enu_to_pixel(north, pos, 0.0, 0.0, 0.0, cam)
        assert front[0] and np.allclose(uv[0], [31.5, 31.5])
        uv, front = project_enu_to_pixel(west, pos, math.pi / 2, 0.0, 0.0, cam)
        assert front[0] and np.allclose(uv[0], [31.5, 31.5])
        # Nose-up pitch puts a point straight ahead below the image centre (v grows downwards).
        uv, _ = project_enu_to_pixel(north, pos, 0.0, 0.2, 0.0, cam)
        assert uv[0, 1] > 31.5
        # Positive roll (right wing down) moves a point right of the axis upwards in the image.
        uv, _ = project_enu_to_pixel(np.array([[30.0, 100.0, 0.0]]), pos, 0.0, 0.0, 0.3, cam)
        assert uv[0, 1] < 31.5

    def test_bad_input(self):
        cam = Camera.square(32)
        with pytest.raises(ValueError, match="points_enu"):
            project_enu_to_pixel(np.zeros((3, 2)), np.zeros(3), 0, 0, 0, cam)
        with pytest.raises(ValueError, match="pitch"):
            project_enu_to_pixel(np.zeros((1, 3)), np.zeros(3), 0, float("nan"), 0, cam)


class TestRenderUav:
    def test_deterministic_and_seed_dependent(self, city):
        cam = Camera.square(48, 60.0)
        pos = np.array([10.0, -20.0, city.ground_height(10.0, -20.0) + 90.0])
        a = render_uav(city, pos, 0.4, -0.5, 0.05, cam)
        b = render_uav(city, pos, 0.4, -0.5, 0.05, cam)
        assert a.shape == (48, 48, 3) and a.dtype == np.uint8
        assert a.tobytes() == b.tobytes()
        other = build_city("oxford", 12, cache_dir=False, size_m=(512.0, 512.0))
        c = render_uav(other, pos + np.array([0.0, 0.0, 20.0]), 0.4, -0.5, 0.05, cam)
        assert np.mean(np.abs(a.astype(int) - c.astype(int))) > 10.0

    @pytest.mark.parametrize(
        "pose", [(0.3, -0.6, 0.0), (2.0, -0.9, 0.1), (-1.2, -0.35, -0.15), (0.0, -1.4, 0.0)]
    )
    def test_marker_lands_where_projection_predicts(self, city, pose):
        yaw, pitch, roll = pose
        marked, (e, n) = add_box(city, 30.0, 40.0, 3.0, city.ground_height(30.0, 40.0) + 25.0)
        top = float(marked.surface_height(e, n))
        R = Rotation.from_euler("ZXY", [yaw, pitch, roll]).as_matrix()
        # Put the camera 110 m from the marker top, looking at it along body +y.
        pos = np.array([e, n, top]) - 110.0 * R[:, 1]
        cam = Camera.square(96, 50.0)
        img = render_uav(marked, pos, yaw, pitch, roll, cam, supersample=2)
        got, area = magenta_centroid(img)
        uv, front = project_enu_to_pixel(np.array([[e, n, top]]), pos, yaw, pitch, roll, cam)
        assert front[0]
        np.testing.assert_allclose(uv[0], [47.5, 47.5], atol=1e-6)
        np.testing.assert_allclose(got, uv[0], atol=0.6)
        # The 6 m top seen from 110 m covers about (6 f / 110)^2 |cos| pixels.
        f = cam.focal_px
        assert area <= (6.0 * f / 110.0 + 2) ** 2

    def test_marker_off_axis(self, flat):
        marked, (e, n) = add_box(flat, -20.0, 40.0, 5.0, 0.0, building=False)
        pos = np.array([5.0, -30.0, 70.0])
        yaw, pitch, roll = 0.2, -0.55, 0.08
        cam = Camera(80, 60, 70.0)
        img = render_uav(marked, pos, yaw, pitch, roll, cam, supersample=3)
        got, _ = magenta_centroid(img)
        uv, _ = project_enu_to_pixel(np.array([[e, n, 0.0]]), pos, yaw, pitch, roll, cam)
        np.testing.assert_allclose(got, uv[0], atol=0.6)

    @pytest.mark.parametrize("pitch_deg", [-20.0, -8.0, 0.0, 6.0])
    def test_horizon_row_matches_pitch(self, city, flat, pitch_deg):
        # Above the horizon only sky is visible, identical for any world; below, the worlds differ.
        cam = Camera.square(64, 60.0)
        pitch = math.radians(pitch_deg)
        pos = np.array([0.0, 0.0, 150.0])
        a = render_uav(city, pos, 0.7, pitch, 0.0, cam).astype(int)
        b = render_uav(flat, pos, 0.7, pitch, 0.0, cam).astype(int)
        differs = np.abs(a - b).max(axis=(1, 2)) > 2
        v_h = cam.principal_point[1] + cam.focal_px * math.tan(pitch)
        first = int(np.argmax(differs))
        assert differs.any()
        assert not differs[: max(0, math.floor(v_h))].any()
        assert v_h - 1.0 <= first <= v_h + 6.0, (first, v_h)

    def test_sky_has_horizon_haze(self, city):
        cam = Camera.square(64, 60.0)
        img = render_uav(city, np.array([0.0, 0.0, 100.0]), 0.0, 0.0, 0.0, cam).astype(float)
        top, near_horizon = img[0], img[30]
        assert top[:, 2].mean() > top[:, 0].mean() + 40  # blue zenith
        assert near_horizon.std(axis=1).mean() < top.std(axis=1).mean() + 20  # greyish haze
        assert near_horizon.mean() > top.mean()

    def test_bad_pose_raises_naming_value(self, city):
        cam = Camera.square(32)
        with pytest.raises(ValueError, match="position_enu must be finite"):
            render_uav(city, np.array([0.0, np.inf, 100.0]), 0, 0, 0, cam)
        with pytest.raises(ValueError, match="yaw"):
            render_uav(city, np.array([0.0, 0.0, 100.0]), float("nan"), 0, 0, cam)
        g = float(city.ground_height(0.0, 0.0))
        with pytest.raises(ValueError, match="inside the geometry"):
            render_uav(city, np.array([0.0, 0.0, g - 5.0]), 0, 0, 0, cam)
        j, i = np.argwhere(city.mat >= MAT_BUILDING)[0]
        e0, n0 = city.origin
        e, n = e0 + i + 0.5, n0 + j + 0.5
        with pytest.raises(ValueError, match="inside the geometry"):
            render_uav(city, np.array([e, n, city.height[j, i] - 1.0]), 0, 0, 0, cam)
        with pytest.raises(TypeError, match="Camera"):
            render_uav(city, np.array([0.0, 0.0, 100.0]), 0, 0, 0, (32, 32, 60.0))
        with pytest.raises(ValueError, match="supersample"):
            render_uav(city, np.array([0.0, 0.0, 100.0]), 0, 0, 0, cam, supersample=0)


class TestRenderSatellite:
    def test_convention_pose_is_paper_eq5(self, city):
        pos, (yaw, pitch, roll) = satellite_pose(city, np.array([10.0, 20.0]), height_m=800.0)
        np.testing.assert_allclose(pos, [10.0, 20.0, city.ground_height(10.0, 20.0) + 800.0])
        R = euler_to_rotmat_np(yaw, pitch, roll)
        np.testing.assert_allclose(R[:, 1], [0, 0, -1], atol=1e-12)  # looks down
        np.testing.assert_allclose(R[:, 2], [0, 1, 0], atol=1e-12)  # image up = north
        q = Rotation.from_matrix(R).as_quat()  # x, y, z, w
        np.testing.assert_allclose(
            np.abs([q[3], q[0], q[1], q[2]]), [0.7071, 0.7071, 0, 0], atol=1e-4
        )

    @pytest.mark.parametrize("height_m", [300.0, 600.0])
    def test_ground_sampling_distance(self, flat, height_m):
        # Two markers 160 m apart east-west and 100 m north: pixel offsets = metres / gsd.
        m1, (e1, n1) = add_box(flat, -80.0, 0.0, 8.0, 0.0, building=False)
        m2, (e2, n2) = add_box(m1, 80.0, 100.0, 8.0, 0.0, building=False)
        fe, fn = 400.0, 400.0
        size = 100
        img = render_satellite(
            m2,
            np.array([0.0, 0.0]),
            height_m=height_m,
            footprint_m=(fe, fn),
            size=size,
            oversample=1.0,
        )
        mask = (img[..., 0] > 200) & (img[..., 1] < 70) & (img[..., 2] > 200)
        rows, cols = np.nonzero(mask)
        west = cols < size / 2
        c1 = np.array([cols[west].mean(), rows[west].mean()])
        c2 = np.array([cols[~west].mean(), rows[~west].mean()])
        gsd = fe / size  # 4 m: the camera's focal length is size * H / fe
        np.testing.assert_allclose(c2 - c1, [(e2 - e1) / gsd, -(n2 - n1) / gsd], atol=0.3)
        np.testing.assert_allclose(c1, [49.5 + e1 / gsd, 49.5 - n1 / gsd], atol=0.3)

    def test_anisotropic_squash_like_the_paper(self, flat):
        # A 2:1 footprint is squashed to a square: E metres per pixel are twice N's.
        m1, (_e1, _n1) = add_box(flat, -100.0, -50.0, 4.0, 0.0, building=False)
        m2, (_e2, _n2) = add_box(m1, 100.0, 50.0, 4.0, 0.0, building=False)
        img = render_satellite(
            m2, np.array([0.0, 0.0]), height_m=500.0, footprint_m=(480.0, 240.0), size=120
        )
        mask = (img[..., 0] > 160) & (img[..., 1] < 110) & (img[..., 2] > 160)
        rows, cols = np.nonzero(mask)
        w = cols < 60
        d = np.array([cols[~w].mean() - cols[w].mean(), rows[~w].mean() - rows[w].mean()])
        np.testing.assert_allclose(d, [200.0 * 120 / 480.0, -100.0 * 120 / 240.0], atol=0.5)

    def test_relief_displacement_closed_form(self, flat):
        # A 100 m tower 150 m east and 60 m north of nadir, camera 500 m up: its top appears at
        # r H / (H - h) from the nadir point, i.e. displaced outwards by r h / (H - h).
        H, h = 500.0, 100.0
        marked, (e, n) = add_box(flat, 150.0, 60.0, 4.0, h)
        size = 256
        fe = 512.0
        img = render_satellite(
            marked,
            np.array([0.0, 0.0]),
            height_m=H,
            footprint_m=(fe, fe),
            size=size,
            oversample=1.0,
        )
        got, _ = magenta_centroid(img)
        f = size * H / fe
        exp = np.array([127.5 + f * e / (H - h), 127.5 - f * n / (H - h)])
        np.testing.assert_allclose(got, exp, atol=0.5)
        ground_only = np.array([127.5 + f * e / H, 127.5 - f * n / H])
        disp = got - ground_only
        assert disp[0] > 0 and disp[1] < 0  # outwards: further east and further north
        np.testing.assert_allclose(
            np.hypot(*disp), f * math.hypot(e, n) * h / (H * (H - h)), rtol=0.05
        )

    def test_output_and_bad_input(self, city):
        img = render_satellite(
            city, np.array([0.0, 0.0]), height_m=400.0, footprint_m=(300.0, 150.0), size=32
        )
        assert img.shape == (32, 32, 3) and img.dtype == np.uint8 and img.std() > 5
        with pytest.raises(ValueError, match="centre_en"):
            render_satellite(city, np.array([np.nan, 0.0]), size=32)
        with pytest.raises(ValueError, match="size"):
            render_satellite(city, np.array([0.0, 0.0]), size=0)
        with pytest.raises(ValueError, match="footprint_m"):
            render_satellite(city, np.array([0.0, 0.0]), size=32, footprint_m=(-1.0, 5.0))


class TestMirrorTiling:
    def test_convention_mirrored_copy_renders_the_mirror_image(self, city):
        # Beyond the eastern edge the world is the tile reflected in E = E_max: a camera reflected
        # there (E -> 2 E_max - E, yaw -> -yaw, roll -> -roll) sees the left-right flipped image.
        _, e_max, _, _ = city.extent
        cam = Camera.square(64, 70.0)
        e, n = e_max - 60.0, 15.0
        u = float(city.ground_height(e, n)) + 70.0
        yaw, pitch, roll = 1.1, -0.45, 0.07
        a = render_uav(city, np.array([e, n, u]), yaw, pitch, roll, cam).astype(int)
        b = render_uav(city, np.array([2 * e_max - e, n, u]), -yaw, pitch, -roll, cam).astype(int)
        diff = np.abs(a - b[:, ::-1])
        assert np.mean(diff) < 1.0 and np.percentile(diff, 99) <= 8
