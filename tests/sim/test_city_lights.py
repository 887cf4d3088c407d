"""Tests of a city's illumination states and of rendering under them (issue 9).

Independent references: the Lambert closed form ``ambient + diffuse cos`` for a facade facing the
sun, uniform-colour textures per state (the satellite image of state k must show state k's colour)
and the shadow geometry of the generated city (ground next to a tall building is darker on its
anti-sun side).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from benchmark.sim import Camera, build_city, changed_city, render_satellite, render_uav
from benchmark.sim.lighting import N_LIGHTS, sun_vector, sun_visibility
from benchmark.sim.render import HAZE
from benchmark.sim.render_core import MAT_BUILDING, MAT_GROUND

SMALL = (512.0, 512.0)


@pytest.fixture(scope="module")
def city():
    return build_city("cambridge", 3, cache_dir=False, size_m=SMALL)


@pytest.fixture(scope="module")
def flat(city):
    """Flat ground, one uniform colour per illumination state (state k: grey 20 + 25 k)."""
    K, (H, W) = city.n_lights, city.shape
    ortho = np.zeros((K, H, W, 3), np.uint8)
    for k in range(K):
        ortho[k] = (20 + 25 * k, 200 - 20 * k, 60 + 10 * k)
    return city.with_rasters(
        height=np.zeros_like(city.height),
        mat=np.zeros_like(city.mat),
        ground=np.zeros_like(city.ground),
        ortho=ortho,
    )


class TestCityLights:
    def test_k_states_with_distinct_suns_and_textures(self, city):
        K = city.n_lights
        assert K == N_LIGHTS == 8
        assert city.light_suns.shape == (K, 3) and city.light_suns.dtype == np.float64
        np.testing.assert_allclose(np.linalg.norm(city.light_suns, axis=1), 1.0, atol=1e-12)
        H, W = city.shape
        assert city.tex.shape[0] == K and city.tex.dtype == np.uint8
        for a in range(K):
            assert city.light_ortho(a).shape == (H, W, 3)
            for b in range(a):
                assert np.degrees(np.arccos(city.light_suns[a] @ city.light_suns[b])) > 5.0
                diff = np.abs(city.light_ortho(a).astype(int) - city.light_ortho(b))
                assert diff.mean() > 1.0, (a, b)
        np.testing.assert_array_equal(city.sun, city.light_suns[0])
        np.testing.assert_array_equal(city.ortho, city.light_ortho(0))
        np.testing.assert_array_equal(city.ortho_image(3), city.light_ortho(3)[::-1])

    def test_light_angles_convention(self, city):
        az = []
        for k in range(city.n_lights):
            a, e = city.light_angles(k)
            assert 0.0 <= a < 2 * math.pi and math.radians(15) - 1e-9 <= e <= math.radians(65)
            np.testing.assert_allclose(sun_vector(a, e), city.light_suns[k], atol=1e-12)
            az.append(math.degrees(a))
        assert min(az) <= 90.0 and max(az) >= 270.0

    def test_each_texture_carries_its_own_suns_shadows(self, city):
        # On open ground, state k's brightness correlates best with the shadow mask of sun k
        # (``sun_visibility`` is checked against a brute-force march in test_lighting.py): the
        # textures and the sun vectors are paired, and each state has its own shadows.
        ground = city.mat == MAT_GROUND
        masks = [
            sun_visibility(city.height, city.metres_per_px, s)[ground] for s in city.light_suns
        ]
        for k in range(city.n_lights):
            lum = city.light_ortho(k).astype(float).mean(axis=2)[ground]
            score = [np.corrcoef(lum, m)[0, 1] for m in masks]
            assert int(np.argmax(score)) == k and score[k] > 0.3, (k, np.round(score, 2))

    def test_deterministic(self, city):
        again = build_city("cambridge", 3, cache_dir=False, size_m=SMALL)
        assert again.tex.tobytes() == city.tex.tobytes()
        assert again.light_suns.tobytes() == city.light_suns.tobytes()
        other = build_city("cambridge", 4, cache_dir=False, size_m=SMALL)
        assert not np.allclose(other.light_suns, city.light_suns)

    def test_cache_round_trip_memory_mapped(self, city, tmp_path):
        first = build_city("cambridge", 3, cache_dir=tmp_path, size_m=SMALL)
        (entry,) = tmp_path.iterdir()
        assert f"-L{N_LIGHTS}-" in entry.name
        second = build_city("cambridge", 3, cache_dir=tmp_path, size_m=SMALL)
        for c in (first, second):
            assert c.tex.tobytes() == city.tex.tobytes()
            np.testing.assert_array_equal(c.light_suns, city.light_suns)
            assert c.n_lights == city.n_lights
        assert isinstance(second.tex.base, np.memmap) or not second.tex.flags.writeable

    def test_n_lights_option_and_changed_city(self, city):
        two = build_city("cambridge", 3, cache_dir=False, size_m=SMALL, n_lights=2)
        assert two.n_lights == 2 and two.tex.shape[0] == 2
        az = sorted(math.degrees(two.light_angles(k)[0]) for k in range(2))
        assert az[1] - az[0] == pytest.approx(180.0)  # one per half circle
        old = changed_city(two, 0, cache_dir=False)
        assert old.n_lights == 2 and old.season in ("winter", "autumn")
        assert all(math.degrees(old.light_angles(k)[1]) <= 34.0 + 1e-9 for k in range(2))
        assert not np.allclose(old.light_suns, two.light_suns)
        for bad in (0, 65, 2.0, True):
            with pytest.raises(ValueError, match="n_lights"):
                build_city("cambridge", 3, cache_dir=False, size_m=SMALL, n_lights=bad)

    @pytest.mark.parametrize("bad", [-1, N_LIGHTS, 1.0, "0", True, None])
    def test_bad_light_named(self, city, bad):
        with pytest.raises(ValueError, match=r"light must be an integer in \[0, 8\)"):
            city.light_angles(bad)
        with pytest.raises(ValueError, match="light"):
            city.light_ortho(bad)


class TestRenderLights:
    def test_satellite_of_state_k_shows_state_k(self, flat):
        for k in range(flat.n_lights):
            img = render_satellite(flat, np.array([0.0, 0.0]), size=32, light=k)
            expected = np.broadcast_to(flat.light_ortho(k)[0, 0], img.shape)
            np.testing.assert_array_equal(img, expected)

    def test_uav_of_state_k_shows_state_k(self, flat):
        cam = Camera.square(24, 40.0)
        for k in (0, 5):
            img = render_uav(flat, np.array([0.0, 0.0, 100.0]), 0.0, -math.pi / 2, 0.0, cam,
                             light=k, visibility_m=1e6)  # fmt: skip
            ref = flat.light_ortho(k)[0, 0].astype(int)
            assert np.abs(img.astype(int) - ref).max() <= 1

    def test_two_lights_differ_same_light_identical(self, city):
        # The morning-most and the evening-most states.
        az = [city.light_angles(k)[0] for k in range(city.n_lights)]
        m, e = int(np.argmin(az)), int(np.argmax(az))
        cam = Camera.square(48, 60.0)
        pos = np.array([20.0, -30.0, float(city.ground_height(20.0, -30.0)) + 90.0])
        a = render_uav(city, pos, 0.3, -0.6, 0.02, cam, light=m)
        b = render_uav(city, pos, 0.3, -0.6, 0.02, cam, light=m)
        c = render_uav(city, pos, 0.3, -0.6, 0.02, cam, light=e)
        assert a.tobytes() == b.tobytes()
        assert np.abs(a.astype(int) - c).mean() > 3.0
        s1 = render_satellite(city, np.array([0.0, 0.0]), size=32, light=m)
        s1b = render_satellite(city, np.array([0.0, 0.0]), size=32, light=m)
        s4 = render_satellite(city, np.array([0.0, 0.0]), size=32, light=e)
        assert s1.tobytes() == s1b.tobytes() and np.abs(s1.astype(int) - s4).mean() > 3.0
        # Default light is state 0.
        d0 = render_uav(city, pos, 0.3, -0.4, 0.02, cam)
        assert d0.tobytes() == render_uav(city, pos, 0.3, -0.4, 0.02, cam, light=0).tobytes()

    def test_facade_lambert_uses_the_states_sun(self, city):
        # One 40 m tower on flat ground, every state with the same texture: only the sun differs.
        # State 0's sun is due west at elevation e (the west wall faces it: ambient + diffuse
        # cos e), state 1's due east (the west wall gets the ambient term only).
        H, W = city.shape
        e0, n0 = city.origin
        height = np.zeros((H, W), np.float32)
        mat = np.zeros((H, W), np.uint8)
        j0, i0 = round(-n0) - 15, round(-e0) - 15
        height[j0 : j0 + 30, i0 : i0 + 30] = 40.0
        mat[j0 : j0 + 30, i0 : i0 + 30] = MAT_BUILDING
        tower = city.with_rasters(height=height, mat=mat, ground=np.zeros_like(city.ground),
                                  ortho=np.full((H, W, 3), 128, np.uint8))  # fmt: skip
        el = math.radians(30.0)
        suns = np.stack([sun_vector(1.5 * math.pi, el), sun_vector(0.5 * math.pi, el)])
        suns = np.concatenate([suns, np.tile(suns[:1], (tower.n_lights - 2, 1))])
        tower = dataclasses.replace(tower, light_suns=suns)
        cam = Camera.square(32, 20.0)
        pos = np.array([-80.0, 0.0, 20.0])  # west of the tower, looking east (yaw -90 deg)
        lit = render_uav(tower, pos, -math.pi / 2, 0.0, 0.0, cam, light=0, visibility_m=1e6)
        dark = render_uav(tower, pos, -math.pi / 2, 0.0, 0.0, cam, light=1, visibility_m=1e6)
        centre = (slice(12, 20), slice(12, 20))  # the middle of the west wall
        ratio = lit[centre].astype(float).sum() / dark[centre].astype(float).sum()
        assert abs(ratio - (0.55 + 0.6 * math.cos(el)) / 0.55) < 0.03, ratio

    def test_visibility_controls_haze(self, city):
        cam = Camera.square(32, 60.0)
        pos = np.array([0.0, 0.0, float(city.ground_height(0.0, 0.0)) + 120.0])
        default = render_uav(city, pos, 0.0, -0.3, 0.0, cam)
        same = render_uav(city, pos, 0.0, -0.3, 0.0, cam, visibility_m=2600.0)
        assert default.tobytes() == same.tobytes()
        clear = render_uav(city, pos, 0.0, -0.3, 0.0, cam, visibility_m=1e6)
        hazy = render_uav(city, pos, 0.0, -0.3, 0.0, cam, visibility_m=300.0)
        haze = np.array(HAZE)
        dist = [np.abs(im.astype(float) - haze).mean() for im in (clear, default, hazy)]
        assert dist[0] > dist[1] > dist[2]

    @pytest.mark.parametrize("bad", [-1, N_LIGHTS, 0.5, "1", True])
    def test_bad_light_rejected(self, city, bad):
        cam = Camera.square(16, 60.0)
        with pytest.raises(ValueError, match="light"):
            render_uav(city, np.array([0.0, 0.0, 150.0]), 0, 0, 0, cam, light=bad)
        with pytest.raises(ValueError, match="light"):
            render_satellite(city, np.array([0.0, 0.0]), size=16, light=bad)

    @pytest.mark.parametrize("bad", [0.0, -5.0, float("nan"), float("inf"), "2600", True, 5.0])
    def test_bad_visibility_rejected(self, city, bad):
        cam = Camera.square(16, 60.0)
        with pytest.raises(ValueError, match="visibility_m"):
            render_uav(city, np.array([0.0, 0.0, 150.0]), 0, 0, 0, cam, visibility_m=bad)
