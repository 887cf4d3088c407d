"""Tests of the procedural cities: determinism, cache, styles, queries, changed cities."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

import benchmark.sim
from benchmark.sim import GENERATOR_VERSION, STYLES, build_city, changed_city, source_digest
from benchmark.sim.render_core import MAT_BUILDING, MAT_TREE, MAT_WATER
from benchmark.sim.world import CITY_MODULES

SMALL = (512.0, 512.0)


@pytest.fixture(scope="module")
def city():
    return build_city("oxford", 5, cache_dir=False, size_m=SMALL)


class TestSourceDigest:
    def test_matches_an_independent_hash_of_the_files(self):
        folder = Path(benchmark.sim.__file__).parent
        names = sorted(p.stem for p in folder.glob("*.py"))
        ref = hashlib.sha256()
        for name in names:
            ref.update(name.encode() + b"\0" + (folder / f"{name}.py").read_bytes() + b"\0")
        assert source_digest() == ref.hexdigest()[:12]

    def test_city_modules_are_a_real_subset_with_their_own_digest(self):
        folder = Path(benchmark.sim.__file__).parent
        assert all((folder / f"{m}.py").is_file() for m in CITY_MODULES)
        assert source_digest(CITY_MODULES) != source_digest()
        assert source_digest(tuple(reversed(CITY_MODULES))) == source_digest(CITY_MODULES)

    def test_unknown_module_is_named(self):
        with pytest.raises(ValueError, match="nosuchmodule"):
            source_digest(("nosuchmodule",))

    def test_dataset_config_records_it(self):
        from benchmark.data import get_data_profile
        from benchmark.data.writer import dataset_config

        assert dataset_config(get_data_profile("smoke"), 0)["generator_source"] == source_digest()


class TestBuildCity:
    def test_deterministic_same_seed_same_bytes(self, city):
        again = build_city("oxford", 5, cache_dir=False, size_m=SMALL)
        for name in ("height", "ortho", "mat", "orient", "ground", "tex", "hpyr", "palette"):
            assert getattr(city, name).tobytes() == getattr(again, name).tobytes(), name

    def test_different_seed_differs(self, city):
        other = build_city("oxford", 6, cache_dir=False, size_m=SMALL)
        assert np.mean(other.ortho != city.ortho) > 0.3
        assert not np.array_equal(other.height, city.height)

    def test_cache_round_trip(self, city, tmp_path):
        first = build_city("oxford", 5, cache_dir=tmp_path, size_m=SMALL)
        dirs = list(tmp_path.iterdir())
        source = source_digest(CITY_MODULES)
        assert len(dirs) == 1 and dirs[0].name.endswith(f"-v{GENERATOR_VERSION}-{source}")
        second = build_city("oxford", 5, cache_dir=tmp_path, size_m=SMALL)  # loaded, memory-mapped
        for c in (first, second):
            for name in ("height", "ortho", "mat", "hpyr", "tex", "flight_centres", "clear"):
                assert np.array_equal(np.asarray(getattr(c, name)), getattr(city, name)), name
            assert c.style == "oxford" and c.seed == 5 and c.metres_per_px == 1.0
            np.testing.assert_array_equal(c.sun, city.sun)

    @pytest.mark.parametrize("victim", ["height.npy", "meta.json", "tex.npy"])
    def test_corrupt_cache_is_named(self, tmp_path, victim):
        build_city("oxford", 5, cache_dir=tmp_path, size_m=SMALL)
        (entry,) = tmp_path.iterdir()
        f = entry / victim
        f.write_bytes(f.read_bytes()[: 40 if victim != "meta.json" else 10])
        with pytest.raises(ValueError, match=rf"corrupt city cache.*{victim}"):
            build_city("oxford", 5, cache_dir=tmp_path, size_m=SMALL)

    def test_unknown_style_names_value_and_choices(self):
        with pytest.raises(ValueError, match=r"'paris'.*oxford.*industrial"):
            build_city("paris", 1, cache_dir=False, size_m=SMALL)

    @pytest.mark.parametrize("bad", [-1, 1.5, "3"])
    def test_bad_seed(self, bad):
        with pytest.raises(ValueError, match="seed"):
            build_city("oxford", bad, cache_dir=False, size_m=SMALL)

    def test_bad_size(self):
        with pytest.raises(ValueError, match="size_m"):
            build_city("oxford", 1, cache_dir=False, size_m=(50.0, 512.0))

    def test_convention_grid_rounded_to_256_and_extent_centred(self, city):
        c = build_city("cambridge", 1, cache_dir=False, size_m=(600.0, 300.0))
        assert c.shape == (512, 768)  # rows along N, columns along E
        assert c.extent == (-384.0, 384.0, -256.0, 256.0)
        assert city.extent == (-256.0, 256.0, -256.0, 256.0)

    @pytest.mark.parametrize("style", STYLES)
    def test_every_style_has_its_content(self, style):
        c = build_city(style, 2, cache_dir=False, size_m=(768.0, 768.0))
        frac_b = np.mean(c.mat >= MAT_BUILDING)
        assert 0.05 < frac_b < 0.7, frac_b
        assert np.mean(c.mat == MAT_TREE) > 0.002
        assert c.max_structure_height < 60.0  # flights are at >= 70 m above ground
        assert c.ortho.dtype == np.uint8 and c.ortho.std() > 15.0

    def test_styles_differ_in_building_height(self):
        tall = build_city("london", 2, cache_dir=False, size_m=(768.0, 768.0))
        low = build_city("cambridge", 2, cache_dir=False, size_m=(768.0, 768.0))

        def median_building(c):
            h = c.height - np.repeat(np.repeat(c.ground, 4, 0), 4, 1)
            return np.median(h[c.mat >= MAT_BUILDING])

        assert median_building(tall) > 1.8 * median_building(low)


class TestCityQueries:
    def test_ground_height_matches_terrain_where_open(self, city):
        # On open ground (not building/tree/water) the surface is the terrain.
        j, i = np.nonzero(city.mat == 0)
        pick = np.arange(0, len(j), max(1, len(j) // 500))
        e0, n0 = city.origin
        E = e0 + (i[pick] + 0.5) * city.metres_per_px
        N = n0 + (j[pick] + 0.5) * city.metres_per_px
        surf = city.height[j[pick], i[pick]]
        gap = surf - city.ground_height(E, N)
        # Cars (1.5 m) and kerbs sit on open ground too; the median gap is the terrain itself.
        assert abs(np.median(gap)) < 0.2

    def test_clearance_bounds_every_texel_nearby(self, city):
        rng = np.random.default_rng(0)
        E = rng.uniform(-250, 250, 300)
        N = rng.uniform(-250, 250, 300)
        clr = city.clearance(E, N)
        for dx in (-8.0, 0.0, 8.0):
            for dy in (-8.0, 0.0, 8.0):
                assert np.all(city.surface_height(E + dx, N + dy) <= clr + 1e-6)

    def test_flight_centres_inside_tile(self, city):
        c = city.flight_centres
        assert c.shape[1] == 2 and c.shape[0] >= 4
        e0, e1, n0, n1 = city.extent
        assert np.all((c[:, 0] > e0) & (c[:, 0] < e1) & (c[:, 1] > n0) & (c[:, 1] < n1))

    def test_full_size_centres_leave_room_for_largest_satellite_footprint(self):
        from benchmark.sim.world import _flight_centres

        c = _flight_centres("oxford", 0, (2560, 3584), 1.0)
        assert np.all(np.abs(c[:, 0]) + 1400.0 <= 1792.0)
        assert np.all(np.abs(c[:, 1]) + 700.0 <= 1280.0)

    def test_convention_rows_go_north_and_ortho_image_is_north_up(self, city):
        H, W = city.shape
        e0, n0 = city.origin
        for j, i in ((0, 0), (H - 1, 5), (17, W - 1), (H // 2, W // 3)):
            E = e0 + (i + 0.5) * city.metres_per_px
            N = n0 + (j + 0.5) * city.metres_per_px
            assert city.surface_height(E, N) == city.height[j, i]
            np.testing.assert_array_equal(city.ortho_image()[H - 1 - j, i], city.ortho[j, i])
        assert n0 == city.extent[2] and e0 == city.extent[0]

    def test_mirror_extension_is_continuous(self, city):
        # Beyond the eastern edge the world is the mirror image of the tile.
        _e0, e1, _, _ = city.extent
        N = np.linspace(-200, 200, 50)
        inside = city.surface_height(np.full(50, e1 - 3.5), N)
        outside = city.surface_height(np.full(50, e1 + 3.5), N)
        np.testing.assert_array_equal(inside, outside)


class TestChangedCity:
    def test_changed_city_differs_plausibly(self, city):
        old = changed_city(city, 0, cache_dir=False)
        assert old.shape == city.shape and old.style == city.style
        np.testing.assert_array_equal(old.flight_centres, city.flight_centres)
        assert not np.allclose(old.sun, city.sun)
        assert old.season in ("winter", "autumn") and city.season == "summer"
        # Same street layout and river: most of the terrain and water unchanged.
        assert np.mean((old.mat == MAT_WATER) == (city.mat == MAT_WATER)) > 0.99
        # Some buildings changed, but most stay.
        b_now = city.mat >= MAT_BUILDING
        b_old = old.mat >= MAT_BUILDING
        changed = np.mean(b_now != b_old) / max(np.mean(b_now), 1e-9)
        assert 0.01 < changed < 0.4, changed

    def test_changed_city_deterministic_and_seeded(self, city):
        a = changed_city(city, 3, cache_dir=False)
        b = changed_city(city, 3, cache_dir=False)
        c = changed_city(city, 4, cache_dir=False)
        assert a.ortho.tobytes() == b.ortho.tobytes()
        assert a.ortho.tobytes() != c.ortho.tobytes()

    def test_bad_change_seed(self, city):
        with pytest.raises(ValueError, match="change seed"):
            changed_city(city, -2, cache_dir=False)
