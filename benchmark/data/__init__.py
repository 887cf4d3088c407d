"""The dataset on disk and its PyTorch Dataset.

``PairDataset(root, split)`` reads a directory written by ``uavbench simulate`` (format in
``benchmark.data.format``); ``PROFILES`` / ``get_profile`` are the simulate profiles. The writer
(``benchmark.data.writer``) needs the simulator and is imported only by the simulate command.
"""

from benchmark.data.dataset import PairDataset, list_splits
from benchmark.data.format import DatasetError, atomic_write_bytes, os_error_message
from benchmark.data.profiles import PROFILES, Profile, get_profile

__all__ = [
    "PROFILES",
    "DatasetError",
    "PairDataset",
    "Profile",
    "atomic_write_bytes",
    "get_profile",
    "list_splits",
    "os_error_message",
]
