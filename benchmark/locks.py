"""One writer per work directory: an exclusive lock file naming its holder (pid, host, start).

    with work_lock(out / ".simulate.lock", what="uavbench simulate", wait=True, notify=print):
        ...  # only one process at a time gets here for this path

    try:  # a command that refuses instead of waiting: exit 2 naming the holder
        with work_lock(workdir / ".reproduce.lock", what="uavbench reproduce"):
            ...
    except LockBusyError as err:
        raise InputError(str(err)) from None

The lock is an ``fcntl.flock`` on the lock file, so the kernel releases it when its holder exits,
however it exits (kill -9 included): a lock left by a dead process is free and is taken over at
once, with a note naming the dead holder. The file's content (JSON ``pid``, ``host``,
``started`` (Unix time, seconds), ``what``) only *describes* the holder, for the message a second
invocation prints; it never decides who holds the lock. A second invocation either waits
(``wait=True``: it says so once through ``notify``, then polls every ``poll_s`` seconds) or raises
:class:`LockBusyError`, whose message names the holder and what to do.

On NFS, Linux maps ``flock`` onto POSIX byte-range locks, which the server arbitrates between hosts.
A filesystem without locks raises :class:`LockBusyError` with the reason rather than run unlocked.

Releasing unlinks the file while still holding the lock; a process that opened the old file before
the unlink and then acquires the lock sees that the path no longer names the file it locked and
starts again (the classic unlink race of lock files).

Why not ``filelock`` (installed with torch, any version): it keeps no holder record (the message
of a second invocation names pid, host and start, and a dead holder's lock is reported as taken
over), and its lock file is its own: a record written into it goes around its API, and filelock
3.x opens it with ``O_TRUNC`` on every attempt, so a waiting process would erase the holder's
record. Its lock is also re-entrant in a process (ours refuses a second take, which would be our
bug), and 4.x may fall back to a soft lock on a filesystem without ``flock``, where this module
refuses to run unlocked. It would save ``_try_lock``'s ~25 lines.

Imports nothing of ours (a leaf like ``benchmark.errors``), so every layer may use it.
"""

from __future__ import annotations

import errno
import fcntl
import json
import os
import socket
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class LockHolder:
    """Who holds (or held) a lock: process id, host name, start (Unix seconds), what it does."""

    pid: int
    host: str
    started: float
    what: str

    def describe(self) -> str:
        when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(self.started))
        return f"pid {self.pid} on {self.host} ({self.what}, since {when})"

    def alive(self) -> bool | None:
        """True/False for a process on this host; None (unknown) for another host's."""
        if self.host != socket.gethostname():
            return None
        try:
            os.kill(self.pid, 0)
        except ProcessLookupError:
            return False
        except PermissionError:  # exists, owned by another user
            return True
        return True


class LockBusyError(RuntimeError):
    """Another process holds the lock (``holder`` if its file could be read), or the filesystem
    cannot lock. The message names the lock file, the holder and what to do."""

    def __init__(self, message: str, path: Path, holder: LockHolder | None) -> None:
        super().__init__(message)
        self.path = path
        self.holder = holder


def read_holder(path: Path) -> LockHolder | None:
    """The holder described in lock file ``path``, or None (absent, empty or unreadable)."""
    try:
        data = json.loads(Path(path).read_text())
        return LockHolder(int(data["pid"]), str(data["host"]), float(data["started"]), data["what"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _try_lock(path: Path) -> int | None:
    """An fd holding the exclusive lock on the file now at ``path``, or None if it is held."""
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            return None
        except OSError as err:
            os.close(fd)
            if err.errno in (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS):
                raise LockBusyError(
                    f"cannot lock {path}: the filesystem does not support locks ({err.strerror}); "
                    f"put the work directory on a local disk",
                    path,
                    None,
                ) from err
            raise
        try:
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if same:
            return fd
        os.close(fd)  # the holder unlinked the file between our open and our lock: start again


def _busy_message(path: Path, holder: LockHolder | None, what: str) -> str:
    who = holder.describe() if holder is not None else "another process"
    hint = "wait for it to finish or stop it"
    if holder is not None and holder.alive() is False:  # flock held though the pid is gone
        hint = "its pid is gone yet the lock is held (a child process of it?); stop that process"
    elif holder is not None and holder.alive() is None:
        hint += f" on {holder.host}"
    return f"{path.parent} is locked by {who}; {hint}, then rerun {what}"


@contextmanager
def work_lock(
    path: str | Path,
    *,
    what: str,
    wait: bool = False,
    poll_s: float = 1.0,
    timeout_s: float | None = None,
    notify: Callable[[str], None] | None = None,
) -> Iterator[LockHolder]:
    """Hold the exclusive lock ``path`` for the ``with`` block; yields this process's holder.

    ``what`` describes the work ("uavbench simulate", "reproduce"), shown to other invocations.
    ``wait=False``: raise :class:`LockBusyError` at once if another process holds it. ``wait=True``:
    report once through ``notify`` and poll every ``poll_s`` s, up to ``timeout_s`` (None:
    forever; then LockBusyError). A lock file left by a dead process is taken over (``notify`` says
    whose). The lock is not re-entrant: taking it twice in one process raises LockBusyError.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    say = notify or (lambda _msg: None)
    start = time.monotonic()
    waiting = False
    while (fd := _try_lock(path)) is None:
        holder = read_holder(path)
        if not wait or (timeout_s is not None and time.monotonic() - start >= timeout_s):
            raise LockBusyError(_busy_message(path, holder, what), path, holder)
        if not waiting:
            who = holder.describe() if holder is not None else "another process"
            say(f"waiting for {path.parent}: locked by {who} (Ctrl-C to stop)")
            waiting = True
        time.sleep(poll_s)
    try:
        previous = read_holder(path)
        if previous is not None and previous.pid != os.getpid():
            say(f"took over the stale lock {path} of {previous.describe()}, which has ended")
        me = LockHolder(os.getpid(), socket.gethostname(), time.time(), what)
        text = json.dumps(me.__dict__, sort_keys=True) + "\n"
        os.ftruncate(fd, 0)
        os.pwrite(fd, text.encode(), 0)
        yield me
    finally:
        try:
            os.unlink(path)  # still holding the lock: see the module docstring
        except OSError:
            pass
        os.close(fd)
