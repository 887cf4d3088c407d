"""The seeds of worlds and renders, derived from the dataset seed (below the plan and the towns).

Every seed is a ``numpy.random.SeedSequence`` spawn key of the dataset seed and a tag of its own,
so it is identical on every machine and depends on nothing else: a world (``city_seed``) on its
style and variant, a UAV render (``sample_seed``) on its global sample index. ``splits`` (the
plan) and ``towns`` (the towns family) both draw from here, so neither imports the other.
"""

from __future__ import annotations

import numpy as np

SAMPLE_STREAM = 0x53  # spawn-key tag of per-sample render seeds
CITY_STREAM = 0x43  # spawn-key tag of world seeds


def sample_seed(seed: int, index: int) -> np.random.SeedSequence:
    """The render seed of global UAV sample ``index``: depends on nothing else."""
    return np.random.SeedSequence(int(seed), spawn_key=(SAMPLE_STREAM, int(index)))


def city_seed(seed: int, style: str, variant: str = "now") -> int:
    """The world seed of ``style`` in a dataset with ``seed`` (a 31-bit int)."""
    key = tuple(ord(c) for c in f"{style}/{variant}")
    return (
        int(np.random.SeedSequence(int(seed), spawn_key=(CITY_STREAM, *key)).generate_state(1)[0])
        >> 1
    )


__all__ = ["CITY_STREAM", "SAMPLE_STREAM", "city_seed", "sample_seed"]
