"""Run a library function in a fresh interpreter: what a bench needs when the environment must be
in place before any library is imported (a forced instruction set, one thread per process) or
when it times work as a user starts it (imports and start-up included).

A spawned process (``multiprocessing``'s ``spawn`` context: a new interpreter, not a fork of
this one) runs ``fn(*args)``; ``fn`` and ``args`` must pickle (a module-level function, frozen
configs). The child's environment is this process's with ``env`` set and ``unset`` removed,
applied to ``os.environ`` just for the start (a spawned interpreter copies the environment when
it starts) and restored right after. Its stdout and stderr go to ``log`` (else they stay this
process's). Its return value comes back through a pipe; an exception in it, or a death without
one, raises :class:`FreshProcessError` with the child's traceback or exit code and the last
lines of ``log``.

No command line is launched: the child runs the library function the command would call, so a
bench never depends on flag names (issue 41).
"""

from __future__ import annotations

import multiprocessing
import os
import sys
import threading
import traceback
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, TypeVar

T = TypeVar("T")

_LOG_TAIL = 15  # lines of the child's log quoted in an error
# One start at a time: os.environ is process-wide, so two threads starting children with
# different environments would see each other's.
_ENV_LOCK = threading.Lock()


class FreshProcessError(RuntimeError):
    """The child raised or died: ``error`` its exception's last traceback line (None if it died
    without one), ``exitcode`` its exit code; the message holds the whole traceback (or the
    exit code) and the log's tail."""

    def __init__(self, message: str, error: str | None, exitcode: int | None) -> None:
        super().__init__(message)
        self.error = error
        self.exitcode = exitcode


def _child(
    conn: Any, fn: Callable[..., Any], args: tuple, cwd: str | None, log: str | None
) -> None:
    """The spawned process: point stdout/stderr at ``log``, move to ``cwd``, run, report."""
    if log is not None:
        fd = os.open(log, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
        for stream in (1, 2):
            os.dup2(fd, stream)
        os.close(fd)
    if cwd is not None:
        os.chdir(cwd)
    try:
        result = fn(*args)
    except BaseException:  # SystemExit and KeyboardInterrupt too: the parent must hear of it
        text = traceback.format_exc()
        sys.stderr.write(text)  # the child's stderr is the log: where a user looks first
        sys.stderr.flush()
        conn.send(("error", text))
    else:
        conn.send(("ok", result))
    finally:
        conn.close()


def _log_tail(log: Path | None) -> str:
    if log is None or not log.is_file():
        return ""
    lines = log.read_text(errors="replace").splitlines()[-_LOG_TAIL:]
    return f"\nlast lines of {log}:\n" + "\n".join(f"  {line}" for line in lines)


def run_fresh(
    fn: Callable[..., T],
    *args: Any,
    env: Mapping[str, str] | None = None,
    unset: tuple[str, ...] = (),
    cwd: Path | None = None,
    log: Path | None = None,
) -> T:
    """``fn(*args)`` in a spawned interpreter under this environment plus ``env`` minus
    ``unset``, in ``cwd``, its output appended to ``log``; returns its value.

    FreshProcessError if it raises or dies (its traceback or exit code, and the log's tail)."""
    context = multiprocessing.get_context("spawn")
    receive, send = context.Pipe(duplex=False)
    child = context.Process(
        target=_child,
        args=(send, fn, args, None if cwd is None else str(cwd), None if log is None else str(log)),
        daemon=False,  # it may start processes of its own (a reproduction's worker pool)
    )
    with _ENV_LOCK:
        saved = dict(os.environ)
        try:
            os.environ.update(env or {})
            for name in unset:
                os.environ.pop(name, None)
            child.start()
        finally:
            os.environ.clear()
            os.environ.update(saved)
    send.close()  # the child holds the only writer: its death ends recv() with EOFError
    try:
        status, value = receive.recv()
    except EOFError:
        status, value = "died", None
    finally:
        receive.close()
        child.join()
    name = getattr(fn, "__qualname__", repr(fn))
    if status == "error":
        last = value.strip().splitlines()[-1] if value.strip() else "(no message)"
        raise FreshProcessError(
            f"{name} failed in a fresh process:\n{value}{_log_tail(log)}", last, child.exitcode
        )
    if status == "died" or child.exitcode != 0:
        raise FreshProcessError(
            f"{name}: the fresh process exited {child.exitcode} without a result{_log_tail(log)}",
            None,
            child.exitcode,
        )
    return value
