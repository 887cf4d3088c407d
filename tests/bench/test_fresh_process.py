"""``run_fresh``: a library function in a spawned interpreter, with its own environment, working
directory and log, its value or its failure brought back (benchmark/bench/fresh_process.py)."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

from benchmark.bench.fresh_process import FreshProcessError, run_fresh

VAR = "UAVBENCH_FRESH_PROCESS_TEST"


# Module-level, so that the spawned interpreter can import them by name.
def where_and_what(name: str) -> tuple[int, str | None, str, bool]:
    """``(pid, os.environ[name], cwd, whether torch was imported before this call)``."""
    return os.getpid(), os.environ.get(name), os.getcwd(), "torch" in sys.modules


def talk_and_fail(message: str) -> None:
    print(f"stdout: {message}")
    print(f"stderr: {message}", file=sys.stderr)
    raise ValueError(f"bad value {message!r}")


def die(code: int) -> None:
    os._exit(code)


class TestRunFresh:
    def test_runs_in_another_interpreter_and_returns_the_value(self):
        pid, _, cwd, torch_loaded = run_fresh(where_and_what, VAR)
        assert pid != os.getpid()
        assert cwd == os.getcwd()
        # A new interpreter, not a fork: nothing this process imported is there (this test
        # module imports no torch; the pytest process has it loaded through conftest).
        assert not torch_loaded

    def test_environment_set_for_the_child_only(self, monkeypatch):
        monkeypatch.setenv("UAVBENCH_FRESH_PROCESS_GONE", "1")
        before = dict(os.environ)
        _, value, _, _ = run_fresh(where_and_what, VAR, env={VAR: "forced"})
        assert value == "forced"
        _, gone, _, _ = run_fresh(
            where_and_what, "UAVBENCH_FRESH_PROCESS_GONE", unset=("UAVBENCH_FRESH_PROCESS_GONE",)
        )
        assert gone is None
        assert dict(os.environ) == before  # restored right after each start

    def test_working_directory(self, tmp_path):
        _, _, cwd, _ = run_fresh(where_and_what, VAR, cwd=tmp_path)
        assert Path(cwd).resolve() == tmp_path.resolve()

    def test_exception_comes_back_with_the_log(self, tmp_path):
        log = tmp_path / "child.log"
        with pytest.raises(FreshProcessError) as caught:
            run_fresh(talk_and_fail, "x1", log=log)
        err = caught.value
        assert err.error == "ValueError: bad value 'x1'"
        assert "Traceback" in str(err) and "stdout: x1" in str(err)
        text = log.read_text()
        assert "stdout: x1" in text and "stderr: x1" in text
        assert "ValueError: bad value 'x1'" in text  # the traceback is in the log too

    def test_death_without_a_result(self, tmp_path):
        with pytest.raises(FreshProcessError) as caught:
            run_fresh(die, 3, log=tmp_path / "child.log")
        assert caught.value.exitcode == 3 and caught.value.error is None
        assert "exited 3 without a result" in str(caught.value)
