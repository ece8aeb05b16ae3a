"""Progress of long work (recording, calibrating, episodes) on the terminal.

In a terminal the progress is one bar, rewritten in place; in a log, a pipe or CI it is one line
per step, so that the log keeps every step. Either way it goes to stderr by default, leaving stdout
to results.
"""

from __future__ import annotations

import shutil
import sys
import time
from typing import TextIO

from solver.errors import InvalidInputError

#: Characters of the bar itself.
BAR_WIDTH = 24


def _clock(seconds: float) -> str:
    """``seconds`` as ``42 s``, ``3:05`` or ``1:02:09``."""
    s = int(round(seconds))
    if s < 60:
        return f"{s} s"
    h, rest = divmod(s, 3600)
    return f"{h}:{rest // 60:02d}:{rest % 60:02d}" if h else f"{rest // 60}:{rest % 60:02d}"


class Progress:
    """A count of ``total`` steps with elapsed time, an estimate of the time left and a status.

    Use as a context manager, or call ``close`` at the end (it ends the bar's line)::

        with Progress(len(motions), "motions") as progress:
            for m in motions:
                ...
                progress.step(f"joint {m.joint}: 40 tracks")

    Args:
        total: steps expected; the bar is full at ``total``.
        unit: what a step is, for the count (``3/25 motions``).
        stream: where to write (default stderr); a bar when it is a terminal, else lines.
        enabled: False writes nothing (``--quiet``).
    """

    def __init__(self, total: int, unit: str = "steps", stream: TextIO | None = None,
                 enabled: bool = True) -> None:
        if total < 1:
            raise InvalidInputError(f"progress needs at least one step, got total={total}")
        self.total = total
        self.unit = unit
        self.done = 0
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled
        self.bar = enabled and bool(getattr(self.stream, "isatty", lambda: False)())
        self.started = time.perf_counter()
        self._drawn = 0  # characters of the bar now on the line (0: none)

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def line(self, status: str = "") -> str:
        """The text of the current state, without the bar: ``3/25 motions, 12 s, ~1:28 left: status``."""
        elapsed = time.perf_counter() - self.started
        text = f"{self.done}/{self.total} {self.unit}, {_clock(elapsed)}"
        if 0 < self.done < self.total:
            text += f", ~{_clock(elapsed / self.done * (self.total - self.done))} left"
        return f"{text}: {status}" if status else text

    def step(self, status: str = "", n: int = 1) -> None:
        """Count ``n`` more steps done and show the new state with ``status``."""
        self.done = min(self.done + n, self.total)
        if not self.enabled:
            return
        if not self.bar:
            print(self.line(status), file=self.stream, flush=True)
            return
        filled = BAR_WIDTH * self.done // self.total
        text = f"[{'#' * filled}{'.' * (BAR_WIDTH - filled)}] {self.line(status)}"
        text = text[:max(shutil.get_terminal_size().columns - 1, BAR_WIDTH + 2)]
        self.stream.write("\r" + text.ljust(self._drawn))
        self.stream.flush()
        self._drawn = len(text)

    def clear(self) -> None:
        """Erase the bar so that other output can be printed on a clean line (``step`` redraws it)."""
        if self._drawn:
            self.stream.write("\r" + " " * self._drawn + "\r")
            self.stream.flush()
            self._drawn = 0

    def close(self) -> None:
        """End the bar's line (the bar stays on screen)."""
        if self._drawn:
            self.stream.write("\n")
            self.stream.flush()
            self._drawn = 0
