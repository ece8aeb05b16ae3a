"""BLAS threads while a stage works: the one place that limits them (threadpoolctl).

The calibrator's and the tracker's products are small (pairs x 6, tracks x 9, patches): more BLAS threads than one
only wait on each other, and on a machine that also renders or tracks they take its cores. Measured on 2 cores with
another process rendering: a realistic 1080p replay (25 motions, the outline stage on) 21.7 s CPU / 21.3 s wall with
OpenBLAS's own 2 threads, 16.2 s / 18.1 s with 1, the same estimates; ``track_keypoints`` on bench_tracking.py's
1080p sweep 18-21 ms CPU per frame with 2, 13-14 ms with 1, the same tracks.
"""

from __future__ import annotations

import contextlib

from threadpoolctl import threadpool_limits

from solver.errors import InvalidInputError

__all__ = ["check_blas_threads", "limited_blas"]


def check_blas_threads(threads: int | None, what: str) -> None:
    """Refuse a BLAS thread count other than None or an int >= 1 (``what`` names the setting)."""
    if threads is not None and (isinstance(threads, bool) or not isinstance(threads, int) or threads < 1):
        raise InvalidInputError(f"{what} must be None or an integer >= 1, got {threads!r}")


def limited_blas(threads: int | None) -> contextlib.AbstractContextManager[object]:
    """A context inside which BLAS runs at most ``threads`` threads, restored after; None: BLAS left as it is."""
    if threads is None:
        return contextlib.nullcontext()
    return threadpool_limits(limits=threads, user_api="blas")
