"""Provenance tags: the git commit of the code and the hash of the dataset manifest."""

from __future__ import annotations

import hashlib
import subprocess
from collections.abc import Iterable
from pathlib import Path

# Names a dataset directory's manifest may have (the dataset format is owned by benchmark.data).
MANIFEST_NAMES = ("manifest.json", "manifest.yaml", "manifest.yml")


def git_commit(path: str | Path | None = None, *, ignore: Iterable[str | Path] = ()) -> str | None:
    """HEAD commit hash of the git work tree containing ``path`` (default: this package), or
    ``None`` outside git or without a git executable. A dirty tree gets the suffix ``-dirty``, so a
    result never claims a commit whose code it did not run. Changes under the directories
    ``ignore`` (a run's own outputs, e.g. the report it is writing into a committed
    ``reports/quick``) do not count; those outside the work tree are skipped."""
    where = Path(path) if path is not None else Path(__file__).resolve().parent
    if where.is_file():
        where = where.parent
    try:
        head = subprocess.run(
            ["git", "rev-parse", "HEAD", "--show-toplevel"],
            cwd=where,
            capture_output=True,
            text=True,
            timeout=10,
        )
        if head.returncode != 0:
            return None
        commit, top = head.stdout.splitlines()[:2]
        root = Path(top).resolve()
        excluded = []
        for directory in ignore:
            resolved = Path(directory).resolve()
            if resolved != root and resolved.is_relative_to(root):
                excluded.append(f":(top,exclude){resolved.relative_to(root).as_posix()}")
        pathspec = ["--", ":/", *excluded] if excluded else []
        status = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no", *pathspec],
            cwd=where,
            capture_output=True,
            text=True,
            timeout=30,
        )
    except (OSError, subprocess.SubprocessError, ValueError):
        return None
    dirty = status.returncode == 0 and bool(status.stdout.strip())
    return f"{commit}-dirty" if dirty else commit


def file_sha256(path: str | Path, chunk_bytes: int = 1 << 20) -> str:
    """Hex sha256 of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        while chunk := fh.read(chunk_bytes):
            digest.update(chunk)
    return digest.hexdigest()


def manifest_sha256(path: str | Path) -> str:
    """sha256 of a dataset manifest: ``path`` is the manifest file or a dataset directory holding
    one of :data:`MANIFEST_NAMES`. The manifest carries the checksums of every shard, so its hash
    identifies the whole dataset."""
    path = Path(path)
    if path.is_dir():
        for name in MANIFEST_NAMES:
            if (path / name).is_file():
                return file_sha256(path / name)
        expected = ", ".join(MANIFEST_NAMES)
        raise FileNotFoundError(
            f"dataset directory {path} holds no manifest (expected one of {expected})"
        )
    if not path.is_file():
        raise FileNotFoundError(f"dataset manifest {path} does not exist")
    return file_sha256(path)
