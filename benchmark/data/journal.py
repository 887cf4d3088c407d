"""The render journal: which shard bytes ``simulate`` itself rendered, for resuming honestly.

While a dataset is being rendered, ``.render-journal.jsonl`` in its directory gets one line per
shard written: ``{"file", "sha256", "bytes", "source"}``, the digest of the bytes *as rendered*
(computed in memory before the write, ``source: "render"``). When a complete dataset is repaired,
the files that still match its manifest are journalled first (``source: "manifest"``: the
manifest was itself written from rendered bytes) and the manifest is removed.

A resumed run trusts a shard on disk only if the journal lists it and its bytes still hash to the
journalled digest; any other shard on disk (no journal line: the journal was lost with the
manifest, or the run was killed between the write and the line) is rendered again and compared
byte for byte (renders are deterministic). So no checksum reaches a manifest that was not
computed from rendered bytes. The journal is removed once the manifest is written.

A line cut short by a kill is ignored (that shard is then re-rendered and compared).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from benchmark.data.format import sha256_file

JOURNAL = ".render-journal.jsonl"


def read_journal(out: Path) -> dict[str, dict[str, Any]]:
    """``{relative path: {"sha256", "bytes", "source"}}``; the last line of a file wins."""
    entries: dict[str, dict[str, Any]] = {}
    path = Path(out) / JOURNAL
    if not path.is_file():
        return entries
    for line in path.read_text(errors="replace").splitlines():
        try:
            row = json.loads(line)
            entries[str(row["file"])] = {
                "sha256": str(row["sha256"]),
                "bytes": int(row["bytes"]),
                "source": str(row.get("source", "render")),
            }
        except (ValueError, KeyError, TypeError):
            continue  # a line cut short by a kill
    return entries


def append_journal(out: Path, rel: str, sha256: str, nbytes: int, source: str = "render") -> None:
    """Record that ``rel`` holds ``nbytes`` bytes with digest ``sha256`` (flushed to disk)."""
    line = json.dumps({"file": rel, "sha256": sha256, "bytes": nbytes, "source": source})
    with open(Path(out) / JOURNAL, "a") as fh:
        fh.write(line + "\n")
        fh.flush()
        os.fsync(fh.fileno())


def remove_journal(out: Path) -> None:
    (Path(out) / JOURNAL).unlink(missing_ok=True)


def trusted(out: Path, rel: str, journal: dict[str, dict[str, Any]]) -> dict[str, Any] | None:
    """The journal entry of ``rel`` if the file on disk still has its size and digest, else None
    (absent, not journalled, or changed since: the caller renders it again)."""
    entry = journal.get(rel)
    path = Path(out) / rel
    if entry is None or not path.is_file() or path.stat().st_size != entry["bytes"]:
        return None
    return entry if sha256_file(path) == entry["sha256"] else None
