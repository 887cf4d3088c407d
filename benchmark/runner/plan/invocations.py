"""The journal of a work directory's reproductions: ``<workdir>/invocations.jsonl``, append-only.

An invocation appends a ``start`` record as soon as it holds the work directory's lock, one
``unit`` record as each unit it trained finishes (ok or failed), and an ``end`` record with its
final state. Each record is one ``write`` of one line on a file opened with ``O_APPEND``, so a
``kill -9`` loses at most the record being written (a cut last line is skipped when read) and an
invocation killed mid-way still shows the units it finished. :func:`read_invocations` merges the
records of each invocation (by ``id``) into one summary:

    {"id", "started" (UTC, "%Y-%m-%d %H:%M"), "wall_s", "trained" (units trained ok),
     "failed" (units that failed), "units" (planned), "unit_keys" (planned),
     "trained_keys" (trained ok or failed), "machine", "git_commit", "pid", "host", "state"}

``state`` is the ``end`` record's (``finished``, ``failed``, ``interrupted``), else ``running``
while its process lives (it still holds the work directory's lock, :func:`owner_alive`) and
``killed/unfinished`` when it is gone; ``wall_s`` is then the time from its start to its last
record. Lines written before this journal existed (one record per invocation, written at its
end) are read as finished invocations.
"""

from __future__ import annotations

import json
import os
import platform
import socket
import time
import uuid
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from benchmark.locks import read_holder

JOURNAL = "invocations.jsonl"
LOCK = ".reproduce.lock"  # ``benchmark.locks.work_lock`` of the work directory
# Tags naming the invocation that owns a tracked run (its parent and training runs).
OWNER_TAGS = ("uavbench.owner_pid", "uavbench.owner_host", "uavbench.owner_workdir")
KILLED_STATE = "killed/unfinished"


def _stamp(seconds: float) -> str:
    return time.strftime("%Y-%m-%d %H:%M", time.gmtime(seconds))


def _append(path: Path, record: dict[str, Any]) -> None:
    """One line in one ``write`` on an ``O_APPEND`` descriptor (atomic against other appenders
    on a local filesystem; a kill between records loses nothing already written)."""
    line = (json.dumps(record, sort_keys=True) + "\n").encode()
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, line)
    finally:
        os.close(fd)


@dataclass
class Invocation:
    """This process's entry in the journal (see the module docstring)."""

    path: Path
    id: str
    started: float
    trained: int = 0
    failed: int = 0

    def unit_done(self, key: str, ok: bool) -> None:
        """Record that the unit ``key`` was trained (``ok``) or failed in this invocation."""
        if ok:
            self.trained += 1
        else:
            self.failed += 1
        _append(self.path, {"id": self.id, "event": "unit", "key": key, "ok": ok,
                            "t": time.time()})  # fmt: skip

    def end(self, state: str, wall_s: float | None = None) -> None:
        """The final record: ``state`` is ``finished``, ``failed`` or ``interrupted``."""
        wall = time.time() - self.started if wall_s is None else wall_s
        _append(self.path, {"id": self.id, "event": "end", "state": state, "wall_s": wall,
                            "t": time.time()})  # fmt: skip


def start_invocation(
    workdir: Path, unit_keys: Iterable[str], git_commit: str, started: float | None = None
) -> Invocation:
    """Append the start record of this process's invocation to ``workdir``'s journal."""
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    keys = sorted(set(unit_keys))
    begun = time.time() if started is None else started
    inv = Invocation(workdir / JOURNAL, uuid.uuid4().hex[:16], begun)
    _append(
        inv.path,
        {
            "id": inv.id, "event": "start", "t": begun, "started": _stamp(begun),
            "units": len(keys), "unit_keys": keys, "pid": os.getpid(),
            "host": socket.gethostname(), "machine": f"{platform.node()}, {os.cpu_count()} cores",
            "git_commit": git_commit,
        },
    )  # fmt: skip
    return inv


def owner_alive(workdir: Path, pid: int, host: str) -> bool:
    """Whether the invocation of process ``pid`` on ``host`` still runs in ``workdir``: it holds
    the work directory's lock (:data:`LOCK`) for its whole life, so it runs if the lock file names
    it and that process lives (another host's process is assumed to). A reused pid does not fool
    this: the new process does not hold the lock."""
    if pid == os.getpid() and host == socket.gethostname():
        return True
    holder = read_holder(Path(workdir) / LOCK)
    if holder is None or holder.pid != pid or holder.host != host:
        return False
    return holder.alive() is not False


def owner_tags(workdir: Path) -> dict[str, str]:
    """This process's :data:`OWNER_TAGS`: pid, host and the work directory whose lock it holds."""
    values = (str(os.getpid()), socket.gethostname(), str(Path(workdir).resolve()))
    return dict(zip(OWNER_TAGS, values, strict=True))


def owner_lives(tags: Mapping[str, str]) -> bool:
    """Whether the invocation named by a run's :data:`OWNER_TAGS` still runs (False without
    them: a run logged before they existed)."""
    pid, host, workdir = (tags.get(k) for k in OWNER_TAGS)
    if not (pid and host and workdir) or not pid.isdigit():
        return False
    return owner_alive(Path(workdir), int(pid), host)


def read_invocations(workdir: Path) -> list[dict[str, Any]]:
    """Every invocation of ``workdir``'s journal, merged (see the module docstring), in the
    order they started."""
    path = Path(workdir) / JOURNAL
    if not path.is_file():
        return []
    merged: dict[str, dict[str, Any]] = {}
    legacy = 0
    for line in path.read_text(errors="replace").splitlines():
        try:
            record = json.loads(line)
        except ValueError:
            continue  # a line cut by a kill
        if not isinstance(record, dict):
            continue
        if "event" not in record:  # a line of the earlier format: one per finished invocation
            legacy += 1
            # no unit records: it trained all it planned
            keys = list(record.get("unit_keys", []))
            merged[f"legacy-{legacy}"] = {**record, "state": "finished", "failed": 0, "keys": keys}
            continue
        inv = merged.setdefault(record.get("id", "?"), {"trained": 0, "failed": 0, "keys": []})
        event = record["event"]
        if event == "start":
            inv.update({k: v for k, v in record.items() if k not in ("event", "t")})
            inv["t0"] = inv["t_last"] = record.get("t", 0.0)
        elif event == "unit":
            inv["trained" if record.get("ok") else "failed"] += 1
            inv["keys"].append(str(record.get("key", "")))
            inv["t_last"] = record.get("t", inv.get("t_last", 0.0))
        elif event == "end":
            inv["state"], inv["wall_s"] = record.get("state", "finished"), record.get("wall_s")
    out = []
    for inv in merged.values():
        if "started" not in inv:
            continue  # its start record was lost: nothing to show
        if "state" not in inv:
            running = owner_alive(workdir, int(inv.get("pid", -1)), str(inv.get("host", "")))
            inv["state"] = "running" if running else KILLED_STATE
        if inv.get("wall_s") is None:
            inv["wall_s"] = float(inv.get("t_last", 0.0)) - float(inv.get("t0", 0.0))
        inv["trained_keys"] = sorted(set(inv.pop("keys")))
        for key in ("t0", "t_last"):
            inv.pop(key, None)
        out.append(inv)
    return out


def relevant_invocations(workdir: Path, keys: Iterable[str], this_id: str) -> list[dict]:
    """The invocations that trained (or failed) units among ``keys``, and this one (``this_id``)
    last: the provenance of a report's results. An invocation that only planned some of
    ``keys`` (it trained other units of the work directory: another seed, another table) is not
    one of them."""
    wanted = set(keys)
    every = read_invocations(workdir)
    this = [inv for inv in every if inv.get("id") == this_id]
    others = [
        inv
        for inv in every
        if inv.get("id") != this_id and wanted & set(inv.get("trained_keys", []))
    ]
    return [*others, *this]
