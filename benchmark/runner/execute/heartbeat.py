"""What a unit being trained in a worker is doing now, for the reproduction's progress line.

A pool worker trains a unit for minutes (a shared matching encoder: over half an hour) and the
driver hears of it only when it ends, so its progress line would stand still that long. The
worker therefore writes a small heartbeat file into the unit's directory when it starts and at
the end of every epoch (:func:`write_heartbeat`, an atomic replace); the driver, while it waits,
reads the heartbeats of the units still pending (:func:`running_status`) and shows them. Files
older than the current invocation are ignored: a unit an earlier, killed invocation was training
is not running now until a worker picks it up again.

A file, not a queue: it needs nothing shared between the processes (spawned pool workers, local
Ray workers) and survives a crash as a record of how far the unit got.
"""

from __future__ import annotations

import contextlib
import json
import os
import time
from collections.abc import Iterable
from pathlib import Path

from benchmark.progress import Progress

HEARTBEAT_FILE = "progress.json"
POLL_S = 30.0  # how often a waiting driver reads the running units' heartbeats
# A file's mtime comes from the kernel's coarse clock (a tick behind time.time()), from a
# filesystem with 2 s granularity, or from another node's clock (Ray on a shared file system):
# a heartbeat written just after ``since`` may carry an mtime slightly before it. An earlier
# invocation's files are minutes older, so a few seconds of slack tell them apart just as well.
MTIME_SLACK_S = 5.0


def write_heartbeat(unit_dir: Path, epoch: int, epochs: int) -> None:
    """Record that the unit in ``unit_dir`` has finished ``epoch`` of ``epochs`` (0: started).
    Best effort: a failed write (disk full) must not fail the training it reports on."""
    path = Path(unit_dir) / HEARTBEAT_FILE
    tmp = path.with_name(f".{HEARTBEAT_FILE}.{os.getpid()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp.write_text(json.dumps({"epoch": int(epoch), "epochs": int(epochs)}))
        os.replace(tmp, path)  # a reader sees the old or the new file, never half of one
    except OSError:
        with contextlib.suppress(OSError):  # the directory itself may be what failed
            tmp.unlink(missing_ok=True)


def read_heartbeat(unit_dir: Path, since: float) -> tuple[int, int] | None:
    """``(epoch, epochs)`` of the unit's heartbeat if written at or after ``since`` (a
    ``time.time()``; its mtime may be up to ``MTIME_SLACK_S`` earlier), else None (absent,
    older, or unreadable)."""
    path = Path(unit_dir) / HEARTBEAT_FILE
    try:
        if path.stat().st_mtime < since - MTIME_SLACK_S:
            return None
        record = json.loads(path.read_text())
        return int(record["epoch"]), int(record["epochs"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def running_status(pending: Iterable[tuple[str, Path]], since: float) -> str:
    """``"running: <title> epoch 3/12; <title> starting"`` for the pending units (``(title,
    unit_dir)``) whose heartbeat is from this invocation (``since``), "" when none has one yet.
    A unit at its last epoch is evaluating."""
    parts = []
    for title, unit_dir in pending:
        beat = read_heartbeat(unit_dir, since)
        if beat is None:
            continue
        epoch, epochs = beat
        if epoch <= 0:
            state = "starting"
        elif epoch >= epochs:
            state = "evaluating"
        else:
            state = f"epoch {epoch}/{epochs}"
        parts.append(f"{title} {state}")
    return "running: " + "; ".join(parts) if parts else ""


class RunningLine:
    """The waiting driver's progress line: :meth:`show` draws :func:`running_status` on ``bar``
    (a ``benchmark.progress.Progress``) when it changed, counting heartbeats written from
    ``since`` (a ``time.time()``; default: the line's creation). Pass the time the units were
    submitted: a unit quick to start writes its first heartbeat before the line exists."""

    def __init__(self, bar: Progress, since: float | None = None) -> None:
        self.bar, self.shown = bar, ""
        self.since = time.time() if since is None else since

    def show(self, pending: Iterable[tuple[str, Path]]) -> None:
        status = running_status(pending, self.since)
        if status and status != self.shown:
            self.bar.status(status)
        self.shown = status
