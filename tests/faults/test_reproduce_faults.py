"""``uavbench reproduce`` under faults (issue 14): one writer per work directory, true run states
and every invocation listed after ``kill -9``, a damaged dataset in one line, failed units shown
as failed in the reports."""

from __future__ import annotations

import errno
import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from fault_tools import CLI, flip_byte

from benchmark.cli import main
from benchmark.runner.execute.worker import UnitResult
from benchmark.runner.plan import invocations as inv
from benchmark.runner.report.logbook import END_REASON_TAG, Logbook, experiment_name
from benchmark.tracking import RUN_KEY_TAG, RunStatus, create_tracker

ROOT = str(Path(__file__).resolve().parents[2])  # this checkout, not an installed copy
ENV = {**os.environ, "OMP_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1", "PYTHONPATH": ROOT}
# A child that takes a lock, says so, and sleeps until killed (as tests/faults/test_locks.py).
HOLDER = """
import sys, time
from benchmark.locks import work_lock
with work_lock(sys.argv[1], what="test holder"):
    print("locked", flush=True)
    time.sleep(600)
"""


def argv(data: Path, tmp: Path, *extra: str) -> list[str]:
    return [
        "reproduce", "--profile", "smoke", "--only", "table3", "--data", str(data),
        "--workdir", str(tmp / "runs"), "--out", str(tmp / "reports"), "--quiet", *extra,
    ]  # fmt: skip


def hold_lock(path: Path) -> subprocess.Popen:
    proc = subprocess.Popen(
        [sys.executable, "-c", HOLDER, str(path)], stdout=subprocess.PIPE, env=ENV
    )
    assert proc.stdout.readline().strip() == b"locked"
    return proc


def local_runs(tmp: Path) -> list[dict]:
    return [json.loads(p.read_text()) for p in (tmp / "tracking-local").rglob("run.json")]


def one_line(text: str) -> str:
    lines = text.strip().splitlines()
    assert len(lines) == 1, text
    return lines[0]


class TestOneWriterPerWorkdir:
    def test_no_wait_exits_2_naming_the_holder(self, tmp_path, capsys):
        """A second reproduce on a held work directory refuses before touching anything (no
        dataset rendered: the data path does not even exist)."""
        holder = hold_lock(tmp_path / "runs" / inv.LOCK)
        try:
            code = main(argv(tmp_path / "nodata", tmp_path, "--no-wait", "--tracker", "local"))
        finally:
            holder.kill()
            holder.wait()
        assert code == 2
        err = one_line(capsys.readouterr().err)
        assert f"pid {holder.pid} on {socket.gethostname()} (test holder" in err
        assert "choose another workdir" in err and not (tmp_path / "nodata").exists()

    @pytest.mark.slow
    def test_two_concurrent_reproductions_train_each_unit_once(self, tmp_path, smoke_dataset):
        """Two ``reproduce`` started together on one work directory and one fresh MLflow store:
        one trains, the other waits (saying so once), then finds every unit in the store."""
        cmd = [*CLI, *argv(smoke_dataset, tmp_path, "--tracker", "mlflow", "--workers", "1",
                            "--no-models")]  # fmt: skip
        # Output to files, not pipes: the waiting process must never block the working one.
        logs = [tmp_path / f"out{i}.txt" for i in range(2)]
        procs = []
        for log in logs:
            with log.open("w") as fh:
                procs.append(subprocess.Popen(cmd, cwd=tmp_path, env=ENV, stdout=fh,
                                              stderr=subprocess.STDOUT))  # fmt: skip
        try:
            for p in procs:
                p.wait(timeout=3600)  # a loaded 2-core machine; the heading-cue audit renders
        finally:
            for p in procs:
                if p.poll() is None:
                    p.kill()
                    p.wait()
        outs = [log.read_text() for log in logs]
        assert [p.returncode for p in procs] == [0, 0], outs
        waited = [o for o in outs if "waiting for" in o]
        assert len(waited) == 1 and waited[0].count("waiting for") == 1, outs
        assert "locked by pid" in waited[0]
        counts = [re.search(r"(\d+) training runs \((\d+) already", o).groups() for o in outs]
        assert sorted(counts) == [("4", "0"), ("4", "4")], counts
        tracker = create_tracker("mlflow", f"sqlite:///{tmp_path / 'mlflow.db'}",
                                 workdir=tmp_path)  # fmt: skip
        try:
            for table in ("table3", "training"):
                runs = tracker.find_runs(experiment_name("smoke", table))
                rows = [r for r in runs if r.status == "FINISHED" and RUN_KEY_TAG in r.tags]
                keys = [r.tags[RUN_KEY_TAG] for r in rows if not r.tags[RUN_KEY_TAG].startswith(
                    "reproduce-")]  # fmt: skip
                assert len(keys) == 4 and len(set(keys)) == 4, (table, keys)
                assert all(r.status != "RUNNING" for r in runs)
        finally:
            tracker.close()
        journal = inv.read_invocations(tmp_path / "runs")
        assert sorted(j["trained"] for j in journal) == [0, 4]
        assert {j["state"] for j in journal} == {"finished"}


class TestKilledInvocation:
    @pytest.mark.slow
    def test_kill_9_then_resume_true_states_and_both_invocations_listed(
        self, tmp_path, smoke_dataset
    ):
        cmd = [*CLI, *argv(smoke_dataset, tmp_path, "--tracker", "local", "--workers", "1")]
        proc = subprocess.Popen(cmd, cwd=tmp_path, env=ENV, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)  # fmt: skip
        journal = tmp_path / "runs" / inv.JOURNAL
        deadline = time.monotonic() + 600
        try:
            while time.monotonic() < deadline and proc.poll() is None:
                if journal.is_file() and '"event": "unit"' in journal.read_text():
                    break
                time.sleep(0.2)
            assert proc.poll() is None, "the reproduction ended before it could be killed"
            os.kill(proc.pid, signal.SIGKILL)  # mid-way: one unit done, the next one training
        finally:
            if proc.poll() is None:
                proc.kill()
            proc.wait()
        runs = local_runs(tmp_path)
        assert any(r["status"] == "RUNNING" and not r["parent_run_id"] for r in runs)
        (killed,) = inv.read_invocations(tmp_path / "runs")
        assert killed["state"] == inv.KILLED_STATE and killed["trained"] == 1

        resumed = subprocess.run(cmd, cwd=tmp_path, env=ENV, capture_output=True, text=True)
        assert resumed.returncode == 0, resumed.stdout + resumed.stderr
        assert "took over the stale lock" in resumed.stdout  # a status line (progress display)
        assert "left RUNNING by a killed invocation: now KILLED" in resumed.stdout
        runs = local_runs(tmp_path)
        assert not [r for r in runs if r["status"] == "RUNNING"]
        parents = [r for r in runs if r["experiment"].endswith("table3") and not r["parent_run_id"]]
        assert sorted(r["status"] for r in parents) == ["FINISHED", "KILLED"]
        stale = next(r for r in parents if r["status"] == "KILLED")
        assert f"pid {proc.pid} on" in stale["tags"][END_REASON_TAG]
        training = [r for r in runs if r["experiment"] == "uavbench-smoke/training"]
        assert len(training) == 4 and {r["status"] for r in training} == {"FINISHED"}
        rows = [r for r in runs if r["parent_run_id"] and r["status"] == "FINISHED"]
        assert len({r["tags"][RUN_KEY_TAG] for r in rows}) == len(rows) == 4
        # The README lists both invocations: the killed one with the unit it finished.
        readme = (tmp_path / "reports" / "README.md").read_text()
        table = [line for line in readme.splitlines() if re.match(r"\| \d{4}-\d\d-\d\d ", line)]
        assert len(table) == 2, readme
        assert "| killed/unfinished |" in table[0] and "| 1 of 4 |" in table[0]
        assert "| finished |" in table[1] and "| 3 of 4 |" in table[1]


class TestInvocationJournal:
    def test_records_merge_and_a_dead_invocation_reads_killed(self, tmp_path):
        first = inv.start_invocation(tmp_path, ["a", "b"], "abc", started=1000.0)
        first.unit_done("a", True)
        with (tmp_path / inv.JOURNAL).open("a") as fh:
            fh.write('{"id": "' + first.id + '", "event": "unit", "ke')  # cut by a kill
            fh.write("\n")
        # Another process's invocation that died without an end record (pid 1 holds no lock).
        lines = (tmp_path / inv.JOURNAL).read_text().splitlines()
        start = json.loads(lines[0]) | {"id": "dead", "pid": 1, "t": 2000.0}
        unit = {"id": "dead", "event": "unit", "key": "b", "ok": False, "t": 2060.0}
        with (tmp_path / inv.JOURNAL).open("a") as fh:
            fh.write(json.dumps(start) + "\n" + json.dumps(unit) + "\n")
        first.end("finished", wall_s=42.0)
        got = {r["id"]: r for r in inv.read_invocations(tmp_path)}
        assert got[first.id]["state"] == "finished" and got[first.id]["wall_s"] == 42.0
        assert got[first.id]["trained"] == 1 and got[first.id]["failed"] == 0
        assert got["dead"]["state"] == inv.KILLED_STATE
        assert got["dead"]["failed"] == 1 and got["dead"]["wall_s"] == pytest.approx(60.0)
        assert [r["id"] for r in inv.relevant_invocations(tmp_path, ["b"], first.id)] == [
            "dead", first.id
        ]  # fmt: skip
        assert got[first.id]["trained_keys"] == ["a"] and got["dead"]["trained_keys"] == ["b"]

    def test_an_invocation_that_trained_other_units_is_not_a_source(self, tmp_path):
        """A run with more seeds on the same work directory plans the report's units too but
        trains only its extra ones: it did not produce the report's results."""
        first = inv.start_invocation(tmp_path, ["a", "b"], "g1")
        first.unit_done("a", True)
        first.unit_done("b", True)
        first.end("finished")
        more_seeds = inv.start_invocation(tmp_path, ["a", "b", "c"], "g2")
        more_seeds.unit_done("c", True)
        more_seeds.end("finished")
        report = inv.start_invocation(tmp_path, ["a", "b"], "g3")
        report.end("finished")
        ids = [r["id"] for r in inv.relevant_invocations(tmp_path, ["a", "b"], report.id)]
        assert ids == [first.id, report.id]
        ids = [r["id"] for r in inv.relevant_invocations(tmp_path, ["c"], report.id)]
        assert ids == [more_seeds.id, report.id]

    def test_a_legacy_line_counts_its_planned_units_as_trained(self, tmp_path):
        legacy = {"started": "2025-01-01 10:00", "wall_s": 60.0, "trained": 2, "units": 2,
                  "machine": "m", "git_commit": "g", "unit_keys": ["a", "b"]}  # fmt: skip
        (tmp_path / inv.JOURNAL).write_text(json.dumps(legacy) + "\n")
        (only,) = inv.read_invocations(tmp_path)
        assert only["trained_keys"] == ["a", "b"]
        assert len(inv.relevant_invocations(tmp_path, ["b"], "none")) == 1

    def test_a_live_invocation_reads_running_and_legacy_lines_finished(self, tmp_path):
        holder = hold_lock(tmp_path / inv.LOCK)
        try:
            legacy = {"started": "2025-01-01 10:00", "wall_s": 60.0, "trained": 2, "units": 2,
                      "machine": "m", "git_commit": "g", "unit_keys": ["a", "b"]}  # fmt: skip
            start = {"id": "live", "event": "start", "t": time.time(), "started": "now",
                     "units": 1, "unit_keys": ["a"], "pid": holder.pid,
                     "host": socket.gethostname(), "machine": "m", "git_commit": "g"}  # fmt: skip
            (tmp_path / inv.JOURNAL).write_text(json.dumps(legacy) + "\n" + json.dumps(start))
            states = [r["state"] for r in inv.read_invocations(tmp_path)]
            assert states == ["finished", "running"]
        finally:
            holder.kill()
            holder.wait()
        assert [r["state"] for r in inv.read_invocations(tmp_path)] == [
            "finished",
            "killed/unfinished",
        ]


class TestStaleRuns:
    def logbook(self, tmp_path, owner):
        tracker = create_tracker("local", workdir=tmp_path)
        return Logbook(tracker, "smoke", {"git_commit": "abc"}, owner=owner)

    def test_dead_owner_killed_live_owner_untouched(self, tmp_path):
        holder = hold_lock(tmp_path / "live-workdir" / inv.LOCK)
        try:
            values = (str(holder.pid), socket.gethostname(), str(tmp_path / "live-workdir"))
            live = dict(zip(inv.OWNER_TAGS, values, strict=True))
            dead = dict(live, **{inv.OWNER_TAGS[2]: str(tmp_path / "dead-workdir")})
            for owner in (live, dead, {}):  # {}: a run logged before owner tags existed
                book = self.logbook(tmp_path, owner)
                book.parent("table3")  # left RUNNING, as by a kill -9
            book = self.logbook(tmp_path, inv.owner_tags(tmp_path / "mine"))
            closed = book.close_stale(["table3"])
            runs = local_runs(tmp_path)
            assert len(closed) == 2 and sorted(r["status"] for r in runs) == [
                "KILLED", "KILLED", "RUNNING"
            ]  # fmt: skip
            running = next(r for r in runs if r["status"] == "RUNNING")
            assert running["tags"][inv.OWNER_TAGS[0]] == str(holder.pid)
            # A new parent for this invocation: neither the live one nor a killed one is reused.
            book.parent("table3")
            book.close(RunStatus.FINISHED)
            assert sorted(r["status"] for r in local_runs(tmp_path)) == [
                "FINISHED", "KILLED", "KILLED", "RUNNING"
            ]  # fmt: skip
        finally:
            holder.kill()
            holder.wait()


class TestDamagedData:
    def test_unreadable_config_one_line_exit_2(self, dataset, tmp_path, capsys):
        (dataset / "config.json").write_text('{"broken')
        assert main(argv(dataset, tmp_path, "--tracker", "local")) == 2
        err = one_line(capsys.readouterr().err)
        assert f"dataset {dataset} is damaged" in err and "config.json" in err
        assert f"uavbench verify {dataset}" in err
        assert not (tmp_path / "runs" / "units").exists()  # nothing trained

    def test_bad_bytes_that_cannot_be_repaired_one_line_exit_2(
        self, dataset, tmp_path, monkeypatch, capsys
    ):
        """A flipped byte is re-rendered by the simulate step; on a read-only dataset it cannot
        be: one line naming the dataset and the fix, before any training."""
        from benchmark.data import journal

        flip_byte(dataset / "uav" / "shard_00001.npy")

        def read_only(path, mode="r", *args, **kwargs):
            if any(c in mode for c in "wa"):
                raise PermissionError(errno.EROFS, os.strerror(errno.EROFS), str(path))
            return open(path, mode, *args, **kwargs)

        monkeypatch.setattr(journal, "open", read_only, raising=False)
        assert main(argv(dataset, tmp_path, "--tracker", "local")) == 2
        captured = capsys.readouterr()
        text = captured.err
        assert "Traceback" not in text
        # simulate's notice of what it tried ("corrupted file ...; rendering it again"), a status
        # line (benchmark.progress: stdout), then the error, one line on stderr
        (notice,) = [line for line in captured.out.splitlines() if line.startswith("simulate: ")]
        (err,) = text.strip().splitlines()
        assert notice.startswith("simulate: corrupted file") and "shard_00001.npy" in notice
        assert f"dataset {dataset} is damaged" in err and "read-only file system" in err
        assert f"uavbench verify {dataset}" in err and "render profile 'smoke', seed 0" in err
        assert not (tmp_path / "runs" / "units").exists()


class TestDataOfAnotherSimulator:
    """A dataset (or a heading-cue audit dataset beside it) rendered by other simulator code is
    refused in one line naming it and the fix, before any training, and left as it was."""

    @staticmethod
    def other_simulators(config: dict, root: Path) -> bytes:
        """``root`` holds ``config`` as another simulator's code would have written it."""
        config = {**config, "generator_source": "0123456789ab"}
        root.mkdir(exist_ok=True)
        (root / "config.json").write_text(json.dumps(config))
        return (root / "config.json").read_bytes()

    def test_the_dataset(self, dataset, tmp_path, capsys):
        before = self.other_simulators(json.loads((dataset / "config.json").read_text()), dataset)
        assert main(argv(dataset, tmp_path, "--tracker", "local")) == 2
        err = one_line(capsys.readouterr().err)
        assert f"{dataset} holds a dataset of another simulator or profile" in err
        assert "generator_source: existing '0123456789ab'" in err
        assert "choose another data directory" in err
        assert (dataset / "config.json").read_bytes() == before
        assert not (tmp_path / "runs" / "units").exists() and not (tmp_path / "reports").exists()

    def test_a_heading_cue_audit_dataset(self, dataset, tmp_path, capsys):
        from benchmark.data.writer import dataset_config
        from benchmark.runner.execute.audit import cue_dataset_plan

        stale, profile, seed = cue_dataset_plan(dataset, 2)[1]
        before = self.other_simulators(dataset_config(profile, seed), stale)
        assert main(argv(dataset, tmp_path, "--tracker", "local")) == 2
        err = one_line(capsys.readouterr().err)
        assert f"error: {stale} holds a heading-cue audit dataset of another simulator" in err
        assert "(generator_source: existing '0123456789ab' != requested '" in err
        assert err.endswith("'); move it away or delete it, and the next reproduce renders it "
                            "again (about 2.5 min for quick on 2 cores)")  # fmt: skip
        assert (stale / "config.json").read_bytes() == before
        assert not (tmp_path / "runs" / "units").exists() and not (tmp_path / "reports").exists()


class TestFailedUnitsInReports:
    @pytest.mark.slow  # the reports' heading-cue audit renders 4 more smoke datasets once
    def test_every_unit_failed_reports_written_rows_read_failed(
        self, smoke_dataset, tmp_path, monkeypatch, capsys
    ):
        """Every unit fails (as when its data is damaged mid-run): exit 1, no traceback, the
        reports name the failed rows and their cells read ``failed``."""
        from benchmark.runner.execute import pool  # the default executor calls pool.run_unit

        def fails(task):
            return UnitResult(task.key, False, error="DatasetError: corrupted file x.npy")

        monkeypatch.setattr(pool, "run_unit", fails)
        monkeypatch.chdir(tmp_path)
        assert main(argv(smoke_dataset, tmp_path, "--tracker", "local", "--workers", "1")) == 1
        out = capsys.readouterr().out
        assert out.count("FAILED ") == 4 and "4 training run(s) failed" in out
        table3 = (tmp_path / "reports" / "table3.md").read_text()
        assert "## Failed training runs" in table3 and "corrupted file x.npy" in table3
        rows = [
            line for line in table3.splitlines() if line.startswith("| ") and "|---" not in line
        ]
        # the main table's rows, then the swap probe's (first column: the split)
        probe = [r for r in rows if r.startswith("| `standard/test` |") and "Constant" not in r]
        trained = [r for r in rows if "Constant" not in r and "failed" in r and r not in probe]
        assert len(trained) == 4 and all("not run" not in r for r in trained)
        assert len(probe) == 4 and all("failed" in r for r in probe)
        readme = (tmp_path / "reports" / "README.md").read_text()
        assert "4 row(s) failed to train" in readme and "| failed | " in readme
        (journal,) = inv.read_invocations(tmp_path / "runs")
        assert journal["failed"] == 4 and journal["state"] == "failed"


def test_stale_lock_file_of_dead_process_is_taken_over(tmp_path, capsys):
    """A lock file left by a dead reproduce (hand-written, pid gone) does not block: it is taken
    over with a note (the run then stops on a --data that is no dataset, after the lock)."""
    lock = tmp_path / "runs" / inv.LOCK
    lock.parent.mkdir(parents=True)
    lock.write_text(json.dumps({"pid": 999999, "host": socket.gethostname(), "started": 1.0,
                                "what": "uavbench reproduce"}))  # fmt: skip
    (tmp_path / "notdata").mkdir()
    (tmp_path / "notdata" / "notes.txt").write_text("not a dataset")
    assert main(argv(tmp_path / "notdata", tmp_path, "--tracker", "local")) == 2
    out, err = capsys.readouterr()
    assert "took over the stale lock" in out and "pid 999999" in out  # a status line
    assert "non-empty directory without config.json" in err
    assert not lock.exists()
