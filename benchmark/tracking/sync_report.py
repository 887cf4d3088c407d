"""``uavbench sync [--from DIR] --to URI``: send the runs kept in a local fallback directory to an
MLflow store (see :mod:`benchmark.tracking.sync` for what is copied and how a second sync copies
nothing).

:func:`sync_and_report` returns a :class:`SyncResult`; the command maps it to its exit code: 0
when every ended run is in the store (copied now or before), 1 when runs were left out (still
RUNNING) or the copy failed midway (rerun: it continues where it stopped). A missing or empty
source directory, an unusable target or an unreachable server raise
:class:`~benchmark.errors.InputError` (exit 2).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from benchmark.tracking.sync import SyncReport


@dataclass(frozen=True)
class SyncResult:
    """How one sync into ``target`` ended: its ``report`` (None when the copy failed midway) and
    ``failure``, the one line that says why it stopped (``""`` when it ran to the end)."""

    target: str
    report: SyncReport | None
    failure: str = ""

    @property
    def ok(self) -> bool:
        """Every ended run is in the store and none was left out (still RUNNING, or a child of
        one)."""
        return (
            not self.failure
            and self.report is not None
            and not (self.report.running or self.report.waiting)
        )

    def lines(self) -> list[str]:
        """The summary ``uavbench sync`` prints last (nothing after a failed copy: the command
        prints :attr:`failure` instead)."""
        return self.report.text().splitlines() if self.report is not None else []


def sync_and_report(source: Path, target: str, *, quiet: bool = False) -> SyncResult:
    """Copy the runs of the local directory ``source`` into the MLflow store ``target``; one
    :func:`~benchmark.progress.status` line per copied run unless ``quiet``. Returns what was
    done (:class:`SyncResult`; a copy that failed midway is a result too: what is copied stays,
    a rerun continues). Raises :class:`~benchmark.errors.InputError` for a missing or empty
    ``source``, an unusable ``target`` or an unreachable server."""
    from benchmark.errors import InputError
    from benchmark.progress import status
    from benchmark.tracking.sync import SyncError, sync_runs

    # One line per copied run while the copy goes on: progress of long work, not the result.
    say = (lambda _m: None) if quiet else status
    try:
        report = sync_runs(source, target, say=say)
    except SyncError as err:
        raise InputError(str(err)) from None
    except InputError:  # a target that is no store (benchmark.tracking.uri)
        raise
    except Exception as err:  # the store failed midway: what is copied stays, a rerun continues
        return SyncResult(
            target,
            None,
            f"the copy into {target} failed: {err!r}; runs copied so far are in the store, "
            "rerun the same command to copy the rest",
        )
    return SyncResult(target, report)
