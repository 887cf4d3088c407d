"""Many towns (issue 9): procedurally distinct small tiles for the ``towns/*`` splits.

A paper city is one large tile flown around six centres, so a model trained on it can memorise its
landmarks and read the UAV's heading and position from the UAV image alone. The towns family has
many small towns instead (each its own world seed, districts and illumination states) with one
flight centre, the tile centre: training towns are never seen at test time, so only the satellite
image says where the UAV is and which way it looks.

Roles: ``train``, ``val`` and ``test`` towns alternate the training styles (oxford, cambridge);
``london`` towns are of the held-out style. Town names are ``town-<role><k:02d>-<style>``; each
name is a city key of the plan (``pairs.city``), its style in ``pairs.style``. A confirmation draw
``d`` (``confirm/towns``, issue 38) adds as many towns as the ``test`` role has, of the training
styles, role ``confirm<d>``: ``town-confirm<d>-<k:02d>-<style>``, world seeds of their own.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from benchmark.sim.seeds import city_seed
from benchmark.sim.world import City, build_city

TOWN_ROLES: tuple[str, ...] = ("train", "val", "test", "london")


@dataclass(frozen=True)
class Town:
    """One town of the towns family: its plan name, style, role and world seed."""

    name: str
    style: str
    role: str
    seed: int


def town_list(
    n_towns: tuple[int, ...],
    seed: int,
    *,
    train_styles: tuple[str, ...] = ("oxford", "cambridge"),
    london_style: str = "london",
    confirm_draw: int = 0,
) -> list[Town]:
    """The towns of a dataset with ``seed``: ``n_towns[r]`` towns of role ``TOWN_ROLES[r]``, then
    (``confirm_draw`` > 0) ``n_towns[test]`` towns of role ``confirm<confirm_draw>``.

    World seeds come from ``city_seed(seed, style, "town-<role><k>")``: independent of every other
    town and of the paper cities, identical on every machine.
    """
    if len(n_towns) != len(TOWN_ROLES) or any(int(n) != n or n < 0 for n in n_towns):
        raise ValueError(
            f"n_towns must be {len(TOWN_ROLES)} non-negative integers {TOWN_ROLES}, got {n_towns}"
        )
    towns = []
    for role, n in zip(TOWN_ROLES, n_towns, strict=True):
        for k in range(int(n)):
            style = london_style if role == "london" else train_styles[k % len(train_styles)]
            variant = f"town-{role}{k}"
            towns.append(
                Town(f"town-{role}{k:02d}-{style}", style, role, city_seed(seed, style, variant))
            )
    if confirm_draw:
        role = f"confirm{int(confirm_draw)}"
        for k in range(int(n_towns[TOWN_ROLES.index("test")])):
            style = train_styles[k % len(train_styles)]
            seed_k = city_seed(seed, style, f"town-{role}-{k}")
            towns.append(Town(f"town-{role}-{k:02d}-{style}", style, role, seed_k))
    return towns


def build_town(
    town: Town,
    *,
    size_m: tuple[float, float],
    metres_per_px: float,
    cache_dir: str | Path | bool | None = None,
) -> City:
    """The world of ``town`` (cached like ``build_city``) with one flight centre, the tile centre,
    so the satellite footprint around it stays inside the tile when the tile holds it."""
    city = build_city(
        town.style, town.seed, cache_dir=cache_dir, size_m=size_m, metres_per_px=metres_per_px
    )
    return replace(city, flight_centres=np.zeros((1, 2)))


__all__ = ["TOWN_ROLES", "Town", "build_town", "town_list"]
