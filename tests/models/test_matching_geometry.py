"""The matching encoder's camera maths against the simulator's pinhole model (the truth).

``benchmark.models`` may not import ``benchmark.sim``; these tests import both and check
``ground_to_uav_pixel`` / ``sat_pixel_of_offset`` against ``project_enu_to_pixel``, first on
random poses, then on rendered images (a magenta ground patch lands where both say).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from benchmark.models.matching_geometry import (
    focal_px,
    ground_to_uav_pixel,
    offset_grid,
    pixel_to_grid,
    rotate_to_level,
    sat_pixel_of_offset,
)
from benchmark.models.matching_ops import bev_templates, bev_templates_planes, sat_grid
from benchmark.sim.camera import Camera, project_enu_to_pixel

MAGENTA = np.array([255, 0, 255], np.uint8)


def _sim_uav_pixel(offset_en, yaw, pitch, roll, altitude, size, fov_deg):
    point = np.array([[offset_en[0], offset_en[1], 0.0]])
    uv, front = project_enu_to_pixel(
        point, np.array([0.0, 0.0, altitude]), yaw, pitch, roll, Camera.square(size, fov_deg)
    )
    return uv[0], bool(front[0])


class TestFocalPx:
    def test_matches_camera(self):
        for size, fov in ((96, 60.0), (224, 75.0), (32, 30.0)):
            f = focal_px(size, torch.tensor(math.radians(fov), dtype=torch.float64))
            assert float(f) == pytest.approx(Camera.square(size, fov).focal_px, rel=1e-12)


class TestRotateToLevel:
    def test_convention_yaw_90_looks_west(self):
        # Yaw +90 deg looks west (DEVELOPERS.md): a point 10 m west is 10 m straight ahead.
        ab = rotate_to_level(
            torch.tensor([[-10.0, 0.0]], dtype=torch.float64),
            torch.tensor(math.pi / 2, dtype=torch.float64),
        )
        assert ab.tolist()[0] == pytest.approx([0.0, 10.0], abs=1e-12)


class TestGroundToUavPixel:
    def test_random_poses_match_project_enu_to_pixel(self):
        rng = np.random.default_rng(0)
        n = 64
        yaw = rng.uniform(-math.pi, math.pi, n)
        pitch = rng.uniform(math.radians(-60), 0.0, n)
        roll = rng.uniform(math.radians(-12), math.radians(12), n)
        alt = rng.uniform(60.0, 130.0, n)
        fov = rng.uniform(45.0, 80.0, n)
        offsets = rng.uniform(-400.0, 400.0, (n, 5, 2))
        level = rotate_to_level(torch.from_numpy(offsets), torch.from_numpy(yaw)[:, None])
        uv, valid = ground_to_uav_pixel(
            level, torch.from_numpy(pitch), torch.from_numpy(roll), torch.from_numpy(alt),
            torch.from_numpy(np.radians(fov)), 96,
        )  # fmt: skip
        checked = 0
        for i in range(n):
            for j in range(5):
                ref, front = _sim_uav_pixel(offsets[i, j], yaw[i], pitch[i], roll[i], alt[i], 96,
                                            fov[i])  # fmt: skip
                inside = front and bool(np.all((ref >= -0.5) & (ref <= 95.5)))
                assert bool(valid[i, j]) == inside
                # Outside the image too, as long as the point is not grazing the camera plane
                # (ours clamps the depth at MIN_DEPTH_M there and masks the point).
                if front and np.all(np.abs(ref) < 2000):
                    np.testing.assert_allclose(uv[i, j].numpy(), ref, atol=1e-8)
                    checked += 1
        assert checked > 50 and int(valid.sum()) > 20

    def test_convention_level_camera_principal_point(self):
        # Pitch -90 deg looks straight down: the point below the camera is the principal point.
        uv, valid = ground_to_uav_pixel(
            torch.zeros(1, 1, 2, dtype=torch.float64), torch.tensor([-math.pi / 2 + 1e-9],
            dtype=torch.float64), torch.zeros(1, dtype=torch.float64),
            torch.tensor([80.0], dtype=torch.float64), torch.tensor([1.0], dtype=torch.float64), 96,
        )  # fmt: skip
        assert bool(valid[0, 0]) and uv[0, 0].tolist() == pytest.approx([47.5, 47.5], abs=1e-6)

    def test_bad_shapes_name_the_field(self):
        with pytest.raises(ValueError, match="pitch"):
            ground_to_uav_pixel(torch.zeros(2, 3, 2), torch.zeros(3), torch.zeros(2),
                                torch.ones(2), torch.ones(2), 96)  # fmt: skip


class TestSatPixelOfOffset:
    @pytest.mark.parametrize("footprint", [(2000.0, 1000.0), (2500.0, 1200.0), (840.0, 420.0)])
    def test_matches_the_satellite_camera(self, footprint):
        # render_satellite: a nadir camera height_m above the centre with square pixels covering
        # the footprint in w x h px, then squashed to S x S (INTER_AREA: output pixel centre j is
        # input coordinate (j + 1/2) w / S - 1/2).
        height, size, gsd = 1000.0, 96, 2.5
        w, h = round(footprint[0] / gsd), round(footprint[1] / gsd)
        f = w * height / footprint[0]
        cam = Camera(w, h, math.degrees(2 * math.atan(0.5 * w / f)))
        rng = np.random.default_rng(1)
        offsets = rng.uniform(-0.5, 0.5, (20, 2)) * np.array(footprint)
        pts = np.c_[offsets, np.zeros(20)]
        uv, _ = project_enu_to_pixel(pts, np.array([0, 0, height]), 0.0, -math.pi / 2, 0.0, cam)
        ref = np.c_[(uv[:, 0] + 0.5) * size / w - 0.5, (uv[:, 1] + 0.5) * size / h - 0.5]
        ours = sat_pixel_of_offset(
            torch.from_numpy(offsets)[None], torch.tensor([footprint], dtype=torch.float64), size
        )[0]
        np.testing.assert_allclose(ours.numpy(), ref, atol=1e-6)


class TestPixelToGrid:
    def test_pooled_cell_centres(self):
        # Stride 2 average pooling: cell j is centred on pixel 2 j + 0.5; cells 0 and n-1 are
        # the grid_sample ends -1 and +1 (align_corners=True).
        uv = torch.tensor([[0.5, 0.5], [94.5, 94.5], [1.0, 0.0]], dtype=torch.float64)
        g = pixel_to_grid(uv, 96, (2, 1))
        assert g[0].tolist() == pytest.approx([-1.0, -1.0 + 2 * 0.5 / 95])
        assert g[1, 0] == pytest.approx(1.0)
        assert g[2, 0] == pytest.approx(-1.0 + 2 * 0.25 / 47)


# --- rendered images --------------------------------------------------------------------------
@pytest.fixture(scope="module")
def flat_city():
    """A 512 m city flattened to U = 0 (no relief, no buildings), textures kept, with a magenta
    12 x 12 m patch painted on the ground at (-40, 70) m."""
    from benchmark.sim.world import build_city

    city = build_city("oxford", 11, cache_dir=False, size_m=(512.0, 512.0), n_lights=1)
    flat = city.with_rasters(
        height=np.zeros_like(city.height), mat=np.zeros_like(city.mat),
        ground=np.zeros_like(city.ground),
    )  # fmt: skip
    return flat


def _paint(city, e, n, half):
    e0, n0 = city.origin
    mpp = city.metres_per_px
    i0, i1 = round((e - half - e0) / mpp), round((e + half - e0) / mpp)
    j0, j1 = round((n - half - n0) / mpp), round((n + half - n0) / mpp)
    ortho = city.ortho.copy()
    ortho[..., j0:j1, i0:i1, :] = MAGENTA
    return city.with_rasters(ortho=ortho)


def _is_magenta(rgb) -> bool:
    r, g, b = (float(x) for x in rgb)
    return r > 150 and b > 150 and g < 90


class TestWarpOnRenderedPair:
    def test_ground_patch_lands_where_the_camera_model_says(self, flat_city):
        from benchmark.sim.render import render_satellite, render_uav

        try:
            city = _paint(flat_city, -40.0, 70.0, 6.0)
        except (TypeError, ValueError):  # a city whose ortho has another layout
            pytest.skip("city.ortho layout not supported by the painter")
        yaw, pitch, roll, alt = math.radians(30.0), math.radians(-45.0), math.radians(4.0), 80.0
        cam = Camera.square(96, 60.0)
        img = render_uav(city, np.array([0.0, 0.0, alt]), yaw, pitch, roll, cam)
        ref, front = _sim_uav_pixel((-40.0, 70.0), yaw, pitch, roll, alt, 96, 60.0)
        assert front and _is_magenta(img[round(ref[1]), round(ref[0])])  # the truth itself
        # The encoder's warp: 10 m cells, yaws every 30 deg; (-40, 70) m is the cell 7 rows
        # north and 4 columns west of the centre, sampled for yaw index 1 (30 deg).
        feats = torch.from_numpy(img.transpose(2, 0, 1).astype(np.float64))[None]
        yaws = torch.arange(12, dtype=torch.float64) * math.radians(30.0)
        t, mask = bev_templates(
            feats, (1, 1), 96, yaws, 10, 10.0, torch.tensor([pitch], dtype=torch.float64),
            torch.tensor([roll], dtype=torch.float64), torch.tensor([alt], dtype=torch.float64),
            torch.tensor([math.radians(60.0)], dtype=torch.float64),
        )  # fmt: skip
        assert bool(mask[0, 1, 10 - 7, 10 - 4])
        assert _is_magenta(t[0, 1, :, 10 - 7, 10 - 4])
        # and nowhere far from it in the same template
        far = [(3, 14), (15, 6), (10, 10)]
        assert not any(_is_magenta(t[0, 1, :, i, j]) for i, j in far)
        # The satellite grid (5 m px over 480 m) puts the same patch in the same cell.
        sat = render_satellite(city, np.array([0.0, 0.0]), height_m=1000.0,
                               footprint_m=(480.0, 480.0), size=96)  # fmt: skip
        sfeat = torch.from_numpy(sat.transpose(2, 0, 1).astype(np.float64))[None]
        grid = sat_grid(sfeat, (1, 1), 96, torch.tensor([[480.0, 480.0]], dtype=torch.float64),
                        10, 10.0)  # fmt: skip
        assert _is_magenta(grid[0, :, 10 - 7, 10 - 4])


class TestOffsetGrid:
    def test_rows_north_first(self):
        g = offset_grid(2, 5.0)
        assert g[0, 0].tolist() == [-10.0, 10.0] and g[4, 4].tolist() == [10.0, -10.0]


def _ramp(size: int) -> torch.Tensor:
    """``(1, 2, size, size)`` float64 features holding each pixel's own ``(u, v)``: bilinear
    sampling of a linear ramp returns the sampled position exactly."""
    v, u = torch.meshgrid(
        torch.arange(size, dtype=torch.float64), torch.arange(size, dtype=torch.float64),
        indexing="ij",
    )  # fmt: skip
    return torch.stack([u, v])[None]


class TestBevTemplatesPlanes:
    """The height-aware lifting against the simulator's camera model (a point ``h`` metres up)."""

    yaw, pitch, roll, alt, fov = 0.7, math.radians(-25.0), math.radians(3.0), 90.0, 60.0
    heights = (0.0, 15.0, 30.0)

    def _run(self, logits: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        f64 = torch.float64
        yaws = torch.tensor([self.yaw], dtype=f64)
        one = lambda x: torch.tensor([x], dtype=f64)  # noqa: E731
        t, w = bev_templates_planes(
            _ramp(96), logits, torch.tensor(self.heights, dtype=f64), (1, 1), 96, yaws, 8,
            25.0, one(self.pitch), one(self.roll), one(self.alt), one(math.radians(self.fov)),
        )  # fmt: skip
        return t, w, offset_grid(8, 25.0, dtype=f64)

    def _sim(self, de: float, dn: float, h: float) -> tuple[np.ndarray, bool]:
        uv, front = project_enu_to_pixel(
            np.array([[de, dn, h]]), np.array([0.0, 0.0, self.alt]), self.yaw, self.pitch,
            self.roll, Camera.square(96, self.fov),
        )  # fmt: skip
        inside = bool(front[0]) and bool(np.all((uv[0] >= -0.5) & (uv[0] <= 95.5)))
        return uv[0], inside

    @pytest.mark.parametrize("plane", [0, 1, 2])
    def test_one_plane_samples_where_the_raised_point_projects(self, plane):
        # All probability on one plane: each cell reads the pixel of the point h_p metres above
        # that cell's ground (project_enu_to_pixel), with weight 1 where it is in view.
        logits = torch.full((1, 4, 96, 96), -60.0, dtype=torch.float64)
        logits[:, plane] = 60.0
        t, w, grid = self._run(logits)
        seen = 0
        for i in range(17):
            for j in range(17):
                de, dn = grid[i, j].tolist()
                if de * de + dn * dn > (8 * 25.0) ** 2:
                    assert float(w[0, 0, i, j]) == 0.0  # outside the disc
                    continue
                uv, inside = self._sim(de, dn, self.heights[plane])
                if not inside:
                    assert float(w[0, 0, i, j]) == pytest.approx(0.0, abs=1e-12)
                elif np.all((uv >= 0) & (uv <= 95)):  # not in the half-pixel border, where the
                    # zero padding of the bilinear sampling fades features and weight alike
                    assert float(w[0, 0, i, j]) == pytest.approx(1.0, abs=1e-9)
                    np.testing.assert_allclose(t[0, 0, :, i, j].numpy(), uv, atol=1e-6)
                    seen += 1
        assert seen > 20

    def test_mixture_is_the_probability_weighted_sum(self):
        # Spatially constant probabilities q_p: cell = sum_p q_p F(u_p), weight = sum_p q_p
        # over the planes where the cell is in view.
        q = torch.tensor([0.5, 0.2, 0.2, 0.1], dtype=torch.float64)
        logits = q.log().view(1, 4, 1, 1).expand(1, 4, 96, 96).contiguous()
        t, w, grid = self._run(logits)
        checked = 0
        for i, j in ((8, 8), (2, 8), (4, 10), (6, 5), (3, 6)):
            de, dn = grid[i, j].tolist()
            expect_t, expect_w = np.zeros(2), 0.0
            for p, h in enumerate(self.heights):
                uv, inside = self._sim(de, dn, h)
                if inside:
                    expect_t += float(q[p]) * uv
                    expect_w += float(q[p])
            ok = all(np.all(np.abs(self._sim(de, dn, h)[0] - 47.5) < 47.5) for h in self.heights
                     if self._sim(de, dn, h)[1])  # fmt: skip
            assert float(w[0, 0, i, j]) == pytest.approx(expect_w, abs=1e-9)
            if ok:
                np.testing.assert_allclose(t[0, 0, :, i, j].numpy(), expect_t, atol=1e-6)
                checked += expect_w > 0
        assert checked >= 2

    def test_gradcheck_float64(self):
        g = torch.Generator().manual_seed(2)
        f64 = torch.float64
        feats = torch.randn(2, 2, 12, 12, generator=g, dtype=f64, requires_grad=True)
        logits = torch.randn(2, 3, 12, 12, generator=g, dtype=f64, requires_grad=True)
        pitch = torch.tensor([-0.6, -0.4], dtype=f64, requires_grad=True)
        alt = torch.tensor([80.0, 90.0], dtype=f64, requires_grad=True)
        roll = torch.tensor([0.05, -0.1], dtype=f64)
        fov = torch.full((2,), 1.0, dtype=f64)
        yaws = torch.tensor([0.3, 2.0], dtype=f64)
        heights = torch.tensor([0.0, 20.0], dtype=f64)

        def warp(f, lg, p, a):
            t, w = bev_templates_planes(f, lg, heights, (2, 2), 24, yaws, 2, 23.0, p, roll, a, fov)
            return t, w

        assert torch.autograd.gradcheck(warp, (feats, logits, pitch, alt), atol=1e-6)

    def test_bad_inputs_are_refused(self):
        f64 = torch.float64
        feats = torch.zeros(1, 2, 12, 12, dtype=f64)
        args = ((2, 2), 24, torch.zeros(1, dtype=f64), 2, 23.0, torch.tensor([-0.5], dtype=f64),
                torch.zeros(1, dtype=f64))  # fmt: skip
        fov = torch.ones(1, dtype=f64)
        with pytest.raises(ValueError, match="plane_logits must be"):
            bev_templates_planes(feats, torch.zeros(1, 2, 12, 12, dtype=f64),
                                 torch.tensor([0.0, 10.0], dtype=f64), *args,
                                 torch.tensor([80.0], dtype=f64), fov)  # fmt: skip
        with pytest.raises(ValueError, match="not below every camera"):
            bev_templates_planes(feats, torch.zeros(1, 3, 12, 12, dtype=f64),
                                 torch.tensor([0.0, 90.0], dtype=f64), *args,
                                 torch.tensor([80.0], dtype=f64), fov)  # fmt: skip
