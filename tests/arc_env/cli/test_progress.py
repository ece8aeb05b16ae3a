"""Progress: a bar rewritten in place in a terminal, one line per step in a log."""

import io

import pytest

from arc_env.cli.progress import BAR_WIDTH, Progress, _clock
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
    assert lines[0].startswith("1/3 motions, ") and lines[0].endswith(": joint 1")
    assert "left" in lines[1]  # an estimate of the time left while steps remain
    assert lines[2].startswith("3/3 motions, ") and "left" not in lines[2]
    assert "\r" not in log.getvalue()


def test_a_terminal_gets_one_bar_rewritten_in_place():
    term = _Terminal()
    progress = Progress(4, "motions", stream=term)
    progress.step("joint 2")
    progress.step("a longer status than the first")
    progress.step("short")  # padded so that no text of the longer line is left behind
    out = term.getvalue()
    assert out.count("\r") == 3 and "\n" not in out
    drawn = out.split("\r")
    assert drawn[3].startswith("[" + "#" * (BAR_WIDTH * 3 // 4) + ".")
    assert len(drawn[3]) >= len(drawn[2])
    progress.close()
    assert term.getvalue().endswith("\n") and term.getvalue().count("\n") == 1


def test_clear_erases_the_bar_before_other_output():
    term = _Terminal()
    progress = Progress(2, stream=term)
    progress.step()
    progress.clear()
    last = term.getvalue().split("\r")[-2]
    assert last.strip() == "" and term.getvalue().endswith("\r")
    progress.close()  # nothing drawn: no empty line
    assert "\n" not in term.getvalue()


def test_disabled_writes_nothing_but_still_counts():
    log = _Terminal()
    with Progress(2, stream=log, enabled=False) as progress:
        progress.step("x")
        progress.step("y")
    assert log.getvalue() == "" and progress.done == 2


def test_the_count_stops_at_the_total():
    progress = Progress(2, stream=io.StringIO())
    progress.step(n=5)
    assert progress.done == 2


def test_no_steps_is_an_error():
    with pytest.raises(ArcCalibError, match="at least one step"):
        Progress(0)


@pytest.mark.parametrize(("seconds", "text"), [(4.4, "4 s"), (59.4, "59 s"), (185, "3:05"), (3729, "1:02:09")])
def test_clock(seconds, text):
    assert _clock(seconds) == text
