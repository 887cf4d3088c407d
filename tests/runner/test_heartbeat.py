"""The units' heartbeat files and the pool driver's progress line built from them."""

from __future__ import annotations

import concurrent.futures as cf
import io
import os
import threading
import time
from types import SimpleNamespace

import pytest

from benchmark.progress import Progress
from benchmark.runner.execute import heartbeat, pool
from benchmark.runner.execute.heartbeat import (
    HEARTBEAT_FILE,
    MTIME_SLACK_S,
    read_heartbeat,
    running_status,
    write_heartbeat,
)
from benchmark.runner.execute.work_items import Entry


class TestWriteAndRead:
    def test_round_trip_and_replace(self, tmp_path):
        write_heartbeat(tmp_path / "u", 0, 12)  # creates the unit directory
        assert read_heartbeat(tmp_path / "u", since=0.0) == (0, 12)
        write_heartbeat(tmp_path / "u", 5, 12)
        assert read_heartbeat(tmp_path / "u", since=0.0) == (5, 12)
        assert [p.name for p in (tmp_path / "u").iterdir()] == [HEARTBEAT_FILE]  # no temp left

    def test_older_than_the_invocation_is_ignored(self, tmp_path):
        write_heartbeat(tmp_path, 3, 12)
        old = time.time() - 3600
        os.utime(tmp_path / HEARTBEAT_FILE, (old, old))  # written by an earlier invocation
        assert read_heartbeat(tmp_path, since=time.time() - 60) is None
        assert read_heartbeat(tmp_path, since=old - 1) == (3, 12)

    def test_an_mtime_a_tick_before_since_still_counts(self, tmp_path):
        """The file system's clock may lag ``time.time()`` (a coarse tick, 2 s granularity,
        another node's clock): a heartbeat stamped up to ``MTIME_SLACK_S`` before ``since`` is
        this invocation's; one stamped well before is not."""
        write_heartbeat(tmp_path, 1, 12)
        since = time.time()
        stamp = since - 0.5 * MTIME_SLACK_S
        os.utime(tmp_path / HEARTBEAT_FILE, (stamp, stamp))
        assert read_heartbeat(tmp_path, since=since) == (1, 12)
        stamp = since - 2 * MTIME_SLACK_S
        os.utime(tmp_path / HEARTBEAT_FILE, (stamp, stamp))
        assert read_heartbeat(tmp_path, since=since) is None

    @pytest.mark.parametrize("text", ["", "{", '{"epoch": 1}', '{"epoch": "x", "epochs": 2}'])
    def test_unreadable_is_none(self, tmp_path, text):
        (tmp_path / HEARTBEAT_FILE).write_text(text)
        assert read_heartbeat(tmp_path, since=0.0) is None
        assert read_heartbeat(tmp_path / "absent", since=0.0) is None

    def test_a_failed_write_does_not_raise(self, tmp_path):
        (tmp_path / "file").write_text("not a directory")
        write_heartbeat(tmp_path / "file", 1, 2)  # the training it reports on carries on
        assert (tmp_path / "file").read_text() == "not a directory"


class TestRunningStatus:
    def test_states(self, tmp_path):
        for name, epoch in (("a", 0), ("b", 3), ("c", 12)):
            write_heartbeat(tmp_path / name, epoch, 12)
        units = [("A", tmp_path / "a"), ("B", tmp_path / "b"), ("C", tmp_path / "c"),
                 ("D", tmp_path / "d")]  # fmt: skip
        status = running_status(units, since=0.0)
        assert status == "running: A starting; B epoch 3/12; C evaluating"  # D: no heartbeat

    def test_nothing_yet(self, tmp_path):
        assert running_status([("A", tmp_path / "a")], since=0.0) == ""


class TestPoolWaitReporting:
    def test_progress_line_names_the_running_unit_and_its_epoch(self, tmp_path, monkeypatch):
        """A slow unit writes heartbeats while the driver waits: the progress line shows each
        new epoch before the unit completes, and on_done runs once per unit."""
        monkeypatch.setattr(heartbeat, "POLL_S", 0.05)
        step = threading.Event()
        stream = io.StringIO()
        units = {key: SimpleNamespace(key=key, title=f"unit {key}") for key in ("fast", "slow")}
        entries = {key: Entry(unit, key, unit.title, heartbeat_dir=tmp_path / key)
                   for key, unit in units.items()}  # fmt: skip

        # Generous timeouts: on a loaded 2-core machine the driver's poll may lag by seconds, and
        # a unit that moved on without its step would skip a line the ticker waits for.
        def train(key: str) -> str:
            if key == "slow":
                for epoch in range(3):
                    write_heartbeat(tmp_path / key, epoch, 3)
                    if not step.wait(60.0):
                        raise TimeoutError(f"no step after epoch {epoch}")
                    step.clear()
            return key

        finished = []
        with cf.ThreadPoolExecutor(2) as executor, Progress(2, "reproduce", stream=stream) as bar:
            submitted = time.time()
            futures = {executor.submit(train, key): entries[key] for key in units}

            missed: list[str] = []  # the ticker's failures, asserted in the test's own thread

            def tick():  # advance the slow unit once the line shows its current epoch
                for expected in ("starting", "epoch 1/3", "epoch 2/3"):
                    deadline = time.time() + 60
                    while f"unit slow {expected}" not in stream.getvalue():
                        if time.time() > deadline:
                            missed.append(f"never showed {expected!r}: {stream.getvalue()!r}")
                            break
                        time.sleep(0.01)
                    step.set()

            ticker = threading.Thread(target=tick)
            ticker.start()
            pool._wait_reporting(futures, lambda u, r: finished.append((u.key, r)), bar, submitted)
            ticker.join()
        assert not missed, missed
        assert sorted(finished) == [("fast", "fast"), ("slow", "slow")]
        lines = stream.getvalue().splitlines()
        assert any("running: unit slow epoch 2/3" in line for line in lines)
        assert not any("unit fast starting" in line for line in lines)  # it wrote no heartbeat
