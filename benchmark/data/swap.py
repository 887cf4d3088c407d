"""The satellite-swap probe: which wrong satellite image each pair of a split gets.

A model that really matches the UAV view against the satellite image must get worse when it is
shown the satellite image of another place. ``PairDataset(root, split, satellite="swap")`` serves
every pair with the image :func:`swap_targets` picks for its true image; labels are unchanged.

Rules (deterministic; one replacement per true satellite image, so pairs that share an image share
its replacement and the model still encodes each distinct image once):

- The replacement always shows another place, a different ``(city, centre)``, and has the same
  capture height, footprint and variant (``now`` / ``earlier``) as the true image, so only the
  place differs.
- The replacement never shows ground of the true image: an image of another city (another world)
  always qualifies, one of the same city only when the two footprints do not overlap. (Until issue
  21 the default was the next centre of the same city; a city's centres lie 400-900 m apart while an
  image covers 2 km x 1 km, so the "other place" showed much of the true one, and a matcher that
  searches the whole image still found the UAV in it: 26% of yaws within 10 deg on standard/test.)
- Default (standard, frames, height, pitch splits): another paper city of the split (oxford <->
  cambridge), spread over its images by the true image's rank; else a centre of the same city whose
  footprint does not overlap the true one (the cyclic successor among those); else any other paper
  city.
- ``generalized/test`` (london only): another city's image, never london: the paper cities outside
  the split (oxford, cambridge), spread over them by the true image's rank.
- ``towns/*`` (one centre per town): another town of the same split, the cyclic successor among
  its towns; if the split has one town, another town of the same style, then any other town.
- If no image of the same height, footprint and variant qualifies (a flight-test split whose city
  has a footprint of its own), the same tiers are tried with the height alone matching, then (a
  dataset too small to hold another city at that height, e.g. smoke's height splits) with nothing
  matching. If nothing qualifies either, :class:`~benchmark.data.format.DatasetError` says so.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import pandas as pd

from benchmark.data.format import DatasetError

SATELLITE_MODES = ("true", "swap")
_STRICT = ("height_m", "footprint_E_m", "footprint_N_m", "variant")
_RELAXED = ("height_m",)


def _is_town(sat: pd.DataFrame) -> pd.Series:
    """Towns are plan cities whose name differs from their style (``town-test03-oxford``)."""
    if "style" not in sat:
        return pd.Series(False, index=sat.index)
    return sat["city"] != sat["style"]


def _family(split: str) -> str:
    if split == "generalized/test":
        return "other-city"
    if split.startswith("towns/"):
        return "towns"
    return "centre"


def _successor(pool: pd.DataFrame, source: int) -> int | None:
    """The image after ``source`` in ``pool`` (sorted by city, centre), cyclically; None if the
    pool holds no other place."""
    places = pool.drop_duplicates(["city", "centre"])
    order = list(places["sat_index"])
    src = pool.loc[pool["sat_index"] == source]
    key = (src["city"].iloc[0], int(src["centre"].iloc[0]))
    keys = list(zip(places["city"], places["centre"].astype(int), strict=True))
    if len(keys) < 2 or key not in keys:
        return None
    return int(order[(keys.index(key) + 1) % len(keys)])


def _spread(candidates: pd.DataFrame, rank: int) -> int | None:
    return None if candidates.empty else int(candidates["sat_index"].iloc[rank % len(candidates)])


def _disjoint(pool: pd.DataFrame, row: pd.Series) -> pd.Series:
    """True where an image's ground footprint does not overlap ``row``'s (same world assumed:
    compare within one city). Without centre coordinates nothing is known to be disjoint."""
    if not {"E", "N"} <= set(pool.columns):
        return pd.Series(False, index=pool.index)
    half_e = 0.5 * (pool["footprint_E_m"] + row["footprint_E_m"])
    half_n = 0.5 * (pool["footprint_N_m"] + row["footprint_N_m"])
    return ((pool["E"] - row["E"]).abs() >= half_e) | ((pool["N"] - row["N"]).abs() >= half_n)


def _pick(sat: pd.DataFrame, source: int, family: str, split_cities: set[str], match) -> int | None:
    row = sat.loc[source]
    same = np.ones(len(sat), dtype=bool)
    for col in match:
        same &= (sat[col] == row[col]).to_numpy()
    pool = sat[same]
    other_place = (pool["city"] != row["city"]) | (pool["centre"] != row["centre"])
    town = _is_town(pool)
    in_split = pool["city"].isin(split_cities)
    rank = list(pool["sat_index"]).index(source)
    if family == "other-city":
        tiers = [
            lambda: _spread(pool[~in_split & ~town], rank),
            lambda: _spread(pool[~in_split & other_place], rank),
        ]
    elif family == "towns":
        styles = pool["style"] if "style" in pool else pool["city"]
        same_style = styles == (row["style"] if "style" in sat else row["city"])
        tiers = [
            lambda: _successor(pool[in_split & town], source),
            lambda: _spread(pool[town & same_style & ~in_split], rank),
            lambda: _spread(pool[town & other_place], rank),
        ]
    else:
        other_city = pool["city"] != row["city"]
        apart = _disjoint(pool, row) & (pool["city"] == row["city"])
        tiers = [
            lambda: _spread(pool[in_split & ~town & other_city], rank),
            lambda: _successor(pool[apart | (pool["sat_index"] == source)], source),
            lambda: _spread(pool[~town & other_city], rank),
        ]
    for tier in tiers:
        target = tier()
        if target is not None:
            return target
    return None


def swap_targets(sat_table: pd.DataFrame, split: str, used: Iterable[int]) -> dict[int, int]:
    """``{true sat_index: replacement sat_index}`` for the images ``used`` by ``split``.

    Args:
        sat_table: the dataset's ``sat.parquet`` (columns ``sat_index``, ``city``, ``centre``,
            ``variant``, ``height_m``, ``footprint_E_m``, ``footprint_N_m``; ``style`` if any).
        split: the split's name (chooses the rule, see the module docstring).
        used: the true satellite indices of the split's pairs.
    Raises:
        DatasetError: when an image has no replacement of another place.
    """
    sat = sat_table.sort_values(["city", "centre", "sat_index"], kind="stable").set_index(
        "sat_index", drop=False
    )
    used = sorted({int(i) for i in used})
    missing = [i for i in used if i not in sat.index]
    if missing:
        raise DatasetError(f"swap_targets: satellite indices {missing} are not in the sat table")
    split_cities = set(sat.loc[used, "city"])
    family = _family(split)
    out = {}
    for source in used:
        target = None
        for match in (_STRICT, _RELAXED, ()):
            target = _pick(sat, source, family, split_cities, match)
            if target is not None:
                break
        if target is None:
            row = sat.loc[source]
            raise DatasetError(
                f"split {split!r}: no satellite image of another place to swap in for image "
                f"{source} ({row['city']} centre {row['centre']}, {row['height_m']:g} m)"
            )
        out[source] = target
    return out
