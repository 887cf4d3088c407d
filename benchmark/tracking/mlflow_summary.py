"""The summaries of :class:`~benchmark.tracking.mlflow_tracker.MlflowTracker` (a mixin): where its
runs really are at the end of a command, and the notice for runs that exist only in the local
fallback directory. mlflow is reached through the tracker's client only."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from benchmark.tracking.pending import (
    count_runs,
    pending_line,
    pending_message,
    show_path,
    sync_command,
    unsynced_runs,
)


class SummaryMixin:
    """Needs ``self.uri``, ``self.fallback_dir``, ``self._fallback``, ``self._client``,
    ``self._is_http``, ``self._failure``, ``self._started_ms`` and ``self._experiment_ids``
    (see MlflowTracker)."""

    uri: str
    fallback_dir: Path
    _fallback: Any
    _client: Any
    _is_http: bool
    _failure: str
    _started_ms: int
    _experiment_ids: dict[str, str]

    def summary(self) -> str:
        """Where the runs are, for a command's last lines. With the fallback in use::

            tracking: 12 runs kept locally in ./tracking-fallback (MLflow server http://h:5000
            was unreachable); `uavbench sync --from ./tracking-fallback --to http://h:5000`
            sends them

        (one line), else ``tracking: <uri> (N runs logged during this invocation)``, followed by
        a second line when runs exist only in the fallback directory (see
        :meth:`pending_sync_notice`)."""
        if self._fallback is not None:
            runs = unsynced_runs(self.fallback_dir, self.uri)
            what = "server" if self._is_http else "store"
            return (
                f"tracking: {count_runs(len(runs))} kept locally in {show_path(self.fallback_dir)}"
                f" (MLflow {what} {self.uri} {self._failure}); "
                f"`{sync_command(self.fallback_dir, self.uri)}` sends them"
            )
        n = self._runs_logged_since_start()
        line = f"tracking: {self.uri}" + (
            f" ({count_runs(n)} logged during this invocation)" if n is not None else ""
        )
        pending = unsynced_runs(self.fallback_dir, self.uri)
        return line + ("\n" + pending_line(pending, self.fallback_dir, self.uri) if pending else "")

    def pending_sync_notice(self) -> str:
        if self._fallback is not None:
            return ""  # the fallback block already said it
        pending = unsynced_runs(self.fallback_dir, self.uri)
        return pending_message(pending, self.fallback_dir, self.uri) if pending else ""

    def _runs_logged_since_start(self) -> int | None:
        """Runs of the experiments this tracker used that ended (or started and still run)
        since it was created, by any process (worker processes log units); None if the store
        cannot say."""
        if self._client is None or not self._experiment_ids:
            return None
        ids = list(self._experiment_ids.values())
        t0 = self._started_ms
        try:
            ended = self._client.search_runs(
                ids, filter_string=f"attributes.end_time >= {t0}", max_results=10000
            )
            live = self._client.search_runs(
                ids,
                filter_string=f"attributes.status = 'RUNNING' and attributes.start_time >= {t0}",
                max_results=10000,
            )
        except Exception:
            return None
        return len(ended) + len(live)
