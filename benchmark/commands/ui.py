"""``uavbench ui``: serve the MLflow UI for the local tracking store on 127.0.0.1
(:mod:`benchmark.tracking.ui`; ``--screenshots DIR``: :mod:`benchmark.tracking.screenshots`)."""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "serve the MLflow UI for the tracking store on 127.0.0.1 (Ctrl-C stops it)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--port", type=int, default=5000, help="port on 127.0.0.1 (default 5000)")
    parser.add_argument(
        "--tracking-uri",
        default=None,
        help="tracking store: a server URL, a sqlite:/// URI or a path ending in .db "
        "(default: MLFLOW_TRACKING_URI, else sqlite:///./mlflow.db)",
    )
    parser.add_argument(
        "--artifacts-dir",
        default="mlartifacts",
        help="where the server stores artifacts of experiments created from the UI "
        "(default ./mlartifacts, where uavbench puts them)",
    )
    parser.add_argument(
        "--open", action="store_true", help="also open the first experiment's Runs view"
    )
    parser.add_argument(
        "--screenshots",
        type=Path,
        default=None,
        metavar="DIR",
        help="take PNG screenshots (experiment list, one experiment's runs, one run) with "
        "headless Chromium into DIR, then stop (e.g. reports/ui)",
    )


def run(args: argparse.Namespace) -> int:
    """Serve the UI; print the screenshots written, or on stderr why it stopped. Exit 0, 1 for
    an unreachable server, the server's own code (1 for 0) when it exited by itself."""
    import sys

    from benchmark.errors import UsageError
    from benchmark.tracking.ui import UiConfig, serve_ui

    if not 1 <= args.port <= 65535:
        raise UsageError(f"--port {args.port}: expected an integer in 1..65535")
    config = UiConfig(
        tracking_uri=args.tracking_uri,
        port=args.port,
        artifacts_dir=Path(args.artifacts_dir),
        open=args.open,
        screenshots=args.screenshots,
    )
    result = serve_ui(config)
    for line in result.lines():
        print(line)
    if not result.ok:
        print(result.failure, file=sys.stderr)
        return result.server_exit_code or 1
    return 0
