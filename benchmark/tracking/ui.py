"""``uavbench ui``: serve the MLflow UI for the local tracking store on 127.0.0.1.

Starts ``python -m mlflow server`` on the default store (``./mlflow.db``, artifacts in
``./mlartifacts``), or on the database given by ``--tracking-uri``, prints the URL once the server
answers, and waits until Ctrl-C. A ``--tracking-uri http(s)://...`` already is a server: its URL is
printed and nothing is started.
"""

from __future__ import annotations

import argparse
import signal
import sys
from pathlib import Path

HELP = "serve the MLflow UI for the tracking store on 127.0.0.1 (Ctrl-C stops it)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--port", type=int, default=5000, help="port on 127.0.0.1 (default 5000)")
    parser.add_argument(
        "--tracking-uri",
        default=None,
        help="tracking store (default: MLFLOW_TRACKING_URI, else sqlite:///./mlflow.db)",
    )
    parser.add_argument(
        "--artifacts-dir",
        default="mlartifacts",
        help="where the server stores artifacts of experiments created from the UI "
        "(default ./mlartifacts, where uavbench puts them)",
    )


def run(args: argparse.Namespace) -> int:
    from benchmark.errors import UsageError
    from benchmark.tracking.mlflow_tracker import default_tracking_uri
    from benchmark.tracking.server import MlflowServer, port_is_free

    uri = args.tracking_uri or default_tracking_uri()
    if uri.startswith(("http://", "https://")):
        print(f"MLflow UI: {uri} (a server already; nothing to start)")
        return 0
    if not 1 <= args.port <= 65535:
        raise UsageError(f"--port {args.port}: expected an integer in 1..65535")
    if not port_is_free(args.port):
        raise UsageError(f"--port {args.port}: the port is already in use on 127.0.0.1")
    if uri.startswith("sqlite:///"):
        db = Path(uri[len("sqlite:///") :])
        if not db.exists():
            print(
                f"note: {db} does not exist yet; the UI starts on an empty store", file=sys.stderr
            )
    server = MlflowServer(
        uri,
        Path(args.artifacts_dir),
        port=args.port,
        log_path=Path(args.artifacts_dir) / ".ui-server.log",
    )
    print(f"starting the MLflow UI on store {uri} ...", file=sys.stderr)
    try:
        server.start()
    except RuntimeError as err:
        raise UsageError(str(err)) from None
    print(f"MLflow UI: {server.url}  (Ctrl-C to stop)", flush=True)
    # A SIGTERM (kill, a service manager) must stop the server too, like Ctrl-C.
    previous = signal.signal(signal.SIGTERM, _raise_keyboard_interrupt)
    try:
        assert server.process is not None
        code = server.process.wait()
        print(f"the MLflow server exited with code {code}", file=sys.stderr)
        return code or 1
    except KeyboardInterrupt:
        print("stopping the MLflow UI", file=sys.stderr)
        return 0
    finally:
        server.stop()
        signal.signal(signal.SIGTERM, previous)


def _raise_keyboard_interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt
