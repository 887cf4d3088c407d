"""``uavbench ui`` serves the UI on 127.0.0.1, prints the URL, and Ctrl-C stops everything."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import urllib.request

import pytest

from benchmark.cli import main
from benchmark.tracking.server import free_port, port_is_free


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

    def test_server_uri_is_only_printed(self, capsys):
        assert main(["ui", "--tracking-uri", "http://example.invalid:5000"]) == 0
        assert "http://example.invalid:5000" in capsys.readouterr().out


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
            line = proc.stdout.readline()  # printed once the server answers /health
            assert line.startswith(f"MLflow UI: http://127.0.0.1:{port}"), line
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
