"""Issue 14, items 4 and 7: a plain path as tracking URI becomes a sqlite store or is refused
with the fix (never a silent fallback), and two processes opening a fresh sqlite store at once
both get MLflow (the schema is created once, under the lock file beside the database)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from fault_tools import CLI

from benchmark.errors import InputError
from benchmark.tracking import create_tracker, normalize_tracking_uri

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("name", ["mlflow.db", "sub/dir/runs.sqlite", "x.sqlite3"])
def test_a_db_path_becomes_a_sqlite_store(tmp_path, monkeypatch, capsys, name):
    monkeypatch.chdir(tmp_path)
    tracker = create_tracker("mlflow", f"./{name}", workdir=tmp_path)
    db = (tmp_path / name).resolve()
    assert tracker.uri == f"sqlite:///{db}"
    assert not tracker.using_fallback
    # said once as a status line (benchmark.progress.status: stdout by default)
    assert f"using the store sqlite:///{db}" in capsys.readouterr().out
    with tracker.start_run("t", "r") as run:
        run.log_metrics({"loss": 1.0}, 0)
    assert db.is_file() and not (tmp_path / "tracking-fallback").exists()
    assert tracker.summary() == f"tracking: sqlite:///{db} (1 run logged during this invocation)"
    from mlflow.tracking import MlflowClient

    (stored,) = MlflowClient(tracker.uri).search_runs(
        [MlflowClient(tracker.uri).get_experiment_by_name("t").experiment_id]
    )
    assert stored.data.metrics == {"loss": 1.0}
    assert not db.with_name(db.name + ".lock").exists()  # the schema lock is released


def test_absolute_path_and_uris_are_kept(tmp_path):
    db = tmp_path / "a.db"
    assert normalize_tracking_uri(str(db)) == f"sqlite:///{db}"
    assert normalize_tracking_uri("http://host:5000/") == "http://host:5000"
    assert normalize_tracking_uri("sqlite:///rel.db") == "sqlite:///rel.db"
    assert normalize_tracking_uri("postgresql+psycopg2://u@h/db") == "postgresql+psycopg2://u@h/db"
    assert normalize_tracking_uri(None) is None and normalize_tracking_uri("  ") is None


@pytest.mark.parametrize(
    "value, match",
    [
        ("{tmp}", r"is a directory, not a tracking store; give a database file such as .*ml"),
        ("{tmp}/runs.txt", r"not a sqlite database.*runs\.db"),
        ("mlruns", r"not a sqlite database.*mlruns\.db"),
        ("file:///{tmp}/mlruns", "MLflow 3 no longer writes file stores"),
        ("htp://host:5000", "unknown tracking URI scheme 'htp'"),
    ],
)  # fmt: skip
def test_anything_else_is_refused_with_the_fix(tmp_path, monkeypatch, value, match):
    monkeypatch.chdir(tmp_path)
    value = value.format(tmp=tmp_path)
    with pytest.raises(InputError, match=match) as err:
        create_tracker("mlflow", value, workdir=tmp_path)
    # the library names the argument, not the command's flag
    assert repr(value) in str(err.value) and "tracking_uri" in str(err.value)
    assert "--tracking-uri" not in str(err.value)
    assert not (tmp_path / "tracking-fallback").exists()


def test_env_value_is_checked_and_named(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MLFLOW_TRACKING_URI", str(tmp_path))
    with pytest.raises(InputError, match="MLFLOW_TRACKING_URI"):
        create_tracker("mlflow", workdir=tmp_path)


def test_commands_refuse_in_one_line(tmp_path):
    """``uavbench ui`` and ``uavbench sync`` go through the same check: exit 2, one line."""
    for args in (["ui", "--tracking-uri", str(tmp_path)], ["sync", "--to", str(tmp_path)]):
        proc = subprocess.run(
            [*CLI, *args], capture_output=True, text=True, cwd=tmp_path, env=_env(), timeout=300
        )
        lines = [line for line in proc.stderr.splitlines() if "INFO" not in line]
        assert proc.returncode == 2, proc.stderr
        assert len(lines) == 1 and "is a directory" in lines[0], proc.stderr


def _env() -> dict[str, str]:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(REPO)}
    env.pop("MLFLOW_TRACKING_URI", None)
    return env


OPENER = """
import json, pathlib, sys, time, warnings
from benchmark.tracking import MlflowTracker, TrackingFallbackWarning
import mlflow.tracking  # imported before the barrier: the opens, not the imports, must overlap
uri, barrier, name = sys.argv[1], pathlib.Path(sys.argv[2]), sys.argv[3]
(barrier / name).touch()
while len(list(barrier.iterdir())) < 2:  # both processes open the fresh store at once
    time.sleep(0.002)
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    tracker = MlflowTracker(uri, fallback_dir=sys.argv[4])
    with tracker.start_run("race", name) as run:
        run.log_metrics({"x": 1.0}, 0)
print(json.dumps({"fallback": tracker.using_fallback,
                  "warnings": [str(w.message)[:300] for w in caught
                               if issubclass(w.category, TrackingFallbackWarning)]}))
"""


def test_two_processes_on_a_fresh_store_both_use_mlflow(tmp_path):
    """Without the lock, MLflow's migration raced (`duplicate column name: step`) and one process
    fell back to files (2 of 3 tries here). Two rounds, each on a fresh store; both processes
    import first, meet at a barrier, then open the store together."""
    import json

    for attempt in range(2):
        db = tmp_path / f"fresh{attempt}" / "mlflow.db"
        uri = f"sqlite:///{db}"
        barrier = tmp_path / f"ready{attempt}"
        barrier.mkdir()
        procs = [
            subprocess.Popen(
                [
                    sys.executable,
                    "-c",
                    OPENER,
                    uri,
                    str(barrier),
                    f"p{i}",
                    str(tmp_path / f"fb{i}"),
                ],
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
                env=_env(),
            )
            for i in range(2)
        ]
        results = []
        for proc in procs:
            out, err = proc.communicate(timeout=600)
            assert proc.returncode == 0, err
            results.append(json.loads(out.strip().splitlines()[-1]))
        assert results == [{"fallback": False, "warnings": []}] * 2, results
        assert not any((tmp_path / f"fb{i}").exists() for i in range(2))
        from mlflow.tracking import MlflowClient

        client = MlflowClient(uri)
        runs = client.search_runs([client.get_experiment_by_name("race").experiment_id])
        assert sorted(r.info.run_name for r in runs) == ["p0", "p1"]
