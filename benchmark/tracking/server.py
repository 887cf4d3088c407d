"""Start and stop a real MLflow tracking server (``python -m mlflow server``) on loopback.

Used by ``uavbench ui`` and by the tests that talk to a live server over HTTP. The server runs in
its own process group so stopping it also stops the uvicorn worker it spawns, and nothing else.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from types import TracebackType

from benchmark.tracking.mlflow_tracker import server_is_healthy


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port that was free a moment ago (the OS picks it)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind((host, 0))
        return int(sock.getsockname()[1])


def port_is_free(port: int, host: str = "127.0.0.1") -> bool:
    """True if nothing listens on ``host:port``. SO_REUSEADDR, as servers set it, so connections
    lingering in TIME_WAIT after a server stopped do not count as "in use"."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind((host, port))
        except OSError:
            return False
        return True


class MlflowServer:
    """``with MlflowServer("sqlite:///x.db", artifacts_dir) as server: server.url``.

    ``start()`` returns once ``/health`` answers (or raises ``RuntimeError`` with the server's log
    tail if it exits or does not come up within ``startup_timeout`` seconds).
    """

    def __init__(
        self,
        backend_store_uri: str,
        artifacts_dir: str | Path,
        *,
        host: str = "127.0.0.1",
        port: int | None = None,
        workers: int = 1,
        log_path: str | Path | None = None,
        startup_timeout: float = 90.0,
    ) -> None:
        self.backend_store_uri = backend_store_uri
        self.artifacts_dir = Path(artifacts_dir).resolve()
        self.host = host
        self.port = int(port) if port is not None else free_port(host)
        self.workers = int(workers)
        self.log_path = Path(log_path) if log_path is not None else None
        self.startup_timeout = float(startup_timeout)
        self.process: subprocess.Popen | None = None
        self._log_file = None

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}"

    def command(self) -> list[str]:
        return [
            sys.executable,
            "-m",
            "mlflow",
            "server",
            "--backend-store-uri",
            self.backend_store_uri,
            "--artifacts-destination",
            str(self.artifacts_dir),
            "--host",
            self.host,
            "--port",
            str(self.port),
            "--workers",
            str(self.workers),
        ]

    def start(self) -> MlflowServer:
        if not port_is_free(self.port, self.host):
            raise RuntimeError(f"port {self.port} on {self.host} is already in use")
        self.artifacts_dir.mkdir(parents=True, exist_ok=True)
        if self.log_path is not None:
            self.log_path.parent.mkdir(parents=True, exist_ok=True)
            self._log_file = open(self.log_path, "wb")
        # One thread per server process: the machine is shared (see DEVELOPERS.md). MLflow 3's
        # job runner (GenAI jobs, 7 huey consumer processes) is of no use to a tracking store.
        env = {
            **os.environ,
            "OMP_NUM_THREADS": "1",
            "MKL_NUM_THREADS": "1",
            "MLFLOW_SERVER_ENABLE_JOB_EXECUTION": "false",
        }
        self.process = subprocess.Popen(
            self.command(),
            stdout=self._log_file or subprocess.DEVNULL,
            stderr=subprocess.STDOUT if self._log_file else subprocess.DEVNULL,
            env=env,
            start_new_session=True,  # own process group: stop() reaches the uvicorn worker too
        )
        deadline = time.monotonic() + self.startup_timeout
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                code = self.process.returncode
                self.stop()
                raise RuntimeError(f"mlflow server exited with code {code}{self._log_tail()}")
            if server_is_healthy(self.url, timeout=1.0)[0]:
                return self
            time.sleep(0.25)
        self.stop()
        raise RuntimeError(
            f"mlflow server did not answer {self.url}/health within {self.startup_timeout:.0f} s"
            f"{self._log_tail()}"
        )

    def _log_tail(self) -> str:
        if self.log_path is None or not self.log_path.exists():
            return ""
        lines = self.log_path.read_text(errors="replace").splitlines()[-15:]
        return "; log tail:\n" + "\n".join(lines)

    def stop(self, timeout: float = 15.0) -> None:
        """SIGTERM the server's process group, SIGKILL it after ``timeout`` seconds."""
        proc, self.process = self.process, None
        if proc is not None and proc.poll() is None:
            pgid = os.getpgid(proc.pid)
            os.killpg(pgid, signal.SIGTERM)
            try:
                proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                os.killpg(pgid, signal.SIGKILL)
                proc.wait()
            # The worker may outlive the parent by a moment; it shares the group id.
            try:
                os.killpg(pgid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        if self._log_file is not None:
            self._log_file.close()
            self._log_file = None

    def __enter__(self) -> MlflowServer:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()
