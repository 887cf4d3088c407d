"""``uavbench sync [--from DIR] --to URI``: send the runs kept in a local fallback directory to an
MLflow store (see :mod:`benchmark.tracking.sync` for what is copied and how a second sync copies
nothing).

Exit codes: 0 when every ended run is in the store (copied now or before), 1 when runs were left
out (still RUNNING) or the copy failed midway (rerun: it continues where it stopped), 2 for a
missing or empty ``--from`` directory, an unusable ``--to`` or an unreachable server.
"""

from __future__ import annotations

import sys
from pathlib import Path


def sync_and_report(source: Path, target: str, *, quiet: bool = False) -> int:
    """Copy the runs of the local directory ``source`` into the MLflow store ``target`` and print
    the summary (each copied run too unless ``quiet``); the exit code above."""
    from benchmark.errors import UsageError
    from benchmark.tracking.sync import SyncError, sync_runs

    say = (lambda _m: None) if quiet else (lambda m: print(m, flush=True))
    try:
        report = sync_runs(source, target, say=say)
    except SyncError as err:
        raise UsageError(str(err)) from None
    except UsageError:  # a --to that is no store (benchmark.tracking.uri)
        raise
    except Exception as err:  # the store failed midway: what is copied stays, a rerun continues
        print(
            f"uavbench sync: the copy into {target} failed: {err!r}; runs copied so far are "
            "in the store, rerun the same command to copy the rest",
            file=sys.stderr,
        )
        return 1
    print(report.text())
    return 1 if report.running or report.waiting else 0
