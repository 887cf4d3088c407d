"""Content checksums verified once per file and cached, so every later open costs a ``stat``.

``check_files(root, manifest, names, mode="sha256")`` is what opening a dataset runs:

- ``"size"``: existence and size only (the cheap opt-out).
- ``"sha256"`` (default): existence, size, then sha256 against the manifest, but only for a file
  whose identity is not in the cache yet. A file's identity is ``(bytes, mtime_ns, ctime_ns, ino,
  dev)`` plus the digest the manifest expects. Any write to the file changes its mtime and ctime
  (a flipped byte, a same-size rewrite, a swapped label); restoring the mtime afterwards
  (``touch -r``, ``cp -p``) cannot restore the ctime; replacing it (copy, rename) changes the inode.
  Each of these makes the file be hashed again. What a stat cannot see (bit rot on the medium) is
  what ``uavbench verify`` is for: it hashes everything, always.
- ``"full"``: always hash (``uavbench verify``), and record the good ones in the cache.

The cache is one small JSON file per dataset under ``$UAVBENCH_VERIFY_CACHE`` (default
``$XDG_CACHE_HOME/uavbench/verified`` or ``~/.cache/uavbench/verified``), named by the dataset's
absolute path. It lives outside the dataset so read-only and shared datasets work and the
dataset's bytes never change; each user hashes a shared dataset once. Writes are atomic
(temporary file + rename) and a failed write (read-only home, disk full) is ignored: the next
process hashes again, nothing else is lost. Concurrent writers may drop each other's new entries
(the file is replaced whole), which costs a re-hash, never a false pass: an entry holds the
digest the manifest expected, and is used only when the manifest still expects it.

Cost: ``uavbench bench verify`` measures a first (hashing) open against later (stat) opens.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from benchmark.data.format import MANIFEST, DatasetError, sha256_file

MODES = ("sha256", "size", "full")
CACHE_VERSION = 1
_MEMO: dict[str, dict[str, Any]] = {}  # cache file -> its entries, loaded once per process
# A file changed within this many ns of being hashed may change again within the same timestamp
# tick (the kernel's clock is coarse, ~4 ms) without a visible mtime change ("racy git"): such a
# file is hashed but not cached.
RACY_NS = 2_000_000_000


def cache_dir() -> Path:
    """Where verification caches live (see the module docstring)."""
    env = os.environ.get("UAVBENCH_VERIFY_CACHE")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "uavbench" / "verified"


def cache_file(root: Path) -> Path:
    """The cache file of the dataset at ``root`` (by its absolute, symlink-free path)."""
    key = hashlib.sha256(str(Path(root).resolve()).encode()).hexdigest()[:20]
    return cache_dir() / f"{key}.json"


def identity(path: Path, expected_sha256: str) -> list[Any]:
    """What must be unchanged for a cached verdict on ``path`` to hold (see module docstring)."""
    st = path.stat()
    return [st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino, st.st_dev, expected_sha256]


def _load(file: Path) -> dict[str, Any]:
    key = str(file)
    if key not in _MEMO:
        entries: dict[str, Any] = {}
        try:
            data = json.loads(file.read_text())
            if data.get("version") == CACHE_VERSION and isinstance(data.get("files"), dict):
                entries = data["files"]
        except (OSError, ValueError, AttributeError):
            pass  # absent or damaged: start empty (the cost is hashing again)
        _MEMO[key] = entries
    return _MEMO[key]


def _store(file: Path, root: Path, entries: dict[str, Any]) -> None:
    """Merge ``entries`` into the cache file; silently give up if it cannot be written."""
    merged = dict(_load(file))
    try:  # entries another process wrote since we loaded
        on_disk = json.loads(file.read_text()).get("files", {})
        merged = {**on_disk, **merged}
    except (OSError, ValueError, AttributeError):
        pass
    merged.update(entries)
    _MEMO[str(file)] = merged
    root_text = str(Path(root).resolve())
    text = json.dumps({"version": CACHE_VERSION, "root": root_text, "files": merged})
    tmp = file.with_name(f".{file.name}.tmp{os.getpid()}")
    try:
        file.parent.mkdir(parents=True, exist_ok=True)
        tmp.write_text(text)
        os.replace(tmp, file)
    except OSError:
        try:
            tmp.unlink(missing_ok=True)
        except OSError:
            pass


def check_size(root: Path, manifest: dict[str, Any], rel: str) -> str | None:
    """What is wrong with ``rel``'s presence or size (None: fine)."""
    files = manifest["files"]
    if rel not in files:
        return f"{root / MANIFEST} lists no file {rel!r}"
    path = Path(root) / rel
    if not path.is_file():
        return f"missing file {path} (listed in {MANIFEST})"
    size, want = path.stat().st_size, files[rel]["bytes"]
    if size != want:
        kind = "truncated" if size < want else "oversized"
        return f"{kind} file {path}: {size} bytes, {MANIFEST} says {want}"
    return None


def check_files(
    root: str | Path,
    manifest: dict[str, Any],
    names: Iterable[str],
    *,
    mode: str = "sha256",
    on_bytes: Callable[[int], None] | None = None,
    collect: list[tuple[str, str]] | None = None,
) -> None:
    """Check ``names`` (paths relative to ``root``) against ``manifest`` in ``mode``.

    Raises DatasetError naming the first bad file and what is wrong, unless ``collect`` is given:
    then every problem is appended to it as ``(rel, message)`` and checking goes on. ``on_bytes(n)``
    is called with the bytes of each file checked (hashed or found in the cache), for progress.
    """
    if mode not in MODES:
        raise ValueError(f"verify must be one of {MODES}, got {mode!r}")
    root = Path(root)
    file = cache_file(root)
    cached = _load(file) if mode != "size" else {}
    fresh: dict[str, Any] = {}
    for rel in names:
        problem = check_size(root, manifest, rel)
        if problem is None and mode != "size":
            want = manifest["files"][rel]["sha256"]
            ident = identity(root / rel, want)
            if mode == "full" or cached.get(rel) != ident:
                if sha256_file(root / rel) == want:
                    if time.time_ns() - max(ident[1], ident[2]) > RACY_NS:
                        fresh[rel] = ident
                else:
                    problem = f"corrupted file {root / rel}: sha256 differs from {MANIFEST}"
        if on_bytes is not None and problem is None:
            on_bytes(int(manifest["files"][rel]["bytes"]))
        if problem is not None:
            if collect is None:
                if fresh:
                    _store(file, root, fresh)
                raise DatasetError(problem)
            collect.append((rel, problem))
    if fresh:
        _store(file, root, fresh)
