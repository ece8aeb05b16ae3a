"""Progress of long work (recording, calibrating, episodes) on stderr, drawn by tqdm.

In a terminal the progress is tqdm's bar, rewritten in place, with the latest step's status after it; in
a log, a pipe or CI it is one line per step (tqdm's count, elapsed and remaining time, then the status),
so that the log keeps every step. Either way it goes to stderr by default, leaving stdout to results
(tables, ``--json -`` style output of callers).
"""

from __future__ import annotations

import sys
import time
from typing import TextIO

from tqdm import tqdm

from solver.errors import InvalidInputError

#: A log line: ``3/25 motions, 00:12<01:30, joint 4: 40 tracks`` (tqdm's fields).
LINE_FORMAT = "{n_fmt}/{total_fmt} {unit}, {elapsed}<{remaining}{postfix}"
#: The terminal bar: ``12%|##   | 3/25 motions [00:12<01:30, joint 4: 40 tracks]``.
BAR_FORMAT = "{percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} {unit} [{elapsed}<{remaining}{postfix}]"


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
        stream: where to write (default stderr); tqdm's bar when it is a terminal, else lines.
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
        terminal = enabled and bool(getattr(self.stream, "isatty", lambda: False)())
        self.bar: tqdm | None = (tqdm(total=total, unit=unit, file=self.stream, dynamic_ncols=True, leave=True,
                                      mininterval=0.0, bar_format=BAR_FORMAT) if terminal else None)
        self.started = time.perf_counter()

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def line(self, status: str = "") -> str:
        """The text of the current state: ``3/25 motions, 00:12<01:30, status`` (tqdm's meter)."""
        return tqdm.format_meter(self.done, self.total, time.perf_counter() - self.started, unit=self.unit,
                                 postfix=status or None, bar_format=LINE_FORMAT)

    def step(self, status: str = "", n: int = 1) -> None:
        """Count ``n`` more steps done and show the new state with ``status``."""
        n = min(n, self.total - self.done)
        self.done += n
        if not self.enabled:
            return
        if self.bar is None:
            print(self.line(status), file=self.stream, flush=True)
            return
        self.bar.set_postfix_str(status, refresh=False)
        self.bar.update(n)
        self.bar.refresh()

    def clear(self) -> None:
        """Erase the bar so that other output can be printed on a clean line (``step`` redraws it)."""
        if self.bar is not None:
            self.bar.clear()

    def close(self) -> None:
        """End the bar's line (the bar stays on screen)."""
        if self.bar is not None:
            self.bar.close()
            self.bar = None
