"""``PairDataset``: the UAV/satellite pairs of one split, memory-mapped from a dataset directory.

Opening checks the manifest and every file the split needs: existence and size always, sha256
with ``verify="sha256"`` (the default): each file is hashed once (about 1 s per GB) and its
verdict cached on disk by file identity, so later opens, in any process, cost a ``stat`` per file
(``benchmark.data.integrity``); ``verify="size"`` skips the hashing, ``"full"`` always hashes.
A missing, truncated or corrupted file raises ``DatasetError`` naming it. UAV shards are opened
with ``np.load(mmap_mode="r")`` once per process (lazily, so forked DataLoader workers map them
themselves), never per item. The satellite images, one per centre and height (a few dozen), are
read into memory once.

``satellite="swap"`` is the satellite-swap probe: every pair gets the satellite image of another
place (rules in ``benchmark.data.swap``) and keeps its labels.

Each item also carries ``context``: the per-sample geometry a pair encoder may use (the UAV
camera's field of view, the served satellite image's footprint and capture height) and the
gravity-aided protocol's sensor priors: pitch and roll as an IMU gives them and the height above
the ground at the centre as an altimeter gives it, the true values plus Gaussian noise of
:data:`PRIOR_SIGMA` (1 deg, 1 deg, 2 m), drawn once per split from a generator seeded by the
dataset seed and the split name, so every model sees the same priors for the same item.
"""

from __future__ import annotations

import math
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch
from torch.utils.data import Dataset

from benchmark.data.format import MANIFEST, TABLES, DatasetError, read_manifest, shard_name
from benchmark.data.integrity import MODES, check_files
from benchmark.data.swap import SATELLITE_MODES, swap_targets

R_COLUMNS = [f"R{i}{j}" for i in range(3) for j in range(3)]  # row-major, as written by simulate
# Noise of the gravity-aided protocol's priors (pitch rad, roll rad, altitude m): a consumer IMU's
# attitude after fusion is good to about 1 deg, a barometric altimeter to about 2 m over a flight.
PRIOR_SIGMA = (math.radians(1.0), math.radians(1.0), 2.0)
CONTEXT_KEYS = ("fov", "sat_footprint_m", "sat_height_m", "prior_attitude", "prior_altitude_m")


def prior_noise(seed: int, split: str, n: int) -> np.ndarray:
    """``(n, 3)`` float64 noise (pitch rad, roll rad, altitude m) of the priors of ``split``'s
    items, a function of the dataset ``seed`` and the split name only (not of the process, the
    satellite mode or the order of reading)."""
    key = zlib.crc32(split.encode("utf-8"))
    rng = np.random.default_rng(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, key, 0x5052]))
    return rng.standard_normal((n, 3)) * np.asarray(PRIOR_SIGMA)


def list_splits(root: str | Path) -> list[str]:
    """The split names of a finished dataset, in manifest order."""
    return list(read_manifest(Path(root))["splits"])


def _to_chw_float(img: np.ndarray) -> torch.Tensor:
    """uint8 ``(H, W, 3)`` -> float32 ``(3, H, W)`` in [0, 1]."""
    return torch.from_numpy(np.ascontiguousarray(img.transpose(2, 0, 1))).float().div_(255.0)


class PairDataset(Dataset):
    """UAV/satellite pairs of ``split`` under ``root`` (written by ``uavbench simulate``).

    Item ``i`` is a dict:
        ``uav``: float32 ``(3, H, W)`` in [0, 1]; ``sat``: float32 ``(3, H, W)`` in [0, 1];
        ``sat_id``: int64 ``()`` row of ``sat_images`` (equal ids = the same satellite image, so a
        model may encode each distinct one once per batch); ``R``: float32 ``(3, 3)``
        ``R_uav^sat`` (paper Eq. 2); ``T``: float32 ``(3,)`` ``[dE, dN, dU]`` metres, UAV minus
        satellite capture point; ``uav_euler``: float32 ``(3,)`` UAV ``(yaw, pitch, roll)``
        radians; ``index``: int64 ``()`` row of ``poses``; ``context``: a dict of float32
        tensors, ``fov`` ``()`` the UAV camera's horizontal field of view (rad),
        ``sat_footprint_m`` ``(2,)`` (E, N) metres covered by the served satellite image at the
        centre's terrain height, ``sat_height_m`` ``()`` its capture height above that terrain,
        ``prior_attitude`` ``(2,)`` (pitch, roll) rad and ``prior_altitude_m`` ``()`` the UAV's
        height above the terrain at the centre (``dU + sat_height_m`` of the true pair), both with
        the noise of :data:`PRIOR_SIGMA` (:func:`prior_noise`).

    ``satellite``: ``"true"`` (each pair's own satellite image) or ``"swap"`` (the image of another
    place, :func:`benchmark.data.swap.swap_targets`; ``sat`` and ``sat_id`` change, labels do not).

    Attributes: ``poses`` (DataFrame, one row per item, all label columns; ``sat_index`` is the
    true image), ``manifest``, ``splits`` (all split names), ``sat_images`` (uint8
    ``(M, H, W, 3)``), ``sat_table``, ``satellite``, ``swap_map`` (``{true: served}`` sat indices;
    empty for ``"true"``), ``served_sat_index`` (int64 ``(N,)``, the image each item serves).
    """

    def __init__(
        self, root: str | Path, split: str, *, verify: str = "sha256", satellite: str = "true"
    ) -> None:
        if verify not in MODES:
            raise ValueError(f"PairDataset: verify must be one of {MODES}, got {verify!r}")
        if satellite not in SATELLITE_MODES:
            raise ValueError(
                f"PairDataset: satellite must be one of {SATELLITE_MODES}, got {satellite!r}"
            )
        self.satellite = satellite
        self.root = Path(root)
        self.manifest = read_manifest(self.root)
        self.splits = list(self.manifest["splits"])
        if split not in self.splits:
            raise ValueError(
                f"PairDataset: unknown split {split!r} in {self.root}; available: {self.splits}"
            )
        self.split = split
        check_files(self.root, self.manifest, TABLES, mode=verify)
        pairs = pd.read_parquet(self.root / "pairs.parquet")
        self.poses = pairs[pairs.split == split].reset_index(drop=True)
        if len(self.poses) != self.manifest["splits"][split]:
            raise DatasetError(
                f"{self.root / 'pairs.parquet'}: {len(self.poses)} rows for split {split!r}, "
                f"{MANIFEST} says {self.manifest['splits'][split]}"
            )
        self.sat_table = pd.read_parquet(self.root / "sat.parquet")
        self.shard_size = int(self.manifest["shard_size"])

        self._uav_index = self.poses["uav_index"].to_numpy(np.int64)
        self._sat_index = self.poses["sat_index"].to_numpy(np.int64)
        self.swap_map: dict[int, int] = {}
        if satellite == "swap":
            self.swap_map = swap_targets(self.sat_table, split, self._sat_index)
            self._sat_index = np.array([self.swap_map[int(s)] for s in self._sat_index], np.int64)
        self.served_sat_index = self._sat_index
        uav_shards = sorted(set((self._uav_index // self.shard_size).tolist()))
        n_sat_shards = -(-len(self.sat_table) // int(self.manifest["sat_shard_size"]))
        sat_names = [shard_name("sat", k) for k in range(n_sat_shards)]
        uav_names = [shard_name("uav", k) for k in uav_shards]
        check_files(self.root, self.manifest, sat_names + uav_names, mode=verify)

        self.sat_images = np.concatenate(
            [np.load(self.root / n, allow_pickle=False) for n in sat_names]
        )
        self._R = self.poses[R_COLUMNS].to_numpy(np.float32).reshape(-1, 3, 3)
        self._T = self.poses[["dE", "dN", "dU"]].to_numpy(np.float32)
        self._euler = self.poses[["yaw", "pitch", "roll"]].to_numpy(np.float32)
        self._context = self._make_context()
        self._maps: dict[int, np.ndarray] = {}

    def _make_context(self) -> dict[str, np.ndarray]:
        """The ``context`` fields of every item as float32 arrays (first axis = item)."""
        fov = float(self.manifest.get("profile", {}).get("fov_deg", float("nan")))
        if not (math.isfinite(fov) and 0.0 < fov < 179.0):
            raise DatasetError(
                f"{self.root / MANIFEST}: profile.fov_deg must be in (0, 179) degrees, got {fov!r}"
            )
        served = self.sat_table.set_index("sat_index").loc[self._sat_index]
        n = len(self.poses)
        noise = prior_noise(int(self.manifest.get("seed", 0)), self.split, n)
        euler = self.poses[["pitch", "roll"]].to_numpy(np.float64)
        altitude = self.poses["dU"].to_numpy(np.float64) + self.poses["sat_height_m"].to_numpy(
            np.float64
        )
        return {
            "fov": np.full(n, math.radians(fov), np.float32),
            "sat_footprint_m": served[["footprint_E_m", "footprint_N_m"]].to_numpy(np.float32),
            "sat_height_m": served["height_m"].to_numpy(np.float32),
            "prior_attitude": (euler + noise[:, :2]).astype(np.float32),
            "prior_altitude_m": (altitude + noise[:, 2]).astype(np.float32),
        }

    def __len__(self) -> int:
        return len(self.poses)

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_maps"] = {}  # memory maps are reopened by each process, never pickled (copied)
        return state

    def _shard(self, k: int) -> np.ndarray:
        arr = self._maps.get(k)
        if arr is None:
            path = self.root / shard_name("uav", k)
            try:
                arr = np.load(path, mmap_mode="r", allow_pickle=False)
            except (OSError, ValueError) as err:
                raise DatasetError(f"cannot memory-map {path}: {err}") from err
            self._maps[k] = arr
        return arr

    def uav_image(self, i: int) -> np.ndarray:
        """The uint8 ``(H, W, 3)`` UAV image of item ``i`` (a view into the memory map)."""
        u = int(self._uav_index[i])
        return self._shard(u // self.shard_size)[u % self.shard_size]

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        if not -len(self) <= i < len(self):
            raise IndexError(f"PairDataset[{i}]: split {self.split!r} has {len(self)} items")
        i = int(i) % len(self)
        s = int(self._sat_index[i])
        return {
            "uav": _to_chw_float(self.uav_image(i)),
            "sat": _to_chw_float(self.sat_images[s]),
            "sat_id": torch.tensor(s, dtype=torch.int64),
            "R": torch.from_numpy(self._R[i].copy()),
            "T": torch.from_numpy(self._T[i].copy()),
            "uav_euler": torch.from_numpy(self._euler[i].copy()),
            "index": torch.tensor(i, dtype=torch.int64),
            "context": {k: torch.from_numpy(np.array(v[i])) for k, v in self._context.items()},
        }
