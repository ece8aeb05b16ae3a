"""Segmentation of a joint stream: one-joint turns found with their times, transits and small turns skipped."""

import numpy as np
import pytest

from arc_env.robot.segmentation import SegmentConfig, segment_motions
from solver.errors import InvalidInputError

NAMES = [f"j{k}" for k in range(6)]
HZ = 500.0
#: rad: encoder noise of the test stream (a real arm: ~1e-4 rad); the net turn is read at two rests
#: through it, so it is known to a few sigma.
NOISE = 1e-4
DELTA_TOL = 1e-3


def _stream(knots, rng):
    """A piecewise-linear joint stream through (time s, q (6,) rad) knots, sampled at HZ with noise."""
    times = np.array([k[0] for k in knots])
    qs = np.array([k[1] for k in knots])
    t = np.arange(times[0], times[-1], 1 / HZ)
    values = np.column_stack([np.interp(t, times, qs[:, j]) for j in range(qs.shape[1])])
    return t, values + rng.normal(0, NOISE, values.shape)


def _script():
    q0 = np.zeros(6)
    q1 = q0 + [0.5, -0.3, 0.2, 0.0, 0.1, 0.0]  # a transit: several joints together
    q2 = q1.copy()
    q2[2] += 0.6  # exploratory: j2 by +0.6 rad
    q3 = q2.copy()
    q3[1] += 0.05  # too small
    q4 = q3.copy()
    q4[4] -= 0.4  # exploratory: j4 by -0.4 rad
    q5 = q4 + 0.3  # a transit
    return [(0.0, q0), (0.5, q0), (1.5, q1), (2.0, q1), (2.6, q2), (3.0, q2), (3.1, q3), (3.6, q3), (4.0, q4),
            (4.5, q4), (5.3, q5), (6.0, q5)]


def test_one_joint_turns_are_segments_and_the_rest_is_skipped_with_reasons():
    t, values = _stream(_script(), np.random.default_rng(0))
    config = SegmentConfig()
    segments, skipped = segment_motions(t, values, NAMES, config)
    assert [s.joint for s in segments] == [2, 4]
    assert [s.delta for s in segments] == pytest.approx([0.6, -0.4], abs=DELTA_TOL)
    slack = config.window_s / 2 + 1 / HZ  # a span starts (ends) up to half a window before (after) the motion
    for s, (start, stop) in zip(segments, [(2.0, 2.6), (3.6, 4.0)], strict=True):
        assert start - slack <= s.t_start <= start and stop <= s.t_stop <= stop + slack
        others = np.delete(s.ranges, s.joint)
        assert np.all(others < config.still_tolerance_rad)
    reasons = [s.reason for s in skipped]
    assert len(skipped) == 3, reasons
    assert "4 joints move" in reasons[0] and "transit" in reasons[0]
    assert "j1 turns by only +0.050 rad" in reasons[1]
    assert "6 joints move" in reasons[2]


def test_a_span_cut_off_by_the_end_of_the_stream_is_skipped():
    knots = _script()[:9]  # ends while j4 turns
    segments, skipped = segment_motions(*_stream(knots, np.random.default_rng(1)), NAMES)
    assert [s.joint for s in segments] == [2]
    assert "end of the joint stream" in skipped[-1].reason


def test_shapes_are_checked():
    with pytest.raises(InvalidInputError, match="values must be"):
        segment_motions(np.arange(3.0), np.zeros((3, 2)), NAMES)
    with pytest.raises(InvalidInputError, match="finite and > 0"):
        SegmentConfig(window_s=0.0)
