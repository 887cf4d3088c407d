"""``uavbench ui``: serve the MLflow UI for the local tracking store on 127.0.0.1.

Starts ``python -m mlflow server`` on the default store (``./mlflow.db``, artifacts in
``./mlartifacts``), or on the database given by ``--tracking-uri``, prints the URL once the server
answers and, below it, one link per experiment of the store (the reproduction's tables and
figures, ``uavbench train``'s) with the first line of its description, then waits until Ctrl-C.
A ``--tracking-uri http(s)://...`` already is a server: its links are printed and nothing is
started. ``--open`` also opens the first link in a browser; ``--screenshots DIR`` takes the
screenshots of ``benchmark.tracking.screenshots`` and exits.

Why the links carry ``?workflowType=machine_learning``: MLflow 3's UI keeps a workspace-wide mode
(``genai`` by default, kept in the browser's local storage) and in that mode opens every
experiment on the GenAI overview (traces, token usage), whatever the experiment's
``mlflow.experimentKind`` tag says. The URL parameter overrides the stored mode (MLflow 3.17's
``WorkflowTypeProvider`` reads it before local storage) and the UI keeps it on its own links, so a
link opens the classic Runs view with the experiment's description on top.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import sys
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

HELP = "serve the MLflow UI for the tracking store on 127.0.0.1 (Ctrl-C stops it)"
ML_VIEW = "workflowType=machine_learning"
DESCRIPTION_TAG = "mlflow.note.content"  # what the UI shows as an experiment's description


@dataclass(frozen=True)
class ExperimentLink:
    """One experiment as printed by ``uavbench ui``: its id, name, the first line of its
    description (``""`` without one) and the URL of its Runs view."""

    experiment_id: str
    name: str
    description: str
    url: str


def experiment_url(base_url: str, experiment_id: str) -> str:
    """``http://127.0.0.1:5000/#/experiments/3?workflowType=machine_learning``: the classic Runs
    view of one experiment."""
    return f"{base_url.rstrip('/')}/#/experiments/{experiment_id}?{ML_VIEW}"


def run_url(base_url: str, experiment_id: str, run_id: str) -> str:
    """The page of one run (overview, parameters, metrics), in the classic view."""
    return f"{base_url.rstrip('/')}/#/experiments/{experiment_id}/runs/{run_id}?{ML_VIEW}"


def experiments_url(base_url: str) -> str:
    """The list of experiments, in the classic view (its links keep the view)."""
    return f"{base_url.rstrip('/')}/#/experiments?{ML_VIEW}"


def first_line(text: str | None, limit: int = 80) -> str:
    """The first non-empty line of ``text`` without Markdown emphasis, cut to ``limit``
    characters with an ellipsis; ``""`` for None or blank text."""
    for line in (text or "").splitlines():
        line = line.strip().lstrip("#").strip().replace("**", "")
        if line:
            return line if len(line) <= limit else line[: limit - 1].rstrip() + "…"
    return ""


def _natural_key(name: str) -> list[object]:
    """``table2`` before ``table10``: digit runs compare as numbers."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", name)]


def experiment_links(
    base_url: str, experiments: Iterable[tuple[str, str, Mapping[str, str]]]
) -> list[ExperimentLink]:
    """Links for ``(experiment id, name, tags)`` triples, in natural name order (``fig5`` ...,
    ``table1``, ``table2`` ..., ``table10``); the description is the first line of the tag
    ``mlflow.note.content``."""
    links = [
        ExperimentLink(
            str(eid), name, first_line(tags.get(DESCRIPTION_TAG)), experiment_url(base_url, eid)
        )
        for eid, name, tags in experiments
    ]
    return sorted(links, key=lambda link: _natural_key(link.name))


def format_links(links: list[ExperimentLink], base_url: str) -> str:
    """The text ``uavbench ui`` prints under the server's URL: the experiment list, then per
    experiment its name and Runs-view URL and, indented below, its description's first line."""
    if not links:
        return (
            "no experiments in this store yet (run `uavbench reproduce` or `uavbench train`); "
            f"experiments: {experiments_url(base_url)}"
        )
    width = max(len(x.name) for x in links)
    lines = [f"experiments (classic Runs view): {experiments_url(base_url)}"]
    for x in links:
        lines.append(f"  {x.name:<{width}}  {x.url}")
        if x.description:
            lines.append(f"  {'':<{width}}  {x.description}")
    return "\n".join(lines)


def list_experiments(tracking_uri: str) -> list[tuple[str, str, dict[str, str]]]:
    """``(id, name, tags)`` of every active experiment of the store; MLflow's ``Default``
    experiment only when it holds runs (every new store has it, empty)."""
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri=tracking_uri)
    out = []
    for exp in client.search_experiments():
        if exp.name == "Default" and not client.search_runs([exp.experiment_id], max_results=1):
            continue
        out.append((exp.experiment_id, exp.name, dict(exp.tags)))
    return out


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
    from benchmark.errors import UsageError
    from benchmark.tracking.server import MlflowServer, port_is_free
    from benchmark.tracking.uri import (
        default_tracking_uri,
        normalize_tracking_uri,
        open_sqlite_store_once,
        server_is_healthy,
    )

    # x.db -> sqlite:///<abs>; a directory or unknown scheme: one line and exit 2
    uri = normalize_tracking_uri(args.tracking_uri) or default_tracking_uri()
    if uri.startswith(("http://", "https://")):
        print(f"MLflow UI: {uri} (a server already; nothing to start)", flush=True)
        ok, reason = server_is_healthy(uri, timeout=5.0)
        if not ok:  # MLflow's client would retry for minutes; say it at once instead
            print(f"cannot reach {reason}: no experiment links", file=sys.stderr)
            return 1
        return _serve_links(args, uri.rstrip("/"), uri)
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
        # Create/migrate the schema here, under its lock (a reproduction may be opening the same
        # fresh store): the server then opens a finished schema.
        from mlflow.tracking import MlflowClient

        open_sqlite_store_once(uri, lambda: MlflowClient(uri).search_experiments(max_results=1))
        # (MlflowClient() itself opens the store: it is built inside the locked call.)
    alias = None
    if args.screenshots is not None:  # reached as ALIAS_HOST: no assistant panel in the pictures
        from benchmark.tracking.screenshots import ALIAS_HOST, alias_env

        alias = ALIAS_HOST
        saved_env = {k: os.environ.get(k) for k in alias_env(args.port)}
        os.environ.update(alias_env(args.port))  # the server process inherits it
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
        if args.screenshots is not None:
            print(f"MLflow UI: {server.url}", flush=True)
            return _serve_links(args, server.url, server.url, alias)
        print(f"MLflow UI: {server.url}  (Ctrl-C to stop)", flush=True)
        _serve_links(args, server.url, server.url)
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


def _serve_links(
    args: argparse.Namespace, base_url: str, tracking_uri: str, alias: str | None = None
) -> int:
    """Print the experiment links; open the first (``--open``) or take the screenshots."""
    from benchmark.errors import UsageError

    links = experiment_links(base_url, list_experiments(tracking_uri))
    print(format_links(links, base_url), flush=True)
    if args.screenshots is not None:
        from benchmark.tracking.screenshots import take_screenshots

        try:
            paths = take_screenshots(base_url, tracking_uri, args.screenshots, alias)
        except RuntimeError as err:
            raise UsageError(str(err)) from None
        for path in paths:
            print(f"wrote {path}")
        return 0
    if args.open:
        import webbrowser

        webbrowser.open(links[0].url if links else experiments_url(base_url))
    return 0


def _raise_keyboard_interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt
