"""Progress: tqdm's bar rewritten in place in a terminal, one line per step in a log, always off stdout."""

import io

import pytest

from arc_env.cli.progress import Progress
from solver.errors import ArcCalibError


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_log_gets_one_line_per_step_with_the_count_and_status():
    log = io.StringIO()
    with Progress(3, "motions", stream=log) as progress:
        for joint in (1, 4, 6):
            progress.step(f"joint {joint}")
    lines = log.getvalue().splitlines()
    assert len(lines) == 3
    assert lines[0].startswith("1/3 motions, 00:00<") and lines[0].endswith(", joint 1")
    assert lines[2].startswith("3/3 motions, ") and lines[2].endswith("<00:00, joint 6")  # nothing left
    assert "\r" not in log.getvalue()


def test_a_terminal_gets_one_tqdm_bar_rewritten_in_place():
    term = _Terminal()
    progress = Progress(4, "motions", stream=term)
    progress.step("joint 2")
    progress.step("a longer status than the first")
    progress.step("short")
    out = term.getvalue()
    assert "\n" not in out and out.count("\r") >= 3  # redrawn on one line
    last = out.split("\r")[-1]
    assert "3/4" in last and "short" in last and "75%" in last
    progress.close()
    assert term.getvalue().endswith("\n") and term.getvalue().count("\n") == 1


def test_clear_erases_the_bar_before_other_output():
    term = _Terminal()
    progress = Progress(2, stream=term)
    progress.step("x")
    progress.clear()
    assert term.getvalue().split("\r")[-2].strip() == ""  # the bar's line is blanked
    progress.close()


def test_disabled_writes_nothing_but_still_counts():
    log = _Terminal()
    with Progress(2, stream=log, enabled=False) as progress:
        progress.step("x")
        progress.step("y")
    assert log.getvalue() == "" and progress.done == 2


def test_progress_goes_to_stderr_never_stdout(capsys):
    with Progress(2, "motions") as progress:
        progress.step("a")
        progress.step("b")
    captured = capsys.readouterr()
    assert captured.out == "" and "2/2 motions" in captured.err


def test_the_count_stops_at_the_total():
    progress = Progress(2, stream=io.StringIO())
    progress.step(n=5)
    assert progress.done == 2


def test_no_steps_is_an_error():
    with pytest.raises(ArcCalibError, match="at least one step"):
        Progress(0)
