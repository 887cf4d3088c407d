"""One writer per directory (``benchmark.locks``, issue 14 item 4): holder named, waiting or exit 2,
a dead holder's lock taken over, and two ``uavbench simulate`` into one directory."""

from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time

import pytest
from fault_tools import CLI, all_files

from benchmark.cli import main
from benchmark.locks import LockBusyError, read_holder, work_lock

# A child that takes the lock, says so, and sleeps until killed.
HOLDER = """
import sys, time
from benchmark.locks import work_lock
with work_lock(sys.argv[1], what="test holder"):
    print("locked", flush=True)
    time.sleep(600)
"""


def hold_in_child(path):
    proc = subprocess.Popen([sys.executable, "-c", HOLDER, str(path)], stdout=subprocess.PIPE)
    assert proc.stdout.readline().strip() == b"locked"
    return proc


class TestWorkLock:
    def test_holder_recorded_then_released(self, tmp_path):
        path = tmp_path / "work" / ".lock"
        with work_lock(path, what="reproduce") as me:
            assert me.pid == os.getpid() and me.host == socket.gethostname()
            assert read_holder(path) == me
            assert json.loads(path.read_text())["what"] == "reproduce"
            assert abs(me.started - time.time()) < 60
        assert not path.exists()

    def test_second_holder_refused_naming_the_first(self, tmp_path):
        path = tmp_path / ".lock"
        proc = hold_in_child(path)
        try:
            with pytest.raises(LockBusyError) as err:
                with work_lock(path, what="reproduce"):
                    pass
            text = str(err.value)
            assert f"pid {proc.pid} on {socket.gethostname()} (test holder, since" in text
            assert err.value.holder.pid == proc.pid
        finally:
            proc.kill()
            proc.wait()

    def test_not_reentrant_in_one_process(self, tmp_path):
        with work_lock(tmp_path / ".lock", what="outer"):
            with pytest.raises(LockBusyError, match="outer"):
                with work_lock(tmp_path / ".lock", what="inner"):
                    pass

    def test_waits_with_a_message_until_released(self, tmp_path):
        path = tmp_path / ".lock"
        proc = hold_in_child(path)
        threading.Timer(1.0, proc.terminate).start()  # SIGTERM: the holder exits, lock freed
        said = []
        with work_lock(path, what="second", wait=True, poll_s=0.1, notify=said.append) as me:
            assert read_holder(path) == me
        proc.wait()
        assert len([m for m in said if m.startswith("waiting for")]) == 1
        assert f"pid {proc.pid}" in said[0]

    def test_wait_timeout(self, tmp_path):
        path = tmp_path / ".lock"
        proc = hold_in_child(path)
        try:
            t0 = time.monotonic()
            with pytest.raises(LockBusyError, match="test holder"):
                with work_lock(path, what="x", wait=True, poll_s=0.05, timeout_s=0.3):
                    pass
            assert 0.3 <= time.monotonic() - t0 < 5
        finally:
            proc.kill()
            proc.wait()

    def test_lock_of_a_killed_process_taken_over(self, tmp_path):
        path = tmp_path / ".lock"
        proc = hold_in_child(path)
        proc.send_signal(signal.SIGKILL)  # no cleanup: the file stays, naming the dead pid
        proc.wait()
        assert path.exists() and read_holder(path).pid == proc.pid
        said = []
        with work_lock(path, what="next", notify=said.append) as me:
            assert read_holder(path) == me
        host = socket.gethostname()
        assert len(said) == 1 and said[0].endswith("which has ended")
        assert said[0].startswith(f"took over the stale lock {path} of pid {proc.pid} on {host}")

    def test_hand_written_stale_lock_taken_over(self, tmp_path):
        path = tmp_path / ".lock"
        dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                              capture_output=True, text=True).stdout  # fmt: skip
        stale = {"pid": int(dead), "host": socket.gethostname(), "started": 0.0, "what": "old"}
        path.write_text(json.dumps(stale))
        with work_lock(path, what="new", notify=lambda m: None) as me:
            assert read_holder(path) == me


class TestSimulateLock:
    def test_no_wait_exits_2_naming_the_holder(self, tmp_path, city_cache, capsys):
        out = tmp_path / "ds"
        with work_lock(out / ".simulate.lock", what="uavbench simulate (test)"):
            code = main(["simulate", "--profile", "smoke", "--out", str(out), "--no-wait",
                         "--city-cache", str(city_cache), "--quiet"])  # fmt: skip
        err = capsys.readouterr().err.strip()
        assert code == 2 and len(err.splitlines()) == 1
        assert f"is locked by pid {os.getpid()} on {socket.gethostname()}" in err
        assert "uavbench simulate (test)" in err
        assert not (out / "config.json").exists()  # nothing written while locked

    @pytest.mark.slow
    def test_two_simulates_into_one_directory_one_writer(self, tmp_path, reference, city_cache):
        """A second ``simulate`` started while the first renders waits, then finds the dataset
        finished: one writer, the reference bytes."""
        out = tmp_path / "ds"
        args = [*CLI, "simulate", "--profile", "smoke", "--size", "240", "--workers", "1",
                "--out", str(out), "--city-cache", str(city_cache), "--quiet"]  # fmt: skip
        env = {**os.environ, "OMP_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}
        # The second interpreter imports everything first and starts on a line from stdin, so
        # it reaches the lock within milliseconds while the first is still rendering.
        preload = ("import sys, benchmark.data.writer, benchmark.sim; from benchmark.cli import "
                   "main; sys.stdin.readline(); sys.exit(main(sys.argv[1:]))")  # fmt: skip
        second = subprocess.Popen(
            [sys.executable, "-c", preload, *args[3:]], env=env, stdin=subprocess.PIPE,
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        time.sleep(3)  # its imports
        first = subprocess.Popen(args, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        deadline = time.monotonic() + 120
        while not (out / ".simulate.lock").exists() and time.monotonic() < deadline:
            time.sleep(0.01)
        out2, err2 = second.communicate("go\n", timeout=600)
        out1, err1 = (s.decode() for s in first.communicate(timeout=600))
        assert first.returncode == 0 and second.returncode == 0, err1 + err2
        assert "written" in out1 and "already complete" in out2
        assert "waiting for" in err2 and f"pid {first.pid}" in err2
        assert not (out / ".simulate.lock").exists()
        ref = tmp_path / "ref"
        subprocess.run([*args[:-4], str(ref), *args[-3:]], env=env, check=True)
        assert all_files(out) == all_files(ref)

    @pytest.mark.slow
    def test_kill_9_during_render_then_rerun(self, tmp_path, city_cache):
        """kill -9 mid-render leaves the lock file (naming the dead pid) and the render journal;
        the rerun takes the lock over, trusts only journalled bytes, and ends with the bytes of
        an uninterrupted run."""
        out, ref = tmp_path / "ds", tmp_path / "ref"
        env = {**os.environ, "OMP_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}

        def args(path):
            return [*CLI, "simulate", "--profile", "smoke", "--size", "240", "--workers", "1",
                    "--out", str(path), "--city-cache", str(city_cache), "--quiet"]  # fmt: skip

        proc = subprocess.Popen(args(out), env=env, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 120
        while len(list(out.glob("uav/shard_*.npy"))) < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        assert read_holder(out / ".simulate.lock").pid == proc.pid
        assert (out / ".render-journal.jsonl").is_file() and not (out / "manifest.json").exists()
        rerun = subprocess.run(args(out), env=env, capture_output=True, text=True, timeout=600)
        assert rerun.returncode == 0, rerun.stderr
        assert (
            f"took over the stale lock {out / '.simulate.lock'} of pid {proc.pid}" in rerun.stderr
        )
        full = subprocess.run(args(ref), env=env, check=True, capture_output=True, text=True)
        assert all_files(out) == all_files(ref)

        def rendered(stdout: str) -> int:
            return int(re.search(r"rendered (\d+) UAV", stdout).group(1))

        assert rendered(rerun.stdout) < rendered(full.stdout)  # journalled shards were kept
