"""Runs kept in a local fallback directory, which of them a store has received, and the messages
that say so.

A :class:`~benchmark.tracking.local.LocalTracker` directory (``./tracking-fallback`` when MLflow
failed, ``./tracking-local`` for ``--tracker local``) holds one ``run.json`` per run. When
``uavbench sync`` has copied a run into a store it writes ``synced.json`` beside it::

    {"sqlite:////abs/mlflow.db": {"run_id": "<id in that store>", "synced_at": 1718000000.0}}

keyed by the store's canonical URI (:func:`benchmark.tracking.uri.uri_key`). That marker is what
"exists only locally" means here: a terminated run without a marker for a store has not reached
that store. (``uavbench sync`` itself decides by the copy's tag in the target store, so a lost or
stale marker never makes it skip or duplicate a run; the marker only serves the messages and
keeps synced runs from being found twice.)
"""

from __future__ import annotations

import json
import os
import shlex
import time
from dataclasses import dataclass
from pathlib import Path

from benchmark.tracking.local import _write_json_atomic
from benchmark.tracking.uri import uri_key

SYNC_MARKER = "synced.json"
TERMINAL = ("FINISHED", "FAILED", "KILLED")
_RULE = "=" * 78


@dataclass(frozen=True)
class LocalRun:
    """One run of a local tracking directory: its directory and its ``run.json`` record."""

    run_dir: Path
    record: dict

    @property
    def run_id(self) -> str:
        return str(self.record["run_id"])

    @property
    def experiment(self) -> str:
        return str(self.record["experiment"])

    @property
    def status(self) -> str:
        return str(self.record.get("status", "RUNNING"))

    @property
    def parent_run_id(self) -> str | None:
        return self.record.get("parent_run_id") or None

    def synced(self) -> dict[str, dict]:
        """``{store uri key: {"run_id", "synced_at"}}`` of the stores this run was copied to."""
        path = self.run_dir / SYNC_MARKER
        try:
            return dict(json.loads(path.read_text(encoding="utf-8")))
        except (OSError, ValueError):
            return {}

    def synced_to(self, uri: str) -> str | None:
        """The run's id in store ``uri`` if ``uavbench sync`` copied it there, else None."""
        entry = self.synced().get(uri_key(uri))
        return str(entry["run_id"]) if entry else None

    def mark_synced(self, uri: str, target_run_id: str) -> None:
        marks = self.synced()
        marks[uri_key(uri)] = {"run_id": target_run_id, "synced_at": time.time()}
        _write_json_atomic(self.run_dir / SYNC_MARKER, marks)


def read_local_runs(root: str | Path) -> list[LocalRun]:
    """Every run under ``root`` (``<experiment>/<run id>/run.json``), oldest first; a run.json
    that cannot be read (a process killed mid-write leaves only a temp file) is skipped."""
    root = Path(root)
    runs = []
    for path in root.glob("*/*/run.json") if root.is_dir() else []:
        try:
            rec = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        if isinstance(rec, dict) and rec.get("run_id") and rec.get("experiment"):
            runs.append(LocalRun(path.parent, rec))
    runs.sort(key=lambda r: (r.record.get("start_time_ms") or 0, r.run_id))
    return runs


def is_synced(run_dir: Path, uri: str) -> bool:
    """True if the local run in ``run_dir`` has been copied to store ``uri``."""
    return LocalRun(run_dir, {}).synced_to(uri) is not None


def unsynced_runs(
    root: str | Path, uri: str, statuses: tuple[str, ...] = TERMINAL
) -> list[LocalRun]:
    """Runs under ``root`` in one of ``statuses`` (default: ended, what ``uavbench sync``
    copies) that store ``uri`` has not received, oldest first."""
    return [
        run
        for run in read_local_runs(root)
        if run.status in statuses and run.synced_to(uri) is None
    ]


def show_path(path: str | Path) -> str:
    """``./tracking-fallback`` for a path under the working directory, else the absolute path."""
    path = Path(path).resolve()
    try:
        rel = path.relative_to(Path.cwd().resolve())
    except ValueError:
        return str(path)
    return f"./{rel}" if str(rel) != "." else "."


def sync_command(root: str | Path, uri: str) -> str:
    """The exact command that sends the runs of ``root`` to ``uri`` (shell-quoted)."""
    return f"uavbench sync --from {shlex.quote(show_path(root))} --to {shlex.quote(uri)}"


def count_runs(n: int) -> str:
    return f"{n} run" if n == 1 else f"{n} runs"


def fallback_message(reason: str, root: str | Path, uri: str) -> str:
    """The block printed once on stderr when MLflow fails and the runs go to ``root``."""
    return "\n".join(
        [
            _RULE,
            f"uavbench: MLFLOW TRACKING FAILED (pid {os.getpid()}): runs are kept locally",
            f"  what failed: {reason}",
            f"  runs go to:  {show_path(root)}  (run.json, metrics.csv and artifacts per run;",
            "               nothing is lost, and a rerun finds its finished runs there)",
            f"  the store {uri} receives none of them until you run:",
            f"    {sync_command(root, uri)}",
            _RULE,
        ]
    )


def pending_message(runs: list[LocalRun], root: str | Path, uri: str) -> str:
    """The block printed when a store is reachable again but runs exist only in ``root``."""
    finished = sum(1 for r in runs if r.status == "FINISHED")
    return "\n".join(
        [
            _RULE,
            f"uavbench: {count_runs(len(runs))} ({finished} finished) exist ONLY in "
            f"{show_path(root)}, not in {uri}",
            "  (an earlier invocation could not reach MLflow). A rerun reuses them, but the store",
            "  does not have them; send them with:",
            f"    {sync_command(root, uri)}",
            _RULE,
        ]
    )


def pending_line(runs: list[LocalRun], root: str | Path, uri: str) -> str:
    """The one-line form of :func:`pending_message`, for a command's end summary."""
    return (
        f"tracking: {count_runs(len(runs))} exist only in {show_path(root)} (not in {uri}); "
        f"`{sync_command(root, uri)}` sends them"
    )
