"""Screenshots of the MLflow UI with headless Chromium (``uavbench ui --screenshots DIR``).

Pages in the classic Runs view (see ``benchmark.tracking.ui_links`` on
``?workflowType=machine_learning``): the experiment list (``experiments.png``), one experiment's
runs table (``runs.png``: the experiment of Table 1 when the store has one, else the first), the
page of one of its runs (``run.png``: a finished nested run, i.e. a table row, when there is one)
and, when the store has a reproduction's ``<profile>/training`` experiment, its runs table
(``training.png``: one run per trained unit). Chromium is found on the ``PATH`` (``chromium``,
``chromium-browser``, ``google-chrome``) or given by ``UAVBENCH_CHROMIUM``; Debian:
``apt-get install -y chromium``.

Each screenshot runs a fresh Chromium (its own empty ``--user-data-dir``, so no stored UI mode
leaks in) with the flags a closed network needs (no background networking, component updates,
sync or QUIC) and ``--virtual-time-budget``: virtual time stands still while requests are pending,
so the budget lets the UI's JavaScript fetch and render before the picture is taken. A PNG with
almost one colour (a blank page) is an error, not a screenshot.

MLflow 3.17 opens its "MLflow Assistant" chat panel on the first visit of a browser profile to a
server addressed as ``localhost``/``127.0.0.1`` (``isLocalServer``), and a fresh profile is a first
visit every time: the panel would cover a third of each picture. When ``uavbench ui`` starts the
server itself, Chromium therefore reaches it under the name :data:`ALIAS_HOST`, mapped to
127.0.0.1 by ``--host-resolver-rules``, and the server is told to accept that name
(:func:`alias_env`: MLflow's DNS-rebinding and CORS checks otherwise refuse a Host other than
localhost). The pages are the same; a user who closes the panel once sees them so too.
"""

from __future__ import annotations

import html
import os
import re
import shutil
import subprocess
import tempfile
from pathlib import Path
from urllib.parse import urlsplit

from benchmark.tracking.ui_links import (
    experiment_url,
    experiments_url,
    list_experiments,
    run_url,
)

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
CHROMIUM_FLAGS = (
    "--headless",
    "--no-sandbox",  # running as root (CI, these machines)
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--hide-scrollbars",
)
ALIAS_HOST = "uavbench-ui"  # the name Chromium uses for 127.0.0.1 (see the module docstring)
WINDOW = (1600, 1000)  # px, width x height
BUDGET_MS = 20_000  # virtual time for the UI to fetch and render
MIN_COLOURS = 16  # a rendered MLflow page has hundreds; a blank one 1-3


def find_chromium() -> str | None:
    """The Chromium binary: ``UAVBENCH_CHROMIUM`` if set, else the first of
    :data:`CHROMIUM_NAMES` on the ``PATH``; None when there is none."""
    explicit = os.environ.get("UAVBENCH_CHROMIUM")
    if explicit:
        return explicit
    return next((path for name in CHROMIUM_NAMES if (path := shutil.which(name))), None)


def alias_env(port: int, host: str = ALIAS_HOST) -> dict[str, str]:
    """Environment for an MLflow server on 127.0.0.1:``port`` that must also answer requests
    addressed to ``host:port`` (its Host header and, for the UI's POST requests, its Origin)."""
    hosts = [f"{h}:{port}" for h in ("localhost", "127.0.0.1", host)] + ["localhost", "127.0.0.1"]
    return {
        "MLFLOW_SERVER_ALLOWED_HOSTS": ",".join(hosts),
        "MLFLOW_SERVER_CORS_ALLOWED_ORIGINS": f"http://{host}:{port}",
    }


def chromium_command(
    binary: str,
    url: str,
    user_data_dir: Path,
    png: Path | None = None,
    window: tuple[int, int] = WINDOW,
    budget_ms: int = BUDGET_MS,
    alias: str | None = None,
) -> list[str]:
    """The command line that renders ``url`` (``window`` px, width x height) into ``png``, or
    with ``png`` None prints its DOM (``--dump-dom``); ``alias``: a host name Chromium resolves
    to 127.0.0.1."""
    rules = [f"--host-resolver-rules=MAP {alias} 127.0.0.1"] if alias else []
    output = f"--screenshot={png}" if png is not None else "--dump-dom"
    return [
        binary,
        *CHROMIUM_FLAGS,
        *rules,
        f"--user-data-dir={user_data_dir}",
        f"--window-size={window[0]},{window[1]}",
        f"--virtual-time-budget={int(budget_ms)}",
        output,
        url,
    ]


def count_colours(png: Path) -> int:
    """Distinct RGB colours in ``png`` (0 when it does not decode)."""
    import cv2
    import numpy as np

    image = cv2.imread(str(png), cv2.IMREAD_COLOR)  # (H, W, 3) uint8 BGR, None if unreadable
    if image is None:
        return 0
    packed = image.astype(np.uint32) @ np.array([1 << 16, 1 << 8, 1], dtype=np.uint32)
    return int(np.unique(packed).size)


def screenshot(
    url: str,
    png: Path,
    binary: str,
    window: tuple[int, int] = WINDOW,
    budget_ms: int = BUDGET_MS,
    timeout_s: float = 180.0,
    alias: str | None = None,
) -> Path:
    """Render ``url`` into ``png`` with a fresh headless Chromium; RuntimeError when Chromium
    fails, writes nothing, or the page is blank (fewer than :data:`MIN_COLOURS` colours)."""
    png = Path(png).resolve()
    png.parent.mkdir(parents=True, exist_ok=True)
    png.unlink(missing_ok=True)
    with tempfile.TemporaryDirectory(prefix="uavbench-chromium-") as profile:
        cmd = chromium_command(binary, url, Path(profile), png, window, budget_ms, alias)
        try:
            done = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
        except subprocess.TimeoutExpired:
            raise RuntimeError(f"chromium did not finish {url} within {timeout_s:.0f} s") from None
    if not png.is_file() or png.stat().st_size == 0:
        tail = "\n".join(done.stderr.splitlines()[-10:])
        raise RuntimeError(
            f"chromium wrote no screenshot of {url} (exit {done.returncode}):\n{tail}"
        )
    colours = count_colours(png)
    if colours < MIN_COLOURS:
        raise RuntimeError(f"{png}: a blank page ({colours} colours) for {url}")
    return png


def page_title(url: str, binary: str, alias: str | None = None, budget_ms: int = BUDGET_MS) -> str:
    """The ``<title>`` of ``url`` once its JavaScript has rendered (``--dump-dom``): MLflow names
    the view there (``Runs - Experiment 3 - MLflow``; the GenAI view ``Overview - ...``)."""
    with tempfile.TemporaryDirectory(prefix="uavbench-chromium-") as profile:
        cmd = chromium_command(binary, url, Path(profile), None, WINDOW, budget_ms, alias)
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=180)
    match = re.search(r"<title>([^<]*)</title>", done.stdout)
    return html.unescape(match[1]) if match else ""


def pick_pages(base_url: str, tracking_uri: str) -> list[tuple[str, str, str]]:
    """``(file name, URL, expected title prefix)`` of the pages: experiment list, one
    experiment's runs table, one run [, the training runs]. RuntimeError when the store has no
    experiment with runs."""
    from mlflow.tracking import MlflowClient

    experiments = [e for e in list_experiments(tracking_uri) if e[1] != "Default"]
    if not experiments:
        raise RuntimeError(f"no experiment in {tracking_uri}: nothing to show")
    preferred = [e for e in experiments if e[1].endswith("/table1")]
    eid = (preferred or experiments)[0][0]
    client = MlflowClient(tracking_uri=tracking_uri)
    runs = client.search_runs([eid], order_by=["attributes.start_time ASC"], max_results=200)
    if not runs:
        raise RuntimeError(f"experiment {eid} of {tracking_uri} has no runs: nothing to show")
    # A table row (a nested, finished run) rather than the invocation's parent.
    nested = [
        r for r in runs if "mlflow.parentRunId" in r.data.tags and r.info.status == "FINISHED"
    ]
    run = (nested or runs)[0]
    pages = [
        ("experiments.png", experiments_url(base_url), "Experiments - MLflow"),
        ("runs.png", experiment_url(base_url, eid), f"Runs - Experiment {eid} "),
        ("run.png", run_url(base_url, eid, run.info.run_id), f"Run {run.info.run_id} "),
    ]
    # The reproduction's training runs (one per unit: durations, datasets, logged models).
    training = [e for e in experiments if e[1].endswith("/training")]
    if training and client.search_runs([training[0][0]], max_results=1):
        tid = training[0][0]
        pages.append(("training.png", experiment_url(base_url, tid), f"Runs - Experiment {tid} "))
    return pages


def take_screenshots(
    base_url: str, tracking_uri: str, out_dir: Path, alias: str | None = None
) -> list[Path]:
    """Screenshots of :func:`pick_pages` into ``out_dir``, each after checking (by the page's
    title) that the UI opened the view it should; RuntimeError without Chromium or when not.
    ``alias``: reach the server (on 127.0.0.1) under this name (see the module docstring)."""
    binary = find_chromium()
    if binary is None:
        raise RuntimeError(
            "no Chromium found (looked for UAVBENCH_CHROMIUM, then "
            f"{', '.join(CHROMIUM_NAMES)} on the PATH); on Debian: apt-get install -y chromium"
        )
    if alias:
        parts = urlsplit(base_url)
        base_url = f"{parts.scheme}://{alias}:{parts.port}"
    paths = []
    for name, url, expected in pick_pages(base_url, tracking_uri):
        # The view first: a GenAI overview would be a screenshot of the wrong page.
        title = page_title(url, binary, alias)
        if not title.startswith(expected):
            raise RuntimeError(f"{url} opened {title!r}, expected a page titled {expected!r}...")
        paths.append(screenshot(url, Path(out_dir) / name, binary, alias=alias))
    return paths
