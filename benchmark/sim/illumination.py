"""Capture times of the plan (issue 9): an illumination state and weather per flight, and an
independent illumination state per satellite image.

A city carries ``n_lights`` baked illumination states (sun direction, shading and shadows; see
``benchmark.sim.world``). Every flight draws one state and a fog visibility (weather) of its own;
every satellite image draws its own state, independently of the flights, as a satellite image
taken months apart at another time of day. So lit and shaded facades, shadow directions and haze
in a UAV frame say nothing about its heading that holds across flights; only matching with the
satellite image (whose shadows point elsewhere) does.

Seeds: ``SeedSequence(seed, spawn_key=(FLIGHT_LIGHT_STREAM, flight))`` per flight and
``(SAT_LIGHT_STREAM, sat_index)`` per satellite image, so a row's draw depends on nothing else.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import pandas as pd

FLIGHT_LIGHT_STREAM = 0x4C  # "L"
SAT_LIGHT_STREAM = 0x4C53  # "LS"
# Fog distance of the UAV view (metres, log-uniform): hazy summer day to clear air. The renderer's
# former fixed value, 2600 m, lies inside.
VISIBILITY_RANGE_M = (1500.0, 8000.0)


def _rng(seed: int, stream: int, index: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(stream, int(index))))


def assign_illumination(
    uav: pd.DataFrame, sat: pd.DataFrame, cities: Mapping[tuple[str, str], Any], seed: int
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Copies of the plan tables with illumination columns added.

    ``uav`` (columns ``city``, ``flight``): adds ``light`` (int, state of the city "now"),
    ``visibility_m`` (fog distance), ``sun_az`` (radians clockwise from north, [0, 2 pi)) and
    ``sun_el`` (radians above the horizon). ``sat`` (columns ``sat_index``, ``city``,
    ``variant``): adds ``light``, ``sun_az``, ``sun_el`` of its own state of ``(city, variant)``.
    ``cities`` maps ``(city, variant)`` to an object with ``n_lights`` and ``light_angles(k)``.
    """
    uav = uav.copy()
    light = np.zeros(len(uav), np.int64)
    vis, az, el = (np.zeros(len(uav)) for _ in range(3))
    lo, hi = (math.log(v) for v in VISIBILITY_RANGE_M)
    for flight, rows in uav.groupby("flight", sort=True).indices.items():
        city = cities[(uav.city.iloc[rows[0]], "now")]
        r = _rng(seed, FLIGHT_LIGHT_STREAM, flight)
        k = int(r.integers(city.n_lights))
        light[rows], vis[rows] = k, math.exp(r.uniform(lo, hi))
        az[rows], el[rows] = city.light_angles(k)
    uav["light"], uav["visibility_m"], uav["sun_az"], uav["sun_el"] = light, vis, az, el

    sat = sat.copy()
    sat_light = np.zeros(len(sat), np.int64)
    az = np.zeros(len(sat))
    el = np.zeros(len(sat))
    for j, r in enumerate(sat.itertuples(index=False)):
        city = cities[(r.city, r.variant)]
        sat_light[j] = _rng(seed, SAT_LIGHT_STREAM, r.sat_index).integers(city.n_lights)
        az[j], el[j] = city.light_angles(int(sat_light[j]))
    sat["light"] = sat_light
    sat["sun_az"], sat["sun_el"] = az, el
    return uav, sat


__all__ = ["VISIBILITY_RANGE_M", "assign_illumination"]
