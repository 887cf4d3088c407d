"""``uavbench ui``: serve the MLflow UI for the local tracking store on 127.0.0.1.

Starts ``python -m mlflow server`` on the default store (``./mlflow.db``, artifacts in
``./mlartifacts``), or on the database given by ``--tracking-uri``, says the URL once the server
answers and, below it, one link per experiment of the store (the reproduction's tables and
figures, ``uavbench train``'s) with the first line of its description, then waits until Ctrl-C.
A ``--tracking-uri http(s)://...`` already is a server: its links are said and nothing is
started. ``--open`` also opens the first link in a browser; ``--screenshots DIR`` takes the
screenshots of ``benchmark.tracking.screenshots`` and exits.

The address and the links are :func:`benchmark.progress.status` lines (said while the server
runs, so they cannot wait for a return value); how the UI ended is returned (:class:`UiResult`)
and ``benchmark.commands.ui`` prints it and picks the exit code.
"""

from __future__ import annotations

import os
import signal
from dataclasses import dataclass
from pathlib import Path

from benchmark.progress import status
from benchmark.tracking.ui_links import (
    experiment_links,
    experiments_url,
    format_links,
    list_experiments,
)


@dataclass(frozen=True)
class UiConfig:
    """One ``uavbench ui``: the store ``tracking_uri`` (None: MLFLOW_TRACKING_URI, else
    ./mlflow.db; a server URL: nothing is started), the server's ``port`` on 127.0.0.1 and
    ``artifacts_dir``; ``open`` the first experiment in a browser; ``screenshots``: take them
    into this directory, then stop."""

    tracking_uri: str | None = None
    port: int = 5000
    artifacts_dir: Path = Path("mlartifacts")
    open: bool = False
    screenshots: Path | None = None


@dataclass(frozen=True)
class UiResult:
    """How one :func:`serve_ui` ended: the UI's ``url``, the ``screenshots`` written, and
    ``failure``, the one line that says why it did not end as asked (``""``: stopped with Ctrl-C
    or SIGTERM, screenshots taken, or a server's links listed). ``server_exit_code``: the MLflow
    server's own exit code when it exited by itself (None otherwise)."""

    url: str
    screenshots: tuple[Path, ...] = ()
    failure: str = ""
    server_exit_code: int | None = None

    @property
    def ok(self) -> bool:
        """The UI ended as asked."""
        return not self.failure

    def lines(self) -> list[str]:
        """What ``uavbench ui`` prints at the end: one ``wrote <png>`` line per screenshot."""
        return [f"wrote {path}" for path in self.screenshots]


def serve_ui(config: UiConfig) -> UiResult:
    """Serve (or reach) the UI of ``config`` until Ctrl-C (or until the screenshots are taken).
    The server's address and the experiment links are :func:`~benchmark.progress.status` lines,
    said while it runs; returns how it ended (:class:`UiResult`). Raises
    :class:`~benchmark.errors.InputError` for a bad store, a bad or busy port, a server that does
    not start or screenshots that cannot be taken."""
    from benchmark.errors import InputError
    from benchmark.tracking.server import MlflowServer, port_is_free
    from benchmark.tracking.uri import (
        default_tracking_uri,
        normalize_tracking_uri,
        open_sqlite_store_once,
        server_is_healthy,
    )

    # x.db -> sqlite:///<abs>; a directory or unknown scheme: InputError naming the value
    uri = normalize_tracking_uri(config.tracking_uri) or default_tracking_uri()
    if uri.startswith(("http://", "https://")):
        status(f"MLflow UI: {uri} (a server already; nothing to start)")
        ok, reason = server_is_healthy(uri, timeout=5.0)
        if not ok:  # MLflow's client would retry for minutes; say it at once instead
            return UiResult(uri, failure=f"cannot reach {reason}: no experiment links")
        return _serve_links(config, uri.rstrip("/"), uri)
    if not 1 <= config.port <= 65535:
        raise InputError(f"UiConfig.port {config.port}: expected an integer in 1..65535")
    if not port_is_free(config.port):
        raise InputError(f"UiConfig.port {config.port}: the port is already in use on 127.0.0.1")
    if uri.startswith("sqlite:///"):
        db = Path(uri[len("sqlite:///") :])
        if not db.exists():
            status(f"note: {db} does not exist yet; the UI starts on an empty store")
        # Create/migrate the schema here, under its lock (a reproduction may be opening the same
        # fresh store): the server then opens a finished schema.
        from mlflow.tracking import MlflowClient

        open_sqlite_store_once(uri, lambda: MlflowClient(uri).search_experiments(max_results=1))
        # (MlflowClient() itself opens the store: it is built inside the locked call.)
    alias = None
    if config.screenshots is not None:  # reached as ALIAS_HOST: no assistant panel in the pictures
        from benchmark.tracking.screenshots import ALIAS_HOST, alias_env

        alias = ALIAS_HOST
        saved_env = {k: os.environ.get(k) for k in alias_env(config.port)}
        os.environ.update(alias_env(config.port))  # the server process inherits it
    server = MlflowServer(
        uri,
        config.artifacts_dir,
        port=config.port,
        log_path=config.artifacts_dir / ".ui-server.log",
    )
    status(f"starting the MLflow UI on store {uri} ...")
    try:
        server.start()
    except RuntimeError as err:
        raise InputError(str(err)) from None
    finally:
        if alias is not None:
            for key, value in saved_env.items():  # this process keeps its own environment
                if value is None:
                    os.environ.pop(key, None)
                else:
                    os.environ[key] = value
    # A SIGTERM (kill, a service manager) must stop the server too, like Ctrl-C.
    previous = signal.signal(signal.SIGTERM, _raise_keyboard_interrupt)
    try:
        if config.screenshots is not None:
            status(f"MLflow UI: {server.url}")
            return _serve_links(config, server.url, server.url, alias)
        status(f"MLflow UI: {server.url}  (Ctrl-C to stop)")
        _serve_links(config, server.url, server.url)
        assert server.process is not None
        code = server.process.wait()
        return UiResult(
            server.url,
            failure=f"the MLflow server exited with code {code}",
            server_exit_code=code,
        )
    except KeyboardInterrupt:
        status("stopping the MLflow UI")
        return UiResult(server.url)
    finally:
        server.stop()
        signal.signal(signal.SIGTERM, previous)


def _serve_links(
    config: UiConfig, base_url: str, tracking_uri: str, alias: str | None = None
) -> UiResult:
    """Say the experiment links (status lines: the server runs); open the first
    (``config.open``) or take the screenshots. Returns the result of a UI that ends here."""
    from benchmark.errors import InputError

    links = experiment_links(base_url, list_experiments(tracking_uri))
    for line in format_links(links, base_url).splitlines():
        status(line)
    if config.screenshots is not None:
        from benchmark.tracking.screenshots import take_screenshots

        try:
            paths = take_screenshots(base_url, tracking_uri, config.screenshots, alias)
        except RuntimeError as err:
            raise InputError(str(err)) from None
        return UiResult(base_url, screenshots=tuple(paths))
    if config.open:
        import webbrowser

        webbrowser.open(links[0].url if links else experiments_url(base_url))
    return UiResult(base_url)


def _raise_keyboard_interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt
