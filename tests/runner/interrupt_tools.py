"""Ctrl-C during a smoke reproduction, as a terminal sends it (a module of its own: conftest files
are not imported), shared by the process-pool and the Ray executor tests."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path


def ctrl_c_while_training(
    tmp_path: Path,
    dataset: Path,
    *extra: str,
    open_timeout_s: float,
    exit_timeout_s: float,
) -> tuple[subprocess.Popen, str]:
    """Start ``uavbench reproduce --profile smoke --workers 2 --tracker local`` (plus ``extra``) in
    ``tmp_path``, wait until a training run is RUNNING, send SIGINT to its whole process group and
    wait for it to end. Returns the ended process and its output (stdout and stderr)."""
    argv = [
        sys.executable, "-m", "benchmark.cli", "reproduce", "--profile", "smoke", *extra,
        "--workers", "2", "--tracker", "local", "--quiet", "--data", str(dataset),
        "--workdir", str(tmp_path / "runs"), "--out", str(tmp_path / "reports"),
    ]  # fmt: skip
    root = str(Path(__file__).resolve().parents[2])  # this checkout, not an installed copy
    env = {**os.environ, "OMP_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1", "PYTHONPATH": root}
    # A process started with SIGINT ignored (a background job of a non-interactive shell, as
    # `nohup bash .ci/run &`) passes that on, and Python then installs no KeyboardInterrupt
    # handler: restore the default, as a terminal's foreground job has it.
    proc = subprocess.Popen(
        argv, cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
        text=True, start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )  # fmt: skip
    training = tmp_path / "tracking-local" / "uavbench-smoke_training"
    deadline = time.monotonic() + open_timeout_s
    try:
        while time.monotonic() < deadline and proc.poll() is None:
            if any(json.loads(p.read_text())["status"] == "RUNNING"
                   for p in training.glob("*/run.json")):  # fmt: skip
                break
            time.sleep(0.05)
        assert proc.poll() is None, "the reproduction ended before a training run opened"
        os.killpg(proc.pid, signal.SIGINT)
        out, _ = proc.communicate(timeout=exit_timeout_s)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    return proc, out
