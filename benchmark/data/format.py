"""The dataset directory on disk: atomic writes, checksums, the manifest and its verification.

Layout (all paths relative to the dataset root)::

    config.json            identity of the dataset (format, generator version, profile, seed);
                           written first, a resumed run must match it
    uav.parquet            one row per UAV image (pose, city, centre, flight, frame, ...)
    sat.parquet            one row per satellite image (pose, city, centre, height, footprint)
    pairs.parquet          one row per (split, pair): indices into both image stores + labels
    uav/shard_00000.npy    uint8 (n, H, W, 3) UAV images, rows [k * shard_size, ...)
    sat/shard_00000.npy    uint8 (m, H, W, 3) satellite images, rows [k * sat_shard_size, ...)
    manifest.json          written last: config, counts, splits and {path: bytes, sha256, shape}

Every file is written to a temporary name and renamed into place, so a killed run leaves either a
complete file or none; the manifest exists only once every shard does.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

FORMAT_VERSION = 2
MANIFEST = "manifest.json"
CONFIG = "config.json"
TABLES = ("uav.parquet", "sat.parquet", "pairs.parquet")


class DatasetError(RuntimeError):
    """A dataset directory is missing, incomplete or corrupted (the message names the file)."""


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` via a temporary file in the same directory and a rename."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    with open(tmp, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def npy_bytes(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.ascontiguousarray(array), allow_pickle=False)
    return buf.getvalue()


def atomic_save_npy(path: Path, array: np.ndarray) -> None:
    atomic_write_bytes(path, npy_bytes(array))


def canonical_json(obj: Any) -> bytes:
    """Deterministic JSON (sorted keys, fixed separators) so equal configs give equal bytes."""
    return (json.dumps(obj, sort_keys=True, indent=1, separators=(",", ": ")) + "\n").encode()


def sha256_file(path: Path, chunk: int = 1 << 22) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while block := fh.read(chunk):
            h.update(block)
    return h.hexdigest()


def shard_name(kind: str, k: int) -> str:
    return f"{kind}/shard_{k:05d}.npy"


def npy_complete(path: Path, shape: tuple[int, ...]) -> bool:
    """True if ``path`` is a whole uint8 .npy of ``shape`` (header parses, size matches)."""
    try:
        arr = np.load(path, mmap_mode="r", allow_pickle=False)
    except (OSError, ValueError):
        return False
    ok = arr.dtype == np.uint8 and tuple(arr.shape) == tuple(shape)
    ok = ok and path.stat().st_size == arr.offset + arr.nbytes
    del arr
    return bool(ok)


def file_entry(root: Path, rel: str, shape: tuple[int, ...] | None = None) -> dict[str, Any]:
    path = root / rel
    entry: dict[str, Any] = {"bytes": path.stat().st_size, "sha256": sha256_file(path)}
    if shape is not None:
        entry["shape"] = list(shape)
    return entry


def read_json(path: Path, what: str) -> dict[str, Any]:
    if not path.is_file():
        raise DatasetError(f"{what}: missing file {path}")
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise DatasetError(f"{what}: {path} is not valid JSON ({err})") from err


def read_manifest(root: Path) -> dict[str, Any]:
    """The manifest of a finished dataset; DatasetError naming the file if absent or wrong."""
    root = Path(root)
    if not root.is_dir():
        raise DatasetError(f"dataset directory {root} does not exist")
    path = root / MANIFEST
    if not path.is_file():
        hint = (
            " (simulate was interrupted; rerun it to resume)" if (root / CONFIG).is_file() else ""
        )
        raise DatasetError(f"{path} is missing: {root} is not a finished uavbench dataset{hint}")
    manifest = read_json(path, "manifest")
    if manifest.get("format_version") != FORMAT_VERSION:
        raise DatasetError(
            f"{path}: format_version {manifest.get('format_version')!r}, this code reads "
            f"{FORMAT_VERSION}; re-simulate the dataset"
        )
    return manifest


def verify_files(root: Path, manifest: dict[str, Any], names: list[str], *, checksum: bool) -> None:
    """Check that each file in ``names`` exists with the manifest's size (and sha256 if asked).

    Raises DatasetError naming the first bad file and what is wrong with it.
    """
    files = manifest["files"]
    for rel in names:
        if rel not in files:
            raise DatasetError(f"{root / MANIFEST} lists no file {rel!r}")
        entry, path = files[rel], Path(root) / rel
        if not path.is_file():
            raise DatasetError(f"missing file {path} (listed in {MANIFEST})")
        size = path.stat().st_size
        if size != entry["bytes"]:
            kind = "truncated" if size < entry["bytes"] else "oversized"
            raise DatasetError(f"{kind} file {path}: {size} bytes, manifest says {entry['bytes']}")
        if checksum and sha256_file(path) != entry["sha256"]:
            raise DatasetError(f"corrupted file {path}: sha256 differs from {MANIFEST}")
