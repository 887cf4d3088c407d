"""Render workers honour the plan's illumination columns; the preview prints sun azimuths.

The reference for every rendered row is a direct call of the public renderer with the row's
``light`` and ``visibility_m`` (every plan has them; plans of older versions are refused).
"""

from __future__ import annotations

import dataclasses
import math
from collections import namedtuple
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from benchmark.data.preview import _sun_text, sun_azimuth_deg
from benchmark.data.profiles import DATA_PROFILES
from benchmark.data.render_pool import RenderContext, render_sat_rows, render_uav_rows
from benchmark.sim import Camera, build_city, render_satellite, render_uav


@pytest.fixture(scope="module")
def ctx(tmp_path_factory):
    city = build_city("oxford", 2, cache_dir=False, size_m=(512.0, 512.0))
    profile = dataclasses.replace(DATA_PROFILES["smoke"], image_size=24)
    g = float(city.ground_height(0.0, 0.0))
    uav = pd.DataFrame(
        dict(
            uav_index=np.arange(4),
            city="oxford",
            E=[0.0, 5.0, 10.0, 0.0],
            N=[0.0, -5.0, 10.0, 0.0],
            U=[g + 100.0] * 4,
            yaw=[0.1, 1.0, -2.0, 0.1],
            pitch=[-0.5, -0.7, -0.3, -0.5],
            roll=[0.0, 0.05, -0.05, 0.0],
            camera_effects=False,
        )
    )
    sat = pd.DataFrame(
        dict(city="oxford", variant="now", E=[0.0, 0.0], N=[0.0, 0.0], height_m=1000.0,
             footprint_E_m=2000.0, footprint_N_m=1000.0)
    )  # fmt: skip
    root = tmp_path_factory.mktemp("render")
    return RenderContext(Path(root), profile, 0, {("oxford", "now"): city}, uav, sat)


def direct_uav(ctx, r, **kw):
    p = ctx.profile
    cam = Camera(p.image_size, p.image_size, p.fov_deg)
    city = ctx.cities[("oxford", "now")]
    return render_uav(city, np.array([r.E, r.N, r.U]), r.yaw, r.pitch, r.roll, cam, **kw)


class TestRenderRowsLights:
    def test_uav_rows_use_light_and_visibility_columns(self, ctx):
        rows = ctx.uav.assign(light=[3, 0, 7, 5], visibility_m=[800.0, 2600.0, 5000.0, 1500.0])
        out = render_uav_rows(ctx, rows)
        for j, r in enumerate(rows.itertuples(index=False)):
            ref = direct_uav(ctx, r, light=r.light, visibility_m=r.visibility_m)
            assert out[j].tobytes() == ref.tobytes(), j
        # Rows 0 and 3 share the pose but not the light: the images differ.
        assert out[0].tobytes() != out[3].tobytes()

    def test_sat_rows_use_light_column(self, ctx):
        with_light = render_sat_rows(ctx, ctx.sat.assign(light=[0, 6]))
        city = ctx.cities[("oxford", "now")]
        for j, k in enumerate((0, 6)):
            ref = render_satellite(city, np.array([0.0, 0.0]), size=ctx.profile.image_size,
                                   light=k)  # fmt: skip
            assert with_light[j].tobytes() == ref.tobytes()
        assert with_light[0].tobytes() != with_light[1].tobytes()

    def test_bad_light_in_plan_is_named(self, ctx):
        with pytest.raises(ValueError, match="light"):
            render_uav_rows(ctx, ctx.uav.iloc[:1].assign(light=99, visibility_m=2600.0))


class TestPreviewSun:
    def test_sun_azimuth_degrees_when_present(self):
        Row = namedtuple("Row", "sun_az sat_sun_az")
        r = Row(math.radians(95.0), 2 * math.pi + math.radians(270.0))
        assert sun_azimuth_deg(r, "sun_az") == pytest.approx(95.0)
        assert sun_azimuth_deg(r, "sat_sun_az") == pytest.approx(270.0)
        assert _sun_text(95.04) == ", sun az 95 deg"

    def test_absent_or_missing_column_prints_nothing(self):
        Row = namedtuple("Row", "yaw sun_az")
        r = Row(0.0, float("nan"))
        assert sun_azimuth_deg(r, "sat_sun_az") is None
        assert sun_azimuth_deg(r, "sun_az") is None
        assert _sun_text(None) == ""

    def test_contact_sheet_titles_show_both_azimuths(self, smoke_root, tmp_path, monkeypatch):
        import matplotlib.image
        from matplotlib.axes import Axes

        from benchmark.data.dataset import PairDataset
        from benchmark.data.preview import contact_sheet

        titles = []
        original = Axes.set_title

        def record(self, label, *args, **kwargs):
            titles.append(label)
            return original(self, label, *args, **kwargs)

        monkeypatch.setattr(Axes, "set_title", record)
        ds = PairDataset(smoke_root, "standard/train", verify="size")
        n = len(ds.poses)
        ds.poses = ds.poses.assign(sun_az=np.full(n, 1.5), sat_sun_az=np.full(n, 4.0))
        out = tmp_path / "sheet.png"
        contact_sheet(ds, [0, 1], out, "sun")
        img = matplotlib.image.imread(out)
        assert img.ndim == 3 and np.std(img[..., :3]) > 0.05
        # 1.5 rad = 85.9 deg (UAV frame), 4.0 rad = 229.2 deg (satellite image)
        assert sum("sun az 86 deg" in t for t in titles) == 2
        assert sum(t.startswith("sat ") and "sun az 229 deg" in t for t in titles) == 2
