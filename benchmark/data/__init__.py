"""The dataset on disk and its PyTorch Dataset.

``PairDataset(root, split)`` reads a directory written by ``uavbench simulate`` (format in
``benchmark.data.format``); ``DATA_PROFILES`` / ``get_data_profile`` are the simulate profiles
(``DataProfile``; the reproduction's are ``benchmark.runner.plan.repro_profiles``). The writer
(``benchmark.data.writer``) needs the simulator and is imported only by the simulate command.

Odometry (issue 39): ``ODOMETRY_COLUMNS`` and ``require_odometry(table, where) -> (n, 4)`` read
the ``odo_*`` columns of a dataset's tables (or name the file that lacks them). The noise model
of the simulator's odometry, ``OdometryNoise``, ``odometry_noise(profile)`` (a profile or a
manifest's ``"profile"`` dict -> ``OdometryNoise`` in SI units) and ``flight_odometry(...)``, are
``benchmark.sim``'s, re-exported here for the packages that may not import the simulator
(evaluation, training); they import it on first use (a few seconds of numba).
"""

from typing import Any

from benchmark.data.dataset import PairDataset, list_splits
from benchmark.data.format import (
    ODOMETRY_COLUMNS,
    DatasetError,
    atomic_write_bytes,
    os_error_message,
    require_odometry,
)
from benchmark.data.profiles import DATA_PROFILES, DataProfile, get_data_profile

__all__ = [
    "DATA_PROFILES",
    "ODOMETRY_COLUMNS",
    "DataProfile",
    "DatasetError",
    "OdometryNoise",
    "PairDataset",
    "atomic_write_bytes",
    "flight_odometry",
    "get_data_profile",
    "list_splits",
    "odometry_noise",
    "os_error_message",
    "require_odometry",
]

# The simulator's odometry model, imported on first access (PEP 562): importing benchmark.sim
# compiles its numba kernels, which a reader of datasets does not need.
_FROM_SIM = ("OdometryNoise", "flight_odometry", "odometry_noise")


def __getattr__(name: str) -> Any:
    if name in _FROM_SIM:
        import benchmark.sim

        return getattr(benchmark.sim, name)
    raise AttributeError(f"module 'benchmark.data' has no attribute {name!r}")
