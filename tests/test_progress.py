"""``benchmark.progress``: the bar's lines, rate, ETA and log-friendly output, on a fake clock."""

from __future__ import annotations

import io

import pytest

import benchmark.progress as progress
from benchmark.progress import Progress, format_duration


class Clock:
    """Stands in for the ``time`` module inside ``benchmark.progress``."""

    def __init__(self) -> None:
        self.now = 100.0

    def monotonic(self) -> float:
        return self.now


class Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


@pytest.fixture
def clock(monkeypatch):
    fake = Clock()
    monkeypatch.setattr(progress, "time", fake)
    return fake


class TestFormatDuration:
    @pytest.mark.parametrize(
        ("seconds", "text"),
        [(0, "00:00"), (59.4, "00:59"), (61, "01:01"), (3725.0, "1:02:05"),
         (float("inf"), "?"), (float("nan"), "?")],
    )  # fmt: skip
    def test_values(self, seconds, text):
        assert format_duration(seconds) == text


class TestLine:
    def test_rate_and_eta_from_this_process_only(self, clock):
        bar = Progress(10, "train", unit="epoch", initial=4, stream=io.StringIO())
        clock.now += 20.0
        bar.update(2)  # 2 epochs in 20 s here (4 were done before a resume)
        line = bar.line()
        assert "6/10" in line and " 60.0%" in line
        assert "0.10 epoch/s" in line  # not (6 / 20)
        assert "elapsed 00:20" in line and "ETA 00:40" in line  # 4 left at 0.1/s

    def test_bar_width(self, clock):
        bar = Progress(4, "x", stream=io.StringIO())
        bar.update(1)
        assert "[######------------------]" in bar.line()  # 24 cells, a quarter filled


class TestLogOutput:
    def test_non_terminal_one_line_per_interval(self, clock):
        stream = io.StringIO()
        with Progress(100, "render", stream=stream, log_every=10.0) as bar:
            for _ in range(30):
                clock.now += 1.0
                bar.update(1)
        lines = stream.getvalue().splitlines()
        assert "\r" not in stream.getvalue()
        # the opening line, one per 10 s (at 10, 20, 30 s), and the final state
        assert [x.split()[2] for x in lines] == ["0/100", "10/100", "20/100", "30/100"]

    def test_final_state_not_repeated(self, clock):
        stream = io.StringIO()
        with Progress(2, "x", stream=stream) as bar:
            bar.update(2)  # the end is always drawn
        assert [x.split()[2] for x in stream.getvalue().splitlines()] == ["0/2", "2/2"]

    def test_status_draws_at_once(self, clock):
        stream = io.StringIO()
        bar = Progress(4, "report", stream=stream, log_every=10.0)
        bar.update(0, postfix="writing table1")  # the first line
        clock.now += 1.0
        bar.update(1, postfix="writing table2")  # within the interval: not drawn
        assert len(stream.getvalue().splitlines()) == 1
        bar.status("table6: Re-Net (1/4)")
        bar.status("table6: Re-Net (2/4)")
        lines = stream.getvalue().splitlines()[1:]
        assert [x.rsplit(" ", 2)[-2:] for x in lines] == [["Re-Net", "(1/4)"], ["Re-Net", "(2/4)"]]
        assert "1/4" in lines[0]

    def test_disabled_writes_nothing(self, clock):
        stream = io.StringIO()
        with Progress(3, "x", stream=stream, enabled=False) as bar:
            bar.update(3)
            bar.status("busy")
        assert stream.getvalue() == ""


class TestTerminal:
    def test_redraws_in_place_and_ends_the_line(self, clock):
        stream = Tty()
        with Progress(3, "x", stream=stream) as bar:
            for _ in range(3):
                clock.now += 1.0
                bar.update(1)
        text = stream.getvalue()
        assert text.count("\n") == 1 and text.endswith("\n")
        assert text.count("\r") == 4 and "\x1b[K" in text  # opening + 3 updates, line cleared
        assert "3/3" in text.rsplit("\r", 1)[1]
