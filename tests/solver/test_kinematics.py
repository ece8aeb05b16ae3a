"""Tests of solver/kinematics.py: the DH chain and the Panda's Gamma(q, joint)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from solver.errors import InvalidInputError
from solver.kinematics import PANDA, DHChain

#: Published Panda flange positions are quoted to the millimetre.
FLANGE_TOL = 1e-3  # m

#: Forward kinematics identities: products of seven 4x4 matrices, float64 rounding only.
FK_TOL = 1e-12

Q_READY = np.array([0.0, -np.pi / 4, 0.0, -3 * np.pi / 4, 0.0, np.pi / 2, np.pi / 4])


def _flange_position(q: np.ndarray) -> np.ndarray:
    return PANDA.frames(q)[-1][:3, 3]


def _random_configurations(rng: np.random.Generator, n: int) -> np.ndarray:
    return rng.uniform(PANDA.lower, PANDA.upper, size=(n, PANDA.n_joints))


def test_panda_flange_at_zero():
    np.testing.assert_allclose(_flange_position(np.zeros(7)), [0.088, 0.0, 0.926], atol=FLANGE_TOL)


def test_panda_flange_at_ready_pose():
    np.testing.assert_allclose(_flange_position(Q_READY), [0.307, 0.0, 0.590], atol=FLANGE_TOL)


def test_panda_flange_points_down_at_zero():
    R = PANDA.frames(np.zeros(7))[-1][:3, :3]
    np.testing.assert_allclose(R[:, 2], [0.0, 0.0, -1.0], atol=FK_TOL)


def test_frames_shape_and_rigidity(rng):
    frames = PANDA.frames(_random_configurations(rng, 1)[0])
    assert frames.shape == (8, 4, 4)
    for T in frames:
        np.testing.assert_allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=FK_TOL)
        assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0)
        np.testing.assert_array_equal(T[3], [0, 0, 0, 1])


def test_axis_and_point_returns_unit_axes(rng):
    for q in _random_configurations(rng, 10):
        for joint in range(PANDA.n_joints):
            axis, point = PANDA.axis_and_point(q, joint)
            assert axis.shape == point.shape == (3,)
            assert np.linalg.norm(axis) == pytest.approx(1.0, abs=FK_TOL)


def test_first_axis_is_the_base_z_axis(rng):
    for q in _random_configurations(rng, 5):
        axis, point = PANDA.axis_and_point(q, 0)
        np.testing.assert_allclose(axis, [0.0, 0.0, 1.0], atol=FK_TOL)
        np.testing.assert_allclose(point[:2], [0.0, 0.0], atol=FK_TOL)  # any point on the line


@pytest.mark.parametrize("joint", range(7))
def test_turning_a_joint_rotates_the_distal_chain_about_its_axis(joint, rng):
    # Gamma's defining property: turning joint J by theta moves every distal point by the
    # rotation of angle theta about the line (point, axis), right-handed.
    q = PANDA.clip(_random_configurations(rng, 1)[0])
    theta = 0.3
    axis, point = PANDA.axis_and_point(q, joint)
    q_turned = q.copy()
    q_turned[joint] += theta
    turn = Rotation.from_rotvec(theta * axis)
    expected = turn.apply(_flange_position(q) - point) + point
    np.testing.assert_allclose(_flange_position(q_turned), expected, atol=FK_TOL)
    # The proximal joints do not move.
    for j in range(joint + 1):
        np.testing.assert_allclose(PANDA.axis_and_point(q_turned, j)[1],
                                   PANDA.axis_and_point(q, j)[1], atol=FK_TOL)


def test_shoulder_axes_meet_in_one_point(rng):
    shoulder = np.array([0.0, 0.0, 0.333])
    for q in _random_configurations(rng, 5):
        for joint in range(3):
            axis, point = PANDA.axis_and_point(q, joint)
            assert np.linalg.norm(np.cross(shoulder - point, axis)) < FK_TOL


@pytest.mark.parametrize("joint", [-1, 7, 100])
def test_joint_out_of_range(joint):
    with pytest.raises(InvalidInputError, match=rf"joint {joint} out of range 0\.\.6"):
        PANDA.axis_and_point(np.zeros(7), joint)


@pytest.mark.parametrize("q", [np.zeros(6), np.zeros(8), np.zeros((1, 7)), np.zeros((7, 1))],
                         ids=["six", "eight", "row", "column"])
def test_bad_q_shape(q):
    with pytest.raises(InvalidInputError, match=r"q must have shape \(7,\), got"):
        PANDA.axis_and_point(q, 0)
    with pytest.raises(InvalidInputError, match=r"q must have shape \(7,\)"):
        PANDA.frames(q)


def test_clip_respects_limits(rng):
    q = rng.uniform(-5, 5, size=7)
    clipped = PANDA.clip(q)
    assert np.all(clipped >= PANDA.lower)
    assert np.all(clipped <= PANDA.upper)
    inside = (q >= PANDA.lower) & (q <= PANDA.upper)
    np.testing.assert_array_equal(clipped[inside], q[inside])


def test_panda_limits_are_the_published_ones():
    assert PANDA.n_joints == 7
    np.testing.assert_allclose(PANDA.upper[3], -0.0698)
    np.testing.assert_allclose(PANDA.lower[5], -0.0175)
    np.testing.assert_allclose(PANDA.upper[5], 3.7525)


def test_dh_chain_validation():
    ok = {"a": [0.0, 0.1], "d": [0.2, 0.0], "alpha": [0.0, np.pi / 2], "lower": [-1.0, -1.0],
          "upper": [1.0, 1.0], "flange": np.eye(4)}
    assert DHChain(**ok).n_joints == 2
    with pytest.raises(InvalidInputError, match=r"must all have shape \(N,\)"):
        DHChain(**{**ok, "d": [0.2]})
    with pytest.raises(InvalidInputError, match="every joint needs lower < upper"):
        DHChain(**{**ok, "lower": [-1.0, 1.0]})


def test_two_link_planar_arm():
    # A hand-checkable chain: two unit links in the plane, both axes along base z.
    arm = DHChain(a=[0.0, 1.0], d=[0.0, 0.0], alpha=[0.0, 0.0], lower=[-3.0, -3.0],
                  upper=[3.0, 3.0], flange=np.array([[1, 0, 0, 1.0], [0, 1, 0, 0], [0, 0, 1, 0],
                                                     [0, 0, 0, 1]]))
    q = np.array([0.5, -1.2])
    expected = [np.cos(0.5) + np.cos(0.5 - 1.2), np.sin(0.5) + np.sin(0.5 - 1.2), 0.0]
    np.testing.assert_allclose(arm.frames(q)[-1][:3, 3], expected, atol=FK_TOL)
    axis, point = arm.axis_and_point(q, 1)
    np.testing.assert_allclose(axis, [0.0, 0.0, 1.0], atol=FK_TOL)
    np.testing.assert_allclose(point, [np.cos(0.5), np.sin(0.5), 0.0], atol=FK_TOL)
