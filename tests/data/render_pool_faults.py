"""Workers that die, for ``test_render_pool.py`` (a module of its own: spawned render workers
import the city factories below by name, so they cannot live in a test module's closure).

``python render_pool_faults.py MODE`` renders one UAV shard with two workers whose city factory
(MODE ``init-kill``: SIGKILLs the worker while it starts; ``render-kill``: returns cities that
SIGKILL the worker when the renderer reads them; ``init-error``: raises) and prints the error the
pool raised, or ``no error``.
"""

from __future__ import annotations

import os
import signal
import sys
import tempfile
from pathlib import Path

import pandas as pd


class DyingCities(dict):
    """A cities mapping whose first lookup kills the worker (as the OOM killer would)."""

    def __getitem__(self, key):
        os.kill(os.getpid(), signal.SIGKILL)


class CityFactory:
    def __init__(self, mode: str) -> None:
        self.mode = mode

    def __call__(self) -> dict:
        if self.mode == "init-kill":
            os.kill(os.getpid(), signal.SIGKILL)
        if self.mode == "init-error":
            raise FileNotFoundError("city cache /nowhere/cities: no such directory")
        return DyingCities()


def main(mode: str) -> int:
    from benchmark.data.profiles import DATA_PROFILES
    from benchmark.data.render_pool import RenderContext, RenderPool, RenderWorkerError

    uav = pd.DataFrame(
        [dict(city="c0", E=0.0, N=0.0, U=300.0, yaw=0.0, pitch=-0.5, roll=0.0, light=0,
              visibility_m=5000.0, camera_effects=False, uav_index=i) for i in range(2)]
    )  # fmt: skip
    root = Path(tempfile.mkdtemp())
    ctx = RenderContext(root, DATA_PROFILES["smoke"], 0, {}, uav, uav.iloc[:0])
    try:
        with RenderPool(ctx, 2, CityFactory(mode)) as pool:
            list(pool.imap([("uav", 0)]))
    except RenderWorkerError as err:
        print(f"{type(err).__name__}: {err}")
        return 0
    print("no error")
    return 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
