"""Progress display: a dependency-free progress bar with rate and ETA (stderr) and the status
lines of long-running work (:func:`status`, stdout by default).

The bar is used by every long-running command (simulate, train, reproduce). On a terminal it
redraws in place; when stderr is a file or pipe (CI logs) it prints one line at most every
``log_every`` seconds, so logs stay short.

**Status lines.** Library code never prints: what long-running work is doing (a reproduction's
plan, a dataset written, a server's address) goes through :func:`status`, one channel that a
Python caller redirects or silences with :func:`status_to`; results are returned, and the command
layer (``benchmark/commands/``) prints them.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TextIO

StatusSink = Callable[[str], None]
_sinks: list[StatusSink | None] = []  # innermost status_to last
_sinks_lock = threading.Lock()


def _to_stdout(message: str) -> None:
    # sys.stdout looked up at each call, so a redirected stdout (pytest's capture) gets the line
    print(message, file=sys.stdout, flush=True)


def to_stderr(message: str) -> None:
    """A :func:`status_to` sink: the line on stderr, beside the progress bar (a command whose
    stdout carries its result, e.g. ``uavbench train``'s metrics)."""
    print(message, file=sys.stderr, flush=True)


def status(message: str) -> None:
    """One status line of long-running work: to the innermost :func:`status_to` sink, else to
    stdout."""
    with _sinks_lock:
        sink = _sinks[-1] if _sinks else _to_stdout
    if sink is not None:
        sink(message)


@contextmanager
def status_to(sink: StatusSink | None) -> Iterator[None]:
    """Send :func:`status` lines to ``sink`` inside the block (None: drop them)."""
    with _sinks_lock:
        _sinks.append(sink)
    try:
        yield
    finally:
        with _sinks_lock:
            _sinks.remove(sink)


def format_duration(seconds: float) -> str:
    """``3725.0 -> '1:02:05'``; unknown (inf/nan) -> ``'?'``."""
    if seconds != seconds or seconds == float("inf"):
        return "?"
    seconds = round(seconds)
    hours, rest = divmod(seconds, 3600)
    minutes, secs = divmod(rest, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes:02d}:{secs:02d}"


class Progress:
    """``with Progress(total, "render", unit="pair") as bar: bar.update(1)``.

    ``initial`` counts work already done before this process started (a resumed job); the rate and
    ETA are computed from the work done in this process only, so a resume does not look
    impossibly fast.
    """

    def __init__(
        self,
        total: int,
        desc: str = "",
        *,
        unit: str = "it",
        initial: int = 0,
        stream: TextIO | None = None,
        log_every: float = 10.0,
        enabled: bool = True,
    ) -> None:
        self.total = int(total)
        self.desc = desc
        self.unit = unit
        self.count = int(initial)
        self._initial = int(initial)
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled
        self._tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._log_every = log_every if not self._tty else 0.2
        self._start = time.monotonic()
        self._last_draw = -float("inf")
        self.postfix = ""

    def __enter__(self) -> Progress:
        self._draw(force=True)
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def rate(self) -> float:
        elapsed = time.monotonic() - self._start
        done = self.count - self._initial
        return done / elapsed if elapsed > 0 else 0.0

    def update(self, n: int = 1, postfix: str | None = None) -> None:
        self.count += n
        if postfix is not None:
            self.postfix = postfix
        self._draw()

    def status(self, text: str) -> None:
        """Say what is being done now (the postfix) and draw at once, whatever ``log_every``:
        for steps long enough that a silent bar would look stuck (a Table 6 measurement)."""
        self.postfix = text
        self._draw(force=True)

    def line(self) -> str:
        elapsed = time.monotonic() - self._start
        rate = self.rate
        remaining = (self.total - self.count) / rate if rate > 0 else float("inf")
        frac = self.count / self.total if self.total else 1.0
        width = 24
        filled = round(width * min(max(frac, 0.0), 1.0))
        bar = "#" * filled + "-" * (width - filled)
        text = (
            f"{self.desc} [{bar}] {self.count}/{self.total} {100 * frac:5.1f}% "
            f"{rate:.2f} {self.unit}/s elapsed {format_duration(elapsed)} "
            f"ETA {format_duration(remaining)}"
        )
        return f"{text} {self.postfix}".rstrip()

    def _draw(self, force: bool = False) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if not force and now - self._last_draw < self._log_every and self.count < self.total:
            return
        self._last_draw = now
        self._drawn = (self.count, self.postfix)
        if self._tty:
            self.stream.write("\r" + self.line() + "\x1b[K")
        else:
            self.stream.write(self.line() + "\n")
        self.stream.flush()

    def close(self) -> None:
        if not self.enabled:
            return
        if getattr(self, "_drawn", None) != (self.count, self.postfix):
            self._draw(force=True)  # the final state, unless it is already on screen
        if self._tty:
            self.stream.write("\n")
            self.stream.flush()
