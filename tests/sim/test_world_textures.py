"""Tests of the generator's building blocks against closed forms and independent references."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from benchmark.sim.lighting import sun_visibility
from benchmark.sim.textures import (
    _bicubic_upsample,
    hash01,
    max_pyramid,
    mean_pyramid,
    smooth_noise,
)


class TestHash01:
    def test_deterministic_uniform_and_key_sensitive(self):
        k = np.arange(200_000)
        a = hash01(k, 7, 3)
        np.testing.assert_array_equal(a, hash01(k, 7, 3))
        assert a.min() >= 0.0 and a.max() < 1.0
        assert abs(a.mean() - 0.5) < 0.005 and abs(a.var() - 1 / 12) < 0.002
        counts = np.bincount((a * 20).astype(int), minlength=20)
        assert counts.min() > 0.95 * len(k) / 20
        # Another key (or the same keys in another order) gives uncorrelated numbers.
        b = hash01(k, 7, 4)
        c = hash01(3, 7, k)
        assert abs(np.corrcoef(a, b)[0, 1]) < 0.01 and abs(np.corrcoef(a, c)[0, 1]) < 0.01

    def test_broadcasts(self):
        out = hash01(np.arange(3)[:, None], np.arange(4)[None, :], 1)
        assert out.shape == (3, 4) and len(np.unique(out)) == 12


class TestSmoothNoise:
    def test_catmull_rom_reproduces_linear_fields(self):
        gy, gx = np.mgrid[0:12, 0:15].astype(np.float64)
        lattice = 0.3 * gx - 0.7 * gy + 2.0
        cell = 4.0
        out = _bicubic_upsample(lattice, cell, 30, 40)
        j, i = np.mgrid[0:30, 0:40]
        x = (i + 0.5) / cell + 1.0
        y = (j + 0.5) / cell + 1.0
        np.testing.assert_allclose(out, 0.3 * x - 0.7 * y + 2.0, atol=1e-5)

    def test_deterministic_range_and_smoothness(self):
        a = smooth_noise(np.random.default_rng(5), (300, 200), 50.0)
        b = smooth_noise(np.random.default_rng(5), (300, 200), 50.0)
        assert a.dtype == np.float32 and a.shape == (300, 200)
        np.testing.assert_array_equal(a, b)
        assert -1.5 < a.min() < -0.2 and 0.2 < a.max() < 1.5
        # Neighbouring texels differ by far less than the amplitude (a 50-texel wavelength).
        assert np.abs(np.diff(a, axis=1)).max() < 0.1


class TestPyramids:
    def test_max_pyramid_levels_are_block_maxima(self):
        rng = np.random.default_rng(0)
        h = rng.normal(size=(64, 96)).astype(np.float32)
        flat, offsets, dims = max_pyramid(h, 4)
        for k in range(5):
            rows, cols = dims[k]
            level = flat[offsets[k] : offsets[k] + rows * cols].reshape(rows, cols)
            s = 1 << k
            for j, i in ((0, 0), (rows - 1, cols - 1), (rows // 2, cols // 3)):
                assert level[j, i] == h[j * s : (j + 1) * s, i * s : (i + 1) * s].max()

    def test_max_pyramid_rejects_indivisible_grid(self):
        with pytest.raises(ValueError, match="divisible"):
            max_pyramid(np.zeros((48, 64), np.float32), 5)

    def test_mean_pyramid_matches_opencv_area_resize(self):
        rng = np.random.default_rng(1)
        img = rng.integers(0, 256, size=(64, 128, 3), dtype=np.uint8)
        flat, offsets, dims = mean_pyramid(img, 3)
        for k in range(1, 4):
            rows, cols = dims[k]
            level = flat[offsets[k] : offsets[k] + rows * cols].reshape(rows, cols, 3)
            ref = cv2.resize(img, (cols, rows), interpolation=cv2.INTER_AREA)
            assert np.abs(level.astype(int) - ref.astype(int)).max() <= 1


class TestSunVisibility:
    @pytest.mark.parametrize("elev_deg, az_deg", [(30.0, 90.0), (45.0, 180.0), (20.0, 225.0)])
    def test_pillar_shadow_length_is_h_over_tan_elevation(self, elev_deg, az_deg):
        # A 1-texel pillar of height 10 m on flat ground at 1 m/px: its shadow runs away from the
        # sun for 10 / tan(elevation) metres.
        H = W = 128
        height = np.zeros((H, W), np.float32)
        height[64, 64] = 10.0
        el, az = math.radians(elev_deg), math.radians(az_deg)  # azimuth clockwise from north
        sun = np.array([math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el)])
        vis = sun_visibility(height, 1.0, sun, 10.1)
        length = 10.0 / math.tan(el)
        away = -sun[:2] / np.linalg.norm(sun[:2])
        for dist in np.arange(1.5, length - 1.5, 1.0):
            x, y = 64.5 + away[0] * dist, 64.5 + away[1] * dist
            assert vis[int(y), int(x)] == 0.0, dist
        for dist in (length + 2.0, length + 6.0):
            x, y = 64.5 + away[0] * dist, 64.5 + away[1] * dist
            assert vis[int(y), int(x)] == 1.0, dist
        # Nothing on the sunny side is shadowed.
        x, y = 64.5 - away[0] * 5.0, 64.5 - away[1] * 5.0
        assert vis[int(y), int(x)] == 1.0
        assert vis.sum() > H * W - 2.0 * length - 10
