"""Tests of the illumination states: sun sampling, the shadow sweep and the baked textures.

References are independent of the code under test: the closed-form shadow of a box on flat ground
(length ``h / tan(elevation)`` on the anti-sun side), and a brute-force numpy ray march from every
texel towards the sun (the algorithm the sweep replaced).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from benchmark.sim.lighting import (
    bake_light_states,
    sample_suns,
    sun_angles,
    sun_vector,
    sun_visibility,
)
from benchmark.sim.world import _suns


def march_visibility(h: np.ndarray, mpp: float, sun: np.ndarray) -> np.ndarray:
    """Reference: 1 where the ray from a texel's top centre towards the sun (quarter-texel
    steps, mirror-tiled field) clears every texel column, else 0."""
    H, W = h.shape
    horiz = math.hypot(sun[0], sun[1])
    step = 0.25
    sx, sy, rise = sun[0] / horiz * step, sun[1] / horiz * step, sun[2] / horiz * step * mpp
    jj, ii = np.mgrid[0:H, 0:W]
    x, y, z = ii + 0.5, jj + 0.5, h + 0.05
    vis = np.ones((H, W), np.float32)
    active = np.ones((H, W), bool)
    top = h.max() + 0.1

    def mirror(a, n):
        m = np.mod(a, 2 * n)
        return np.where(m >= n, 2 * n - 1 - m, m)

    while active.any():
        x, y, z = x + sx, y + sy, z + rise
        hv = h[mirror(np.floor(y).astype(int), H), mirror(np.floor(x).astype(int), W)]
        hit = active & (hv > z)
        vis[hit] = 0.0
        active &= ~hit & (z < top)
    return vis


def box_field(H=160, W=160, half=4, h=12.0):
    height = np.zeros((H, W), np.float32)
    c = H // 2, W // 2
    height[c[0] - half : c[0] + half, c[1] - half : c[1] + half] = h
    return height, (W // 2, H // 2)  # centre in (x, y) grid units


def deg(x):
    return math.degrees(x)


class TestSampleSuns:
    @pytest.mark.parametrize("season", ["summer", "winter", "autumn"])
    def test_unit_vectors_and_angles_round_trip(self, season):
        suns = sample_suns(np.random.default_rng(3), 8, season)
        assert suns.shape == (8, 3) and suns.dtype == np.float64
        np.testing.assert_allclose(np.linalg.norm(suns, axis=1), 1.0, atol=1e-12)
        for s in suns:
            az, el = sun_angles(s)
            assert 0.0 <= az < 2 * math.pi
            np.testing.assert_allclose(sun_vector(az, el), s, atol=1e-12)

    def test_convention_azimuth_clockwise_from_north(self):
        # Azimuth 90 deg is east (+E), 180 deg south (-N); the vector points towards the sun.
        np.testing.assert_allclose(sun_vector(math.pi / 2, 0.0), [1.0, 0.0, 0.0], atol=1e-12)
        np.testing.assert_allclose(sun_vector(math.pi, 0.0), [0.0, -1.0, 0.0], atol=1e-12)
        np.testing.assert_allclose(sun_vector(0.3, math.pi / 2)[2], 1.0)

    def test_summer_coverage_and_elevations_on_many_seeds(self):
        all_az, all_el = [], []
        for seed in range(300):
            suns = sample_suns(np.random.default_rng(seed), 8, "summer")
            ang = np.array([sun_angles(s) for s in suns])
            az, el = np.degrees(ang[:, 0]), np.degrees(ang[:, 1])
            assert az.min() <= 90.0 and az.max() >= 270.0, (seed, az)
            assert el.min() >= 15.0 - 1e-9 and el.max() <= 65.0 + 1e-9, (seed, el)
            # one azimuth per 45 deg sector, one elevation per 6.25 deg stratum
            np.testing.assert_allclose(np.diff(np.sort(az)), 45.0, atol=1e-9)
            strata = np.floor((el - 15.0) / 6.25).clip(0, 7)
            assert sorted(strata) == list(range(8)), (seed, el)
            all_az.append(az)
            all_el.append(el)
        # No compass: azimuths uniform on the circle (mean resultant length ~0), elevation
        # uncorrelated with the direction of the sun.
        az, el = np.radians(np.concatenate(all_az)), np.concatenate(all_el)
        assert abs(np.exp(1j * az).mean()) < 0.02
        for f in (np.cos(az), np.sin(az)):
            assert abs(np.corrcoef(f, el)[0, 1]) < 0.05

    def test_city_suns_cover_90_to_270_for_every_style_and_seed(self):
        for style in ("oxford", "cambridge", "london", "industrial"):
            for seed in range(40):
                suns, season = _suns(style, seed, 0, 8)
                ang = np.degrees([sun_angles(s) for s in suns])
                assert season == "summer"
                assert ang[:, 0].min() <= 90.0 and ang[:, 0].max() >= 270.0
                assert 15.0 - 1e-9 <= ang[:, 1].min() and ang[:, 1].max() <= 65.0 + 1e-9

    def test_changed_city_suns_are_low_winter_or_autumn(self):
        seasons = set()
        for seed in range(40):
            suns, season = _suns("industrial", seed, 1, 8)
            seasons.add(season)
            el = np.degrees([sun_angles(s)[1] for s in suns])
            assert season in ("winter", "autumn")
            lo, hi = (12.0, 24.0) if season == "winter" else (20.0, 34.0)
            assert lo - 1e-9 <= el.min() and el.max() <= hi + 1e-9
        assert seasons == {"winter", "autumn"}

    def test_state_order_is_shuffled(self):
        first = [deg(sun_angles(sample_suns(np.random.default_rng(s), 8, "summer")[0])[0])
                 for s in range(40)]  # fmt: skip
        assert max(first) - min(first) > 270.0

    def test_bad_arguments(self):
        rng = np.random.default_rng(0)
        with pytest.raises(ValueError, match="n_lights"):
            sample_suns(rng, 0, "summer")
        with pytest.raises(ValueError, match=r"season.*'spring'"):
            sample_suns(rng, 4, "spring")


class TestShadowSweep:
    @pytest.mark.parametrize(
        "az_deg, el_deg", [(90.0, 30.0), (135.0, 20.0), (200.0, 45.0), (250.0, 15.0), (300.0, 60.0)]
    )
    def test_box_shadow_lies_anti_sun_with_closed_form_length(self, az_deg, el_deg):
        h = 12.0
        height, (cx, cy) = box_field(h=h)
        sun = sun_vector(math.radians(az_deg), math.radians(el_deg))
        vis = sun_visibility(height, 1.0, sun)
        away = -sun[:2] / np.linalg.norm(sun[:2])
        shadow = (vis < 0.5) & (height == 0.0)
        jj, ii = np.nonzero(shadow)
        rel = np.stack([ii + 0.5 - cx, jj + 0.5 - cy], axis=1)
        along = rel @ away
        assert shadow.sum() > 20
        assert np.all(along > 0.0)  # every shadow texel is on the anti-sun side of the box
        # On the line through the box centre along `away` the shadow starts at the box's side and
        # runs h / tan(el) further; nowhere does it reach beyond the corner's shadow.
        half = 4.0
        length = h / math.tan(math.radians(el_deg))
        across = rel @ np.array([-away[1], away[0]])
        centre_line = np.abs(across) < 0.75
        side = half / max(abs(away[0]), abs(away[1]))
        assert abs(along[centre_line].max() - (side + length)) < 2.0  # texels ~1 m apart
        assert along.max() <= half * (abs(away[0]) + abs(away[1])) + length + 1.0
        assert np.all(np.abs(across) < half * math.sqrt(2) + 1.0)
        # Sunny side of the box: nothing shadowed.
        jj, ii = np.mgrid[0 : vis.shape[0], 0 : vis.shape[1]]
        sunny = ((ii + 0.5 - cx) * away[0] + (jj + 0.5 - cy) * away[1]) < -1.5 * half
        assert np.all(vis[sunny] == 1.0)

    @pytest.mark.parametrize("az_deg, el_deg", [(30.0, 40.0), (100.0, 20.0), (200.0, 15.0),
                                                (300.0, 55.0), (45.0, 25.0)])  # fmt: skip
    def test_matches_brute_force_march_on_random_city(self, az_deg, el_deg):
        rng = np.random.default_rng(int(az_deg))
        from scipy.ndimage import uniform_filter

        h = uniform_filter(rng.normal(0.0, 3.0, (96, 128)), 15)
        for _ in range(25):  # buildings, some touching the tile edges (mirror tiling)
            j, i = rng.integers(0, 96), rng.integers(0, 128)
            h[j : j + rng.integers(2, 12), i : i + rng.integers(2, 12)] += rng.uniform(3, 30)
        sun = sun_vector(math.radians(az_deg), math.radians(el_deg))
        ours = sun_visibility(h, 1.0, sun)
        ref = march_visibility(h, 1.0, sun)
        # Disagreements are one-texel edge effects: a few percent of the texels, no bias.
        diff = np.abs(ours - ref)
        assert diff.mean() < 0.04 and np.mean(diff > 0.5) < 0.03
        assert abs(ours.mean() - ref.mean()) < 0.01

    def test_metres_per_px_scales_shadow(self):
        # At 2 m/px a 12 m box casts a shadow half as many texels long as at 1 m/px.
        height, _ = box_field(h=12.0)
        sun = sun_vector(math.radians(90.0), math.radians(30.0))
        n1 = np.sum(sun_visibility(height, 1.0, sun) < 0.5)
        n2 = np.sum(sun_visibility(height, 2.0, sun) < 0.5)
        length1 = 12.0 / math.tan(math.radians(30.0))
        assert abs(n1 - 8 * length1) < 16 and abs(n2 - 8 * length1 / 2) < 16

    def test_sun_below_horizon_rejected(self):
        with pytest.raises(ValueError, match="sun"):
            sun_visibility(np.zeros((8, 8)), 1.0, np.array([1.0, 0.0, -0.1]))


class TestBakeLightStates:
    def test_each_state_shadows_away_from_its_own_sun(self):
        height, (cx, cy) = box_field(H=128, W=128, h=10.0)
        albedo = np.full((*height.shape, 3), 180.0, np.float32)
        suns = sample_suns(np.random.default_rng(7), 8, "summer")
        tex, toff, tdims = bake_light_states(albedo, height, 1.0, suns, 4)
        assert tex.shape == (8, int(toff[-1] + tdims[-1].prod()), 3) and tex.dtype == np.uint8
        H, W = height.shape
        jj, ii = np.mgrid[0:H, 0:W]
        for k, sun in enumerate(suns):
            ortho = tex[k, : H * W].reshape(H, W, 3).astype(float)
            _az, el = sun_angles(sun)
            away = -sun[:2] / np.linalg.norm(sun[:2])
            along = (ii + 0.5 - cx) * away[0] + (jj + 0.5 - cy) * away[1]
            across = -(ii + 0.5 - cx) * away[1] + (jj + 0.5 - cy) * away[0]
            ground = height == 0.0
            lit = np.median(ortho[ground, 0])  # 180 (0.55 + 0.6 sin el)
            umbra = 180.0 * 0.55  # ambient only
            dark = ground & (ortho[..., 0] < 0.5 * (lit + umbra))
            assert dark.sum() > 10
            # Shadow on the anti-sun side (up to the one-texel penumbra blur).
            assert np.all(along[dark] > -1.0), k
            half_diag = 4.0 * (abs(away[0]) + abs(away[1]))
            reach = half_diag + 10.0 / math.tan(el)
            # 3x3 penumbra blur: the tip may reach about 1.5 texels further.
            assert abs(along[dark].max() - reach) < 2.5, (k, along[dark].max(), reach)
            assert np.all(np.abs(across[dark]) < 4.0 * math.sqrt(2) + 2.0)
        # Different suns, different textures.
        assert all(np.any(tex[a] != tex[b]) for a in range(8) for b in range(a))

    def test_bad_suns(self):
        with pytest.raises(ValueError, match="suns"):
            bake_light_states(np.zeros((8, 8, 3), np.float32), np.zeros((8, 8)), 1.0,
                              np.zeros((2, 2)), 1)  # fmt: skip
