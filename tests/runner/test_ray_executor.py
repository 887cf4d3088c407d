"""``reproduce --executor ray`` (benchmark/runner/execute/ray_executor.py): the same numbers as
the process pool, a killed worker retried or reported, the dataset check on the node, the tracking
guard and the message without ray. A local Ray with 2 CPUs stands in for a cluster."""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import json
import os
import platform
import re
import sys
from pathlib import Path

import pandas as pd
import pytest
from interrupt_tools import ctrl_c_while_training

from benchmark.cli import main
from benchmark.commands import reproduce as reproduce_command
from benchmark.errors import InputError
from benchmark.runner import ReproduceConfig
from benchmark.runner.execute.pool import ExecutorConfig, check_executor
from benchmark.runner.execute.ray_executor import (
    INSTALL_LINE,
    check_dataset_on_node,
    check_ray_tracking,
    connect_ray,
    execute_units_ray,
    import_ray,
    is_local_address,
    is_node_local_uri,
    ray_unit,
)
from benchmark.runner.reproduction import planned_tracking_uri

HAVE_RAY = importlib.util.find_spec("ray") is not None
needs_ray = pytest.mark.skipif(
    not HAVE_RAY, reason='ray is not installed (pip install -e ".[ray]")'
)
TABLE = "table3"  # four units: Pd/Re-Net, Re-Net-T, the Laplace head and the UAV-only control
# Columns that are measurements of time or where the files are, not results.
TIME_SUFFIXES = ("seconds", "_s", "_ms")
NOT_NUMBERS = {"run_id", "training_run_id", "model_uri", "started", "ended"}


def has_executor_flag() -> bool:
    parser = argparse.ArgumentParser()
    reproduce_command.add_arguments(parser)
    return any("--executor" in action.option_strings for action in parser._actions)


def reproduce(tmp: Path, dataset: Path, *extra: str) -> int:
    return main([
        "reproduce", "--profile", "smoke", "--only", TABLE, "--data", str(dataset),
        "--out", str(tmp / "reports"), "--workdir", str(tmp / "runs"), "--tracker", "local",
        "--quiet", "--no-models", "--workers", "2", *extra,
    ])  # fmt: skip


def run_in(tmp: Path, dataset: Path, *extra: str) -> int:
    previous = os.getcwd()
    os.chdir(tmp)  # the tracking store lives in the working directory
    try:
        return reproduce(tmp, dataset, *extra)
    finally:
        os.chdir(previous)


@pytest.fixture(scope="module")
def pool_run(tmp_path_factory, smoke_dataset):
    tmp = tmp_path_factory.mktemp("pool")
    return tmp, run_in(tmp, smoke_dataset)


@pytest.fixture(scope="module")
def ray_run(tmp_path_factory, smoke_dataset):
    """The same reproduction through a local Ray (2 CPUs) that the executor starts and stops."""
    tmp = tmp_path_factory.mktemp("ray")
    return tmp, run_in(tmp, smoke_dataset, "--executor", "ray")


def numbers(tmp: Path) -> pd.DataFrame:
    frame = pd.read_csv(tmp / "reports" / "results.csv")
    keep = [c for c in frame.columns if not c.endswith(TIME_SUFFIXES) and c not in NOT_NUMBERS]
    keys = ["table", "label", "split", "satellite", "seed"]
    return frame[keep].sort_values(keys).reset_index(drop=True)


@needs_ray
class TestReproduceThroughRay:
    def test_results_csv_numbers_equal_the_process_pool(self, pool_run, ray_run):
        (pool_tmp, pool_code), (ray_tmp, ray_code) = pool_run, ray_run
        assert pool_code == 0 and ray_code == 0
        pool, ray = numbers(pool_tmp), numbers(ray_tmp)
        assert len(pool) > 0 and "dphi_deg" in pool.columns
        assert pool["dphi_deg"].notna().any()
        pd.testing.assert_frame_equal(pool, ray)  # every number, to the last bit

    def test_same_unit_files_and_one_finished_training_run_per_unit(self, pool_run, ray_run):
        pool_units = {p.name for p in (pool_run[0] / "runs" / "units").iterdir()}
        ray_units = {p.name for p in (ray_run[0] / "runs" / "units").iterdir()}
        assert pool_units == ray_units and len(ray_units) == 4
        for key in ray_units:
            names = {p.name for p in (ray_run[0] / "runs" / "units" / key / "eval").iterdir()}
            pool_names = {p.name for p in (pool_run[0] / "runs" / "units" / key / "eval").iterdir()}
            assert names == pool_names
            assert (ray_run[0] / "runs" / "units" / key / "train" / "checkpoint.pt").is_file()
        # Logged live by the Ray workers into the driver's store (they work in its directory)
        training = ray_run[0] / "tracking-local" / "uavbench-smoke_training"
        runs = [json.loads(p.read_text()) for p in training.glob("*/run.json")]
        assert len(runs) == 4 and {r["status"] for r in runs} == {"FINISHED"}

    def test_reproduce_has_the_executor_flag(self):
        if not has_executor_flag():
            pytest.skip("needs integration: reproduce.add_arguments has no --executor yet")
        parser = argparse.ArgumentParser()
        reproduce_command.add_arguments(parser)
        args = parser.parse_args(["--executor", "ray", "--gpus-per-unit", "0.5"])
        assert args.executor == "ray" and args.gpus_per_unit == 0.5


# ----------------------------------------------------------------------------- failures on workers
@pytest.fixture(scope="module")
def shared_ray():
    """One local Ray (2 CPUs) for the failure tests; the executor uses a Ray it finds running."""
    if not HAVE_RAY:
        pytest.skip("ray is not installed")
    import ray

    assert connect_ray(None, num_cpus=2)
    yield ray
    ray.shutdown()


@pytest.fixture(scope="module")
def planned(smoke_dataset):
    """The table's units, planned as ``reproduce`` plans them (no tracking)."""
    from benchmark.data import list_splits
    from benchmark.runner.plan.repro_profiles import get_repro_profile
    from benchmark.runner.plan.specs import load_specs
    from benchmark.runner.plan.units import plan_units
    from benchmark.tracking import manifest_sha256

    specs = load_specs(None, [TABLE])
    profile = get_repro_profile("smoke")
    manifest = manifest_sha256(smoke_dataset)
    return plan_units(specs, profile, [0], smoke_dataset, list_splits(smoke_dataset), manifest)


def make_todo(units, workdir: Path):
    from benchmark.runner.execute.worker import UnitTask

    return [(u, UnitTask(u.key, u.cfg, u.eval_splits, workdir / "units" / u.key)) for u in units]


def killed_once(victim: str, markers: Path):
    """A task function that SIGKILLs its own worker process mid-unit (when the first training
    epoch of the unit ``victim`` ends, before its evaluation) on the first attempt, and runs
    everything else as it is. A marker file records each attempt of ``victim``."""

    def task(task, digest, cwd):  # a closure: Ray ships it by value to the workers
        if task.key == victim:
            attempt = len(list(markers.glob("attempt-*"))) + 1
            (markers / f"attempt-{attempt}").write_text(str(os.getpid()))
            if attempt == 1:
                import signal

                import benchmark.runner.execute.worker as execute

                train_and_evaluate = execute.train_and_evaluate

                def dying(*args, **kwargs):  # this process dies in it: no need to restore
                    def on_epoch_end(epoch, record):
                        os.kill(os.getpid(), signal.SIGKILL)

                    return train_and_evaluate(*args, **{**kwargs, "on_epoch_end": on_epoch_end})

                execute.train_and_evaluate = dying
        return ray_unit(task, digest, cwd)

    return task


def run_todo(todo, **kwargs) -> dict:
    results = {}
    execute_units_ray(todo, lambda unit, result: results.__setitem__(unit.key, result), True,
                      **kwargs)  # fmt: skip
    return results


@needs_ray
class TestWorkerKilled:
    def test_retried_and_gives_the_pool_numbers(self, shared_ray, planned, pool_run, tmp_path):
        victim, other = planned[0], planned[2]  # Pd/Re-Net (killed) and the UAV-only control
        markers = tmp_path / "markers"
        markers.mkdir()
        todo = make_todo([victim, other], tmp_path / "runs")
        results = run_todo(todo, max_retries=1, task_fn=killed_once(victim.key, markers))
        assert len(list(markers.glob("attempt-*"))) == 2  # killed once, run again
        pids = {p.read_text() for p in markers.glob("attempt-*")}
        assert len(pids) == 2  # a fresh worker process for the retry
        assert results[victim.key].ok and results[other.key].ok, results
        # The retried unit's numbers are those the process pool's reproduction computed for it.
        for split in ("standard/test", "standard/val"):
            name = split.replace("/", "__") + ".json"
            pool = json.loads((pool_run[0] / "runs" / "units" / victim.key / "eval" / name)
                              .read_text())  # fmt: skip
            got = results[victim.key].metrics[split]
            assert got["dphi_deg"] == pool["dphi_deg"] and got["dE_m"] == pool["dE_m"], split

    def test_without_retries_reported_failed_and_the_others_finish(
        self, shared_ray, planned, tmp_path
    ):
        victim, other = planned[0], planned[2]
        markers = tmp_path / "markers"
        markers.mkdir()
        todo = make_todo([victim, other], tmp_path / "runs")
        results = run_todo(todo, max_retries=0, task_fn=killed_once(victim.key, markers))
        assert len(list(markers.glob("attempt-*"))) == 1
        failed = results[victim.key]
        assert not failed.ok and failed.error.startswith("worker died on each of 1 attempt(s)")
        assert "max_retries 0" in failed.error and failed.metrics == {}
        assert results[other.key].ok and results[other.key].metrics["standard/test"]


@needs_ray
@pytest.mark.skipif(not has_executor_flag(), reason="needs integration (reproduce --executor)")
class TestCtrlC:
    def test_one_message_runs_killed_local_ray_stopped(self, tmp_path, smoke_dataset):
        """SIGINT to the process group (a terminal's Ctrl-C) while a Ray worker trains: exit 130,
        one message and no traceback, no run left RUNNING, no process of the local Ray left."""
        import time

        import psutil

        proc, out = ctrl_c_while_training(
            tmp_path, smoke_dataset, "--only", TABLE, "--executor", "ray",
            open_timeout_s=300, exit_timeout_s=120,
        )  # fmt: skip
        training = tmp_path / "tracking-local" / "uavbench-smoke_training"
        assert proc.returncode == 130, out
        assert "Traceback" not in out and "KeyboardInterrupt" not in out, out
        assert out.count("interrupted: finished runs are kept") == 1, out
        statuses = [json.loads(p.read_text())["status"] for p in training.glob("*/run.json")]
        assert "RUNNING" not in statuses and "KILLED" in statuses, statuses
        time.sleep(2)  # ray.shutdown() has signalled its processes; give them a moment
        # A local Ray's session directory ends in the driver's pid; its processes name it.
        session = re.compile(rf"session_[0-9_-]+_{proc.pid}(/|$)")
        left = [
            p.info["cmdline"] for p in psutil.process_iter(["cmdline"])
            if any(session.search(arg) for arg in p.info["cmdline"] or [])
        ]  # fmt: skip
        assert not left, left


# ----------------------------------------------------------------------------- the data on the node
class TestDatasetCheckOnNode:
    def test_the_same_dataset_passes(self, smoke_dataset):
        from benchmark.tracking import manifest_sha256

        assert check_dataset_on_node(smoke_dataset, manifest_sha256(smoke_dataset)) == ""

    def test_missing_directory_names_path_host_and_shared_file_system(self, tmp_path):
        message = check_dataset_on_node(tmp_path / "nowhere", "0" * 64)
        assert message.startswith(f"dataset {tmp_path / 'nowhere'} not readable on node ")
        assert platform.node() in message and "shared file system" in message

    def test_another_dataset_at_the_path_is_refused(self, smoke_dataset):
        message = check_dataset_on_node(smoke_dataset, "0" * 64)
        assert "is not the driver's" in message and "expected 0000000000000000" in message

    @needs_ray
    def test_on_a_worker_the_unit_fails_with_the_reason(self, shared_ray, planned, tmp_path):
        """A node that sees other data at the path (here: one task is told another digest) fails
        that unit, untrained, and the other unit finishes."""
        import dataclasses

        victim = planned[2]  # the UAV-only control: the cheapest unit
        twin = dataclasses.replace(victim, key="twin")  # the same model under another key

        def other_node(task, digest, cwd):
            return ray_unit(task, "f" * 64 if task.key == victim.key else digest, cwd)

        results = run_todo(make_todo([victim, twin], tmp_path / "runs"), task_fn=other_node)
        error = results[victim.key].error
        assert not results[victim.key].ok and "is not the driver's" in error
        assert f"on node {platform.node()}" in error and "shared file system" in error
        assert not (tmp_path / "runs" / "units" / victim.key).exists()  # nothing trained
        assert results["twin"].ok and results["twin"].metrics["standard/test"]


# ----------------------------------------------------------------------------- guards
class TestTrackingGuard:
    @pytest.mark.parametrize(
        "uri", ["sqlite:///mlflow.db", "sqlite:////abs/mlflow.db", "file:///tmp/mlruns", "mlruns",
                "/abs/tracking-local"],
    )  # fmt: skip
    def test_file_store_with_a_cluster_is_refused_saying_why_and_the_fix(self, uri):
        with pytest.raises(InputError) as err:
            check_ray_tracking("10.0.0.5:6379", uri)
        text = str(err.value)
        assert uri in text and "10.0.0.5:6379" in text
        assert "lost" in text and "node" in text  # why
        assert "http://<that host>:5000" in text and "MLflow server" in text  # the fix
        assert "tracker null" in text  # or track nothing

    @pytest.mark.parametrize("address", [None, "local", "127.0.0.1:6379", "localhost",
                                         "ray://127.0.0.1:10001", "[::1]:6379"])  # fmt: skip
    def test_local_ray_may_use_the_sqlite_file(self, address):
        assert is_local_address(address)
        check_ray_tracking(address, "sqlite:///mlflow.db")  # no error

    @pytest.mark.parametrize("uri", ["http://head:5000", "https://mlflow.example.org", None, ""])
    def test_a_server_or_nothing_tracked_passes_with_a_cluster(self, uri):
        check_ray_tracking("ray://10.0.0.5:10001", uri)

    def test_classification(self):
        assert not is_local_address("auto") and not is_local_address("head.cluster:6379")
        assert is_node_local_uri("sqlite:///x.db") and is_node_local_uri("relative/dir")
        assert not is_node_local_uri("postgresql://db/mlflow")

    def test_ray_only_flags_need_the_ray_executor(self):
        parser = argparse.ArgumentParser()
        reproduce_command.add_executor_arguments(parser)
        args = parser.parse_args(["--ray-address", "10.0.0.5:6379"])
        args.workers = 2
        with pytest.raises(InputError, match="executor ray_address only apply to kind 'ray'"):
            check_executor(reproduce_command.executor_config(args), None)

    @needs_ray
    def test_check_executor_resolves_the_default_store(self, monkeypatch):
        parser = argparse.ArgumentParser()
        reproduce_command.add_arguments(parser)
        args = parser.parse_args(["--executor", "ray", "--ray-address", "10.0.0.5:6379"])
        config = reproduce_command.config_from(args)
        monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
        planned = planned_tracking_uri(config.tracker, config.tracking_uri)
        with pytest.raises(InputError, match=r"sqlite:///mlflow\.db"):
            check_executor(config.executor, planned)
        check_executor(config.executor, planned_tracking_uri("null", None))  # nothing tracked
        bad = dataclasses.replace(config.executor, gpus_per_unit=-1.0)
        with pytest.raises(InputError, match=r"executor\.gpus_per_unit must be >= 0"):
            check_executor(bad, None)

    def test_the_flags_become_the_frozen_config(self):
        parser = argparse.ArgumentParser()
        reproduce_command.add_arguments(parser)
        args = parser.parse_args(
            [
                "--only",
                "table1, fig7",
                "--workers",
                "3",
                "--no-models",
                "--no-wait",
                "--executor",
                "ray",
                "--max-retries",
                "0",
            ]
        )
        config = reproduce_command.config_from(args)
        assert config.only == ("table1", "fig7") and not config.log_models and not config.wait
        assert config.executor == ExecutorConfig(kind="ray", workers=3, max_retries=0)
        assert config == dataclasses.replace(
            ReproduceConfig(),
            only=config.only,
            log_models=False,
            wait=False,
            executor=config.executor,
        )  # every other field: the library's default is the flag's

    @pytest.mark.parametrize("command", [["reproduce"], ["bench", "ray"]])
    @pytest.mark.parametrize("old", [["--jobs", "2"], ["--jobs=2"], ["--jobs"]])
    def test_the_old_jobs_flag_names_workers_in_one_line(self, command, old, capsys):
        with pytest.raises(SystemExit) as exit_:
            main([*command, *old])
        assert exit_.value.code == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "--jobs is now --workers" in err
        assert "processes" in err and "table rows" in err
        assert "unrecognized" not in err

    @pytest.mark.skipif(not has_executor_flag(), reason="needs integration (reproduce --executor)")
    def test_cli_exits_2_before_any_work(self, tmp_path, capsys):
        code = main([
            "reproduce", "--profile", "smoke", "--executor", "ray", "--ray-address",
            "10.0.0.5:6379", "--precision", "fp32", "--tracking-uri", "sqlite:///mlflow.db",
            "--data", str(tmp_path / "never-rendered"), "--workdir", str(tmp_path / "runs"),
        ])  # fmt: skip
        assert code == 2
        assert "track to http://<that host>:5000" in capsys.readouterr().err
        assert not (tmp_path / "never-rendered").exists()


class TestWithoutRay:
    @pytest.fixture
    def no_ray(self, monkeypatch):
        monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` now raises ImportError

    def test_import_names_the_install_line(self, no_ray):
        with pytest.raises(InputError) as err:
            import_ray()
        assert INSTALL_LINE in str(err.value) and "the Ray executor" in str(err.value)

    def test_executor_refuses_before_doing_anything(self, no_ray):
        with pytest.raises(InputError, match=r"pip install -e \"\.\[ray\]\""):
            execute_units_ray([], lambda *_: None, True)

    @pytest.mark.skipif(not has_executor_flag(), reason="needs integration (reproduce --executor)")
    def test_cli_exits_2_with_the_install_line(self, no_ray, tmp_path, capsys):
        code = main([
            "reproduce", "--profile", "smoke", "--executor", "ray", "--data",
            str(tmp_path / "never-rendered"), "--workdir", str(tmp_path / "runs"),
        ])  # fmt: skip
        assert code == 2 and INSTALL_LINE in capsys.readouterr().err
