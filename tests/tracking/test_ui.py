"""``uavbench ui``: serves the UI on 127.0.0.1, prints one classic-Runs-view link per experiment,
Ctrl-C stops everything; ``--screenshots`` takes the three PNGs with headless Chromium."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import urllib.request
from urllib.parse import parse_qs, urlsplit

import numpy as np
import pytest

from benchmark.cli import main
from benchmark.tracking.screenshots import (
    ALIAS_HOST,
    CHROMIUM_FLAGS,
    MIN_COLOURS,
    alias_env,
    chromium_command,
    count_colours,
    find_chromium,
    pick_pages,
    screenshot,
)
from benchmark.tracking.server import free_port, port_is_free
from benchmark.tracking.ui_links import (
    ExperimentLink,
    experiment_links,
    experiment_url,
    experiments_url,
    first_line,
    format_links,
    list_experiments,
    run_url,
)

BASE = "http://127.0.0.1:5000"


def make_store(path, descriptions: dict[str, str | None]):
    """A sqlite store with one experiment per name (description tag when given), each holding a
    parent run and a finished nested run; returns its URI and the client."""
    from mlflow.tracking import MlflowClient

    uri = f"sqlite:///{path / 'mlflow.db'}"
    client = MlflowClient(tracking_uri=uri)
    for name, text in descriptions.items():
        tags = {"mlflow.note.content": text} if text is not None else {}
        eid = client.create_experiment(name, artifact_location=str(path / "art"), tags=tags)
        parent = client.create_run(eid, run_name="reproduce smoke")
        child = client.create_run(
            eid, run_name="Pd/Re-Net seed 0", tags={"mlflow.parentRunId": parent.info.run_id}
        )
        client.log_metric(child.info.run_id, "test_dphi_deg", 12.5)
        client.set_terminated(child.info.run_id)
        client.set_terminated(parent.info.run_id)
    return uri, client


class TestUrls:
    def test_classic_view_of_one_experiment(self):
        url = experiment_url(BASE + "/", "3")
        assert url == "http://127.0.0.1:5000/#/experiments/3?workflowType=machine_learning"
        # what MLflow's router reads: the route in the fragment, the view in its query
        route, _, query = urlsplit(url).fragment.partition("?")
        assert route == "/experiments/3"
        assert parse_qs(query) == {"workflowType": ["machine_learning"]}

    def test_run_and_list(self):
        assert run_url(BASE, "3", "abc") == f"{BASE}/#/experiments/3/runs/abc?{self.view}"
        assert experiments_url(BASE) == f"{BASE}/#/experiments?{self.view}"

    view = "workflowType=machine_learning"


class TestFirstLine:
    @pytest.mark.parametrize(
        ("text", "expected"),
        [
            (None, ""),
            ("", ""),
            ("\n  \n", ""),
            ("**Table 1** of `quick`.\nSecond line.", "Table 1 of `quick`."),
            ("\n# Heading\nbody", "Heading"),
        ],
    )
    def test_values(self, text, expected):
        assert first_line(text) == expected

    def test_cut_with_ellipsis(self):
        line = first_line("x" * 300, limit=40)
        assert len(line) == 40 and line.endswith("…")


class TestLinks:
    def test_natural_order_and_descriptions(self):
        experiments = [
            ("7", "uavbench-quick/table10", {}),
            ("2", "uavbench-quick/table2", {"mlflow.note.content": "**Table 2**\nmore"}),
            ("5", "uavbench-quick/fig5", {"mlflow.note.content": "Fig. 5"}),
            ("9", "train", {}),
        ]
        links = experiment_links(BASE, experiments)
        assert [x.name for x in links] == [
            "train", "uavbench-quick/fig5", "uavbench-quick/table2", "uavbench-quick/table10",
        ]  # fmt: skip
        assert links[2] == ExperimentLink("2", "uavbench-quick/table2", "Table 2",
                                          experiment_url(BASE, "2"))  # fmt: skip
        assert links[0].description == ""

    def test_format(self):
        links = experiment_links(BASE, [("4", "a/table1", {"mlflow.note.content": "Table 1"})])
        text = format_links(links, BASE).splitlines()
        assert text[0].endswith(experiments_url(BASE))
        assert text[1].split() == ["a/table1", experiment_url(BASE, "4")]
        assert text[2].strip() == "Table 1"
        assert "no experiments" in format_links([], BASE)

    def test_list_from_a_store(self, tmp_path):
        uri, _ = make_store(tmp_path, {"uavbench-smoke/table1": "Table 1\nx", "train": None})
        found = {name: (eid, tags) for eid, name, tags in list_experiments(uri)}
        assert set(found) == {"uavbench-smoke/table1", "train"}  # the empty Default left out
        assert found["uavbench-smoke/table1"][1]["mlflow.note.content"] == "Table 1\nx"


class TestUiArguments:
    def test_port_in_use(self, tmp_path, monkeypatch, capsys):
        import socket

        monkeypatch.chdir(tmp_path)
        with socket.socket() as sock:
            sock.bind(("127.0.0.1", 0))
            sock.listen()
            port = sock.getsockname()[1]
            assert main(["ui", "--port", str(port)]) == 2
        assert "already in use" in capsys.readouterr().err

    def test_unreachable_server_said_at_once(self, capsys):
        start = time.monotonic()
        assert main(["ui", "--tracking-uri", "http://example.invalid:5000"]) == 1
        out, err = capsys.readouterr()
        assert "http://example.invalid:5000" in out and "cannot reach" in err
        assert time.monotonic() - start < 30  # no minutes of client retries

    def test_links_of_a_running_server(self, mlflow_server, capsys):
        from mlflow.tracking import MlflowClient

        client = MlflowClient(tracking_uri=mlflow_server.url)
        eid = client.create_experiment(
            "uavbench-smoke/fig7", tags={"mlflow.note.content": "κ sweep\nmore"}
        )
        assert main(["ui", "--tracking-uri", mlflow_server.url]) == 0
        out = capsys.readouterr().out
        line = next(x for x in out.splitlines() if "uavbench-smoke/fig7" in x)
        assert line.split()[-1] == experiment_url(mlflow_server.url, eid)
        assert "κ sweep" in out and "more" not in out


class TestChromiumCommand:
    def test_flags(self, tmp_path):
        cmd = chromium_command("chromium", "http://x/", tmp_path / "p", tmp_path / "a.png",
                               (800, 600), 5000, alias="uavbench-ui")  # fmt: skip
        # the flags a closed network needs (no background networking, updates, sync, QUIC)
        for flag in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                     "--no-first-run", "--disable-background-networking",
                     "--disable-component-update", "--disable-sync"):  # fmt: skip
            assert flag in cmd and flag in CHROMIUM_FLAGS
        assert f"--user-data-dir={tmp_path / 'p'}" in cmd
        assert "--window-size=800,600" in cmd and "--virtual-time-budget=5000" in cmd
        assert f"--screenshot={tmp_path / 'a.png'}" in cmd and cmd[-1] == "http://x/"
        assert "--host-resolver-rules=MAP uavbench-ui 127.0.0.1" in cmd
        dom = chromium_command("chromium", "http://x/", tmp_path / "p")
        assert "--dump-dom" in dom and not any(c.startswith("--screenshot") for c in dom)
        assert not any(c.startswith("--host-resolver-rules") for c in dom)

    def test_alias_env(self):
        env = alias_env(5123)
        assert f"{ALIAS_HOST}:5123" in env["MLFLOW_SERVER_ALLOWED_HOSTS"].split(",")
        assert "127.0.0.1:5123" in env["MLFLOW_SERVER_ALLOWED_HOSTS"].split(",")
        assert env["MLFLOW_SERVER_CORS_ALLOWED_ORIGINS"] == f"http://{ALIAS_HOST}:5123"


class TestBlankPage:
    def test_colours(self, tmp_path):
        import cv2

        blank = np.full((50, 80, 3), 255, np.uint8)
        blank[10:20, 10:20] = (0, 0, 0)
        cv2.imwrite(str(tmp_path / "blank.png"), blank)
        noisy = np.random.default_rng(0).integers(0, 256, (50, 80, 3), dtype=np.uint8)
        cv2.imwrite(str(tmp_path / "page.png"), noisy)
        assert count_colours(tmp_path / "blank.png") == 2
        assert count_colours(tmp_path / "page.png") == len(np.unique(noisy.reshape(-1, 3), axis=0))
        assert count_colours(tmp_path / "missing.png") == 0

    def test_blank_screenshot_is_an_error(self, tmp_path):
        # A stand-in browser that writes a white PNG wherever --screenshot= points.
        fake = tmp_path / "fake-chromium"
        fake.write_text(
            f"#!{sys.executable}\nimport sys, numpy as np, cv2\n"
            "png = next(a.split('=', 1)[1] for a in sys.argv if a.startswith('--screenshot='))\n"
            "cv2.imwrite(png, np.full((20, 20, 3), 255, np.uint8))\n"
        )
        fake.chmod(0o755)
        with pytest.raises(RuntimeError, match="blank page"):
            screenshot("http://127.0.0.1:1/", tmp_path / "out.png", str(fake))


class TestPickPages:
    def test_table1_and_a_nested_run(self, tmp_path):
        uri, client = make_store(
            tmp_path, {"uavbench-smoke/fig5": "F", "uavbench-smoke/table1": "T"}
        )
        pages = pick_pages(BASE, uri)
        assert [p[0] for p in pages] == ["experiments.png", "runs.png", "run.png"]
        eid = client.get_experiment_by_name("uavbench-smoke/table1").experiment_id
        assert pages[1][1] == experiment_url(BASE, eid)
        run_id = pages[2][1].split("/runs/")[1].split("?")[0]
        assert client.get_run(run_id).info.run_name == "Pd/Re-Net seed 0"  # not the parent
        assert pages[1][2] == f"Runs - Experiment {eid} "  # the classic view's title

    def test_training_runs_when_there(self, tmp_path):
        names = {"uavbench-smoke/table1": "T", "uavbench-smoke/training": "runs"}
        uri, client = make_store(tmp_path, names)
        pages = pick_pages(BASE, uri)
        tid = client.get_experiment_by_name("uavbench-smoke/training").experiment_id
        assert pages[3] == ("training.png", experiment_url(BASE, tid), f"Runs - Experiment {tid} ")

    def test_empty_store(self, tmp_path):
        uri, _ = make_store(tmp_path, {})
        with pytest.raises(RuntimeError, match="no experiment"):
            pick_pages(BASE, uri)


@pytest.mark.skipif(find_chromium() is None, reason="no Chromium (apt-get install -y chromium)")
class TestScreenshots:
    def test_three_pages(self, tmp_path, capsys):
        """The documented command, end to end: its own server, the alias, real Chromium."""
        uri, _ = make_store(tmp_path, {"uavbench-smoke/table1": "Table 1 of smoke"})
        before = {k: os.environ.get(k) for k in alias_env(1)}
        out = tmp_path / "ui"
        args = ["--port", str(free_port()), "--artifacts-dir", str(tmp_path / "art")]
        assert main(["ui", "--tracking-uri", uri, *args, "--screenshots", str(out)]) == 0
        assert {k: os.environ.get(k) for k in alias_env(1)} == before  # restored
        import cv2

        for name in ("experiments.png", "runs.png", "run.png"):
            image = cv2.imread(str(out / name))
            assert image.shape == (1000, 1600, 3)
            assert count_colours(out / name) >= MIN_COLOURS
        assert f"wrote {out / 'run.png'}" in capsys.readouterr().out


@pytest.mark.slow
class TestUiServes:
    def test_serves_and_stops_on_ctrl_c(self, tmp_path):
        port = free_port()
        env = {**os.environ, "MLFLOW_TRACKING_URI": ""}
        proc = subprocess.Popen(
            [sys.executable, "-m", "benchmark.cli", "ui", "--port", str(port)],
            cwd=tmp_path,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
            env=env,
        )
        try:
            # Status lines, in order: the empty store's note, "starting ...", then the URL,
            # said once the server answers /health.
            said = [proc.stdout.readline() for _ in range(3)]
            assert "does not exist yet" in said[0] and said[1].startswith("starting"), said
            assert said[2].startswith(f"MLflow UI: http://127.0.0.1:{port}"), said
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/health", timeout=10) as resp:
                assert resp.status == 200
            assert (tmp_path / "mlflow.db").is_file()  # the default store, in the cwd
            proc.send_signal(signal.SIGINT)
            assert proc.wait(timeout=30) == 0
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        deadline = time.monotonic() + 10
        while not port_is_free(port) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert port_is_free(port)  # the server (and its worker) are gone
