"""Joints at exposure times: linear interpolation across two clocks, the time offset's sign, bad times."""

import numpy as np
import pytest

from arc_env.robot.timing import check_times, exposures_in_span, joints_at_times
from solver.errors import InvalidInputError

#: rad: interpolating a piecewise-linear trajectory sampled at its corners is exact up to rounding.
EXACT = 1e-12


def _trajectory(t):
    """A test motion on the true clock: joint 0 turns at 1 rad/s from t=1 to t=2, joint 1 at -0.5 rad/s throughout."""
    return np.column_stack([np.clip(t - 1.0, 0.0, 1.0), 0.3 - 0.5 * t])


def test_interpolation_is_linear_not_nearest_sample():
    t_joints = np.linspace(0.0, 3.0, 7)  # 2 Hz: a nearest-sample read would be off by up to 0.125 rad
    exposures = np.array([1.1, 1.37, 1.9])
    q, v = joints_at_times(exposures, t_joints, _trajectory(t_joints))
    np.testing.assert_allclose(q, _trajectory(exposures), atol=EXACT)
    np.testing.assert_allclose(v[:, 1], -0.5, atol=EXACT)


def test_a_late_joint_log_is_undone_by_the_same_positive_offset():
    """d = t_joint - t_camera: joint stamps late by 20 ms are read back at t + 0.020."""
    latency = 0.020
    true_times = np.arange(0.0, 3.0, 0.005)  # 200 Hz
    stamps = true_times + latency  # the joint log stamps each sample 20 ms late
    values = _trajectory(true_times)
    exposures = np.arange(1.1, 1.9, 1 / 30)
    q, v = joints_at_times(exposures, stamps, values, time_offset_s=latency)
    np.testing.assert_allclose(q, _trajectory(exposures), atol=1e-9)
    np.testing.assert_allclose(v[:, 0], 1.0, atol=1e-9)
    q_wrong, _ = joints_at_times(exposures, stamps, values, time_offset_s=0.0)
    np.testing.assert_allclose(q_wrong[:, 0], _trajectory(exposures)[:, 0] - latency, atol=1e-9)


def test_velocity_is_the_finite_difference_at_the_exposure():
    t = np.linspace(0.0, 1.0, 201)
    values = np.sin(3 * t)[:, None]
    exposures = np.array([0.2, 0.5, 0.77])
    q, v = joints_at_times(exposures, t, values)
    np.testing.assert_allclose(q[:, 0], np.sin(3 * exposures), atol=1e-4)
    np.testing.assert_allclose(v[:, 0], 3 * np.cos(3 * exposures), atol=1e-3)


def test_exposures_outside_the_span_are_refused_never_extrapolated():
    t = np.array([0.0, 1.0, 2.0])
    values = np.zeros((3, 1))
    assert exposures_in_span(np.array([-0.1, 0.0, 2.0, 2.05]), t, 0.0).tolist() == [False, True, True, False]
    assert exposures_in_span(np.array([-0.1]), t, 0.1).tolist() == [True]
    with pytest.raises(InvalidInputError, match=r"exposure #1 .* outside .* never extrapolated"):
        joints_at_times(np.array([1.0, 2.5]), t, values)
    with pytest.raises(InvalidInputError, match="at least 2"):
        joints_at_times(np.array([0.0]), t[:1], values[:1])


@pytest.mark.parametrize(("times", "message"), [
    ([0.0, 1.0, np.nan], r"time #2 is nan"),
    ([0.0, 1.0, 1.0], r"time #2 = 1.0 s repeats time #1"),
    ([0.0, 2.0, 1.0], r"time #2 = 1.0 s is earlier than time #1"),
], ids=["nan", "duplicate", "backwards"])
def test_bad_times_are_named(times, message):
    with pytest.raises(InvalidInputError, match=message):
        check_times(np.array(times), "joints")
