"""The render pool (``benchmark.data.render_pool``): a worker that dies or cannot start ends the
render with one ``RenderWorkerError`` instead of a hang, and the pool's bytes are the in-process
render's (same seed, same bytes, any number of workers).

``multiprocessing.Pool`` waited forever when a worker was killed (it replaces the worker and
keeps waiting for the lost task) or when its initializer died (it restarts it without end); each
case here runs in a subprocess under a timeout, so a regression fails instead of hanging the suite.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).parent
TIMEOUT_S = 600  # generous: spawned workers import torch and cv2 on a loaded 2-core machine


def run_mode(mode: str) -> str:
    proc = subprocess.run(
        [sys.executable, str(HERE / "render_pool_faults.py"), mode],
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
        env={**os.environ, "PYTHONPATH": str(HERE.parents[1])},
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return proc.stdout.strip()


class TestDeadWorker:
    def test_worker_killed_while_rendering(self):
        out = run_mode("render-kill")
        assert out.startswith("RenderWorkerError: a render worker process died (pid ")
        assert "killed by SIGKILL; the out-of-memory killer sends SIGKILL" in out
        assert "rerun the same command (finished shards are kept)" in out

    def test_worker_killed_while_starting(self):
        out = run_mode("init-kill")
        assert out.startswith("RenderWorkerError: a render worker process died (")
        assert "killed by SIGKILL" in out

    def test_start_up_error_is_reported_with_its_message(self):
        out = run_mode("init-error")
        assert out.startswith("RenderWorkerError: render worker ")
        assert "could not start: FileNotFoundError: city cache /nowhere/cities" in out


@pytest.mark.slow
def test_two_workers_write_the_bytes_of_the_in_process_render(smoke_root, city_cache, tmp_path):
    """Same profile and seed through the process pool (2 spawned workers) and in this process
    (``smoke_root``, 1 worker): every file, manifest included, byte-identical."""
    from benchmark.data.profiles import DATA_PROFILES
    from benchmark.data.writer import simulate_dataset

    out = tmp_path / "ds"
    stats = simulate_dataset(
        out, DATA_PROFILES["smoke"], 0, workers=2, cache_dir=city_cache, progress=False
    )
    assert stats["state"] == "written"

    def files(root: Path) -> dict[str, bytes]:
        return {str(p.relative_to(root)): p.read_bytes() for p in root.rglob("*") if p.is_file()}

    assert files(out) == files(smoke_root)
