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
    .simulate.lock         while simulate runs: its pid, host and start (benchmark.locks)
    .render-journal.jsonl  while unfinished: sha256 of each shard as rendered (data.journal)

**Odometry columns** (issue 39; :data:`ODOMETRY_COLUMNS`, float64, on every row of
``uav.parquet`` and carried to every row of ``pairs.parquet``): the motion from the previous
sample of the same flight (by ``frame``) to this one, as a consumer IMU plus visual odometry
reports it. ``odo_dyaw`` (rad, wrapped to (-pi, pi]): the measured heading increment;
``odo_dx``, ``odo_dy``, ``odo_dz`` (m): the measured displacement in the *levelled heading frame of
the previous sample* (x right, y forward, z up: the body frame with pitch and roll removed,
``Rz(yaw_prev)^T (dE, dN, dU)``). NaN on the first sample of every flight. Simulated datasets
measure them with the profile's ``odometry_*`` noise figures (``benchmark.sim.odometry``); a
user's real data brings its own in the same columns, frame and units. Readers that need them call
:func:`require_odometry`, which names the file and the missing columns. New columns that old
readers can ignore do not change ``FORMAT_VERSION``; it changes when a reader of the old format
could no longer read the files.

Every file is written to a temporary name and renamed into place, so a killed run leaves either a
complete file or none; the manifest exists only once every shard does. Its digests are those
of the bytes simulate rendered, never of whatever is found on disk. Opening a dataset checks them
once per file and caches the verdict outside the dataset (``benchmark.data.integrity``).
"""

from __future__ import annotations

import errno
import hashlib
import io
import json
import os
import shutil
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # the writer's and the dataset's tables; format itself needs no pandas
    import pandas as pd

FORMAT_VERSION = 2
# The odometry columns (module docstring); equal to benchmark.sim.ODOMETRY_COLUMNS (tested: the
# format is the data package's, and reading it needs no simulator).
ODOMETRY_COLUMNS: tuple[str, ...] = ("odo_dyaw", "odo_dx", "odo_dy", "odo_dz")
MANIFEST = "manifest.json"
CONFIG = "config.json"
TABLES = ("uav.parquet", "sat.parquet", "pairs.parquet")


class DatasetError(RuntimeError):
    """A dataset directory is missing, incomplete or corrupted (the message names the file)."""


def require_odometry(table: pd.DataFrame, where: str | Path) -> np.ndarray:
    """The odometry of every row of ``table`` (``uav.parquet`` or ``pairs.parquet`` rows) as
    float64 ``(n, 4)``, columns in :data:`ODOMETRY_COLUMNS` order (``odo_dyaw`` rad, ``odo_dx,
    odo_dy, odo_dz`` m; NaN on a flight's first sample). ``where`` names the file the table came
    from; a table without some of the columns raises :class:`DatasetError` naming it and them."""
    missing = [c for c in ODOMETRY_COLUMNS if c not in table.columns]
    if missing:
        raise DatasetError(
            f"{where}: no odometry columns {missing} (a dataset from before issue 39: "
            f"re-simulate it; real data must bring odo_dyaw (rad), odo_dx, odo_dy, odo_dz (m, in "
            f"the levelled heading frame of the previous sample of the flight), NaN on a "
            f"flight's first sample; benchmark.data.format)"
        )
    return table[list(ODOMETRY_COLUMNS)].to_numpy(np.float64)


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` via a temporary file in the same directory and a rename."""
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except OSError as err:
        # A failed write (disk full, quota, permissions) leaves no partial file and names the
        # file it was writing: a bare ``[Errno 28]`` from ``write`` carries no path.
        try:
            tmp.unlink(missing_ok=True)
        except OSError:
            pass
        if err.filename is None or err.filename == str(tmp):
            raise OSError(err.errno, err.strerror, str(path)) from err
        raise


# errno -> (what happened, how to fix it). These are the environment's problems, not the
# program's or the data's: the commands report them in one line and exit 2 (as for bad input).
_OS_FIXES = {
    errno.ENOSPC: ("no space left on the device", "free space there (or choose another"
                   " directory) and rerun the same command: finished work is kept"),
    errno.EDQUOT: ("disk quota exceeded", "free space in your quota and rerun the same command"),
    errno.EACCES: ("permission denied", "fix the permissions or choose a directory you can write"),
    errno.EPERM: ("operation not permitted", "fix the permissions or choose another directory"),
    errno.EROFS: ("read-only file system", "choose a writable directory"),
}  # fmt: skip


def os_error_message(err: OSError) -> str | None:
    """One line naming the path, what happened and the fix, for disk-full and permission errors;
    None for other OS errors (a bug or an unexpected state: let them surface)."""
    if err.errno not in _OS_FIXES:
        return None
    what, fix = _OS_FIXES[err.errno]
    where = err.filename if err.filename is not None else "(path unknown)"
    free = ""
    if err.errno == errno.ENOSPC and err.filename is not None:
        try:
            probe = Path(err.filename)
            while not probe.exists() and probe != probe.parent:
                probe = probe.parent
            free = f", {shutil.disk_usage(probe).free / 1e9:.2f} GB free"
        except OSError:
            pass
    return f"{where}: {what}{free}; {fix}"


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
