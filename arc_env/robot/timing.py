"""Joint positions at the camera's exposure times: two clocks, one time offset, linear interpolation.

A camera stamps each frame with its exposure time on the camera clock; a robot logs its joint states at
its own rate on the joint clock. The two disagree by a constant **time offset** d (seconds)::

    d = t_joint - t_camera      (the stamps of one physical instant on the two clocks)

so the joints at an exposure stamped t (camera clock) are the joint series read at t + d. d > 0 is a
joint log stamped late (``arc-calib record --joint-latency-ms 20`` writes d = +0.020 s, and
``arc-calib calibrate --time-offset 0.020`` undoes it); d < 0 a log that leads the camera. This is the
one place the convention is defined (``docs/recording-format.md`` repeats it).

Joint values between two samples are interpolated linearly (``np.interp`` per joint), never taken from
the nearest sample; an exposure outside the series' time span is never extrapolated
(``joints_at_times`` raises, ``exposures_in_span`` tells which ones are inside).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from solver.arrays import FloatArray
from solver.errors import InvalidInputError


def check_times(t: FloatArray, what: str) -> FloatArray:
    """The times t (M,) s as float64, after checking they are finite and strictly increasing.

    Args:
        t: (M,) float64, s: sample or exposure times.
        what: how messages name the series (a file, a topic).

    Raises:
        InvalidInputError: t is not 1-D, holds NaN or infinity, repeats a time or goes back in time
            (the message gives the first offending index and its value).
    """
    t = np.asarray(t, dtype=np.float64)
    if t.ndim != 1:
        raise InvalidInputError(f"{what}: times must be a 1-D series, got shape {t.shape}")
    bad = np.nonzero(~np.isfinite(t))[0]
    if bad.size:
        raise InvalidInputError(f"{what}: time #{bad[0]} is {t[bad[0]]} (NaN or infinite)")
    step = np.diff(t)
    same = np.nonzero(step == 0)[0]
    if same.size:
        k = int(same[0]) + 1
        raise InvalidInputError(f"{what}: time #{k} = {float(t[k])!r} s repeats time #{k - 1} (duplicate time stamps)")
    back = np.nonzero(step < 0)[0]
    if back.size:
        k = int(back[0]) + 1
        raise InvalidInputError(f"{what}: time #{k} = {float(t[k])!r} s is earlier than time #{k - 1} = "
                                f"{float(t[k - 1])!r} s (times must increase)")
    return t


def exposures_in_span(t_frames: FloatArray, t_joints: FloatArray, time_offset_s: float = 0.0) -> NDArray[np.bool_]:
    """Which exposures fall within the joint series' time span once shifted to the joint clock.

    Args:
        t_frames: (F,) float64, s: exposure times, camera clock.
        t_joints: (M,) float64, s: joint sample times, joint clock, increasing.
        time_offset_s: d = t_joint - t_camera, s.

    Returns:
        (F,) bool: t_frames + d within [t_joints[0], t_joints[-1]].
    """
    shifted = np.asarray(t_frames, dtype=np.float64) + time_offset_s
    return (shifted >= t_joints[0]) & (shifted <= t_joints[-1])


def joints_at_times(t_frames: FloatArray, t_joints: FloatArray, values: FloatArray, time_offset_s: float = 0.0,
                    what: str = "joint states") -> tuple[FloatArray, FloatArray]:
    """Joint positions and velocities at the exposures, linearly interpolated from the joint series.

    The velocity of each joint is the series' finite difference (``np.gradient`` over the sample times:
    central inside, one-sided at the ends) interpolated at the exposures the same way: what a time-offset
    estimate needs (d(delta)/d(offset) at each frame).

    Args:
        t_frames: (F,) float64, s: exposure times, camera clock.
        t_joints: (M,) float64, s: joint sample times, joint clock, strictly increasing, M >= 2.
        values: (M, n) float64, rad: the joint positions at t_joints.
        time_offset_s: d = t_joint - t_camera, s (the module doc's convention).
        what: how messages name the joint series.

    Returns:
        positions (F, n) float64 rad and velocities (F, n) float64 rad/s at t_frames + d.

    Raises:
        InvalidInputError: fewer than 2 samples, or an exposure outside the series' span (never extrapolated).
    """
    t_joints = np.asarray(t_joints, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    t_frames = np.asarray(t_frames, dtype=np.float64)
    if t_joints.size < 2:
        raise InvalidInputError(f"{what}: {t_joints.size} sample(s); interpolation needs at least 2")
    inside = exposures_in_span(t_frames, t_joints, time_offset_s)
    if not inside.all():
        k = int(np.nonzero(~inside)[0][0])
        raise InvalidInputError(
            f"{what}: exposure #{k} at t = {float(t_frames[k])!r} s (camera clock; "
            f"{float(t_frames[k] + time_offset_s)!r} s on the joint clock with time offset {time_offset_s:+g} s) "
            f"is outside the joint samples' span [{float(t_joints[0])!r}, {float(t_joints[-1])!r}] s; "
            "joint positions are never extrapolated")
    shifted = t_frames + time_offset_s
    rates = np.gradient(values, t_joints, axis=0)
    positions = np.column_stack([np.interp(shifted, t_joints, values[:, j]) for j in range(values.shape[1])])
    velocities = np.column_stack([np.interp(shifted, t_joints, rates[:, j]) for j in range(values.shape[1])])
    return positions.reshape(len(t_frames), -1), velocities.reshape(len(t_frames), -1)


__all__ = ["check_times", "exposures_in_span", "joints_at_times"]
