"""Tests of solver/frames.py: transforms, SO(3) projection, perturbations, pose errors."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from solver.errors import InvalidInputError
from solver.frames import (
    check_transform,
    perturb,
    pose_difference,
    pose_errors,
    project_to_so3,
    quaternion_xyzw_from_matrix,
    rotation_about_axis,
    skew,
    transform_from_rt,
)
from tests.solver.scene import random_pose, random_unit

#: Orthonormality, round trips and closed-form values: float64 rounding of a few 3x3 products.
EXACT_TOL = 1e-12

#: Rotation-vector extraction near small angles loses a few digits (acos/atan2 of ~1 - eps).
ROTVEC_TOL = 1e-9


def test_project_to_so3_gives_proper_rotations(rng):
    for _ in range(50):
        M = rng.normal(size=(3, 3))
        R = project_to_so3(M)
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=EXACT_TOL)
        assert np.linalg.det(R) == pytest.approx(1.0, abs=EXACT_TOL)


def test_project_to_so3_of_reflection_is_still_proper():
    R = project_to_so3(np.diag([1.0, 1.0, -1.0]))
    assert np.linalg.det(R) == pytest.approx(1.0, abs=EXACT_TOL)


def test_project_to_so3_keeps_rotations(rng):
    R = Rotation.random(random_state=rng).as_matrix()
    np.testing.assert_allclose(project_to_so3(R), R, atol=EXACT_TOL)


def test_project_to_so3_is_nearest_in_frobenius_norm(rng):
    R_true = Rotation.random(random_state=rng).as_matrix()
    M = R_true + 0.3 * rng.normal(size=(3, 3))
    best = np.linalg.norm(M - project_to_so3(M))
    others = Rotation.random(5000, random_state=rng).as_matrix()
    # Also try rotations near the answer, where a wrong projection would most likely lose.
    near = (Rotation.from_rotvec(0.05 * rng.normal(size=(500, 3)))
            * Rotation.from_matrix(project_to_so3(M))).as_matrix()
    candidates = np.concatenate([others, near])
    assert best <= np.min(np.linalg.norm(M - candidates, axis=(1, 2))) + EXACT_TOL


def test_skew_is_the_cross_product(rng):
    a, b = rng.normal(size=(2, 3))
    np.testing.assert_allclose(skew(a) @ b, np.cross(a, b), atol=EXACT_TOL)
    batch = rng.normal(size=(4, 3))
    np.testing.assert_allclose(np.einsum("nij,j->ni", skew(batch), b), np.cross(batch, b),
                               atol=EXACT_TOL)


def test_skew_writes_the_cross_product_matrix_out_for_any_stack(rng):
    """Against the matrix written entry by entry: the same values exactly, stacks of any shape."""
    v = rng.normal(size=(2, 5, 3))
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    zero = np.zeros_like(x)
    written = np.stack([np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1), np.stack([-y, x, zero], -1)], -2)
    np.testing.assert_array_equal(skew(v), written)
    np.testing.assert_array_equal(skew(v[0, 0]), written[0, 0])
    assert skew(v).shape == (2, 5, 3, 3)


def test_transform_from_rt_maps_points(rng):
    R = Rotation.random(random_state=rng).as_matrix()
    t = rng.normal(size=3)
    p = rng.normal(size=3)
    np.testing.assert_allclose((transform_from_rt(R, t) @ np.append(p, 1.0))[:3], R @ p + t,
                               atol=EXACT_TOL)


def test_perturb_follows_left_rotation_convention(rng):
    T = random_pose(rng)
    xi = np.concatenate([rng.normal(0, 0.3, 3), rng.normal(0, 0.1, 3)])
    T_new = perturb(T, xi)
    np.testing.assert_allclose(T_new[:3, :3], Rotation.from_rotvec(xi[:3]).as_matrix() @ T[:3, :3],
                               atol=EXACT_TOL)
    np.testing.assert_allclose(T_new[:3, 3], T[:3, 3] + xi[3:], atol=EXACT_TOL)


def test_perturb_of_pose_difference_round_trip(rng):
    for _ in range(20):
        T_est, T_true = random_pose(rng), random_pose(rng)
        np.testing.assert_allclose(perturb(T_est, pose_difference(T_est, T_true)), T_true,
                                   atol=EXACT_TOL)


def test_pose_difference_of_perturb_round_trip(rng):
    for _ in range(20):
        T = random_pose(rng)
        omega = random_unit(rng) * rng.uniform(0.0, 3.0)  # below pi: rotation vectors are unique
        xi = np.concatenate([omega, rng.normal(0, 0.2, 3)])
        np.testing.assert_allclose(pose_difference(T, perturb(T, xi)), xi, atol=ROTVEC_TOL)


def test_pose_errors_of_identical_poses_are_zero(rng):
    T = random_pose(rng)
    rot_err, trans_err = pose_errors(T, T)
    assert rot_err == pytest.approx(0.0, abs=EXACT_TOL)
    assert trans_err == 0.0


def test_pose_errors_of_known_offset(rng):
    T_true = random_pose(rng)
    axis = random_unit(rng)
    T_est = T_true.copy()
    T_est[:3, :3] = Rotation.from_rotvec(0.1 * axis).as_matrix() @ T_true[:3, :3]
    T_est[:3, 3] += [0.03, 0.04, 0.0]
    rot_err, trans_err = pose_errors(T_est, T_true)
    assert rot_err == pytest.approx(0.1, abs=ROTVEC_TOL)
    assert trans_err == pytest.approx(0.05, abs=EXACT_TOL)
    # A right-multiplied (body-frame) rotation has the same geodesic angle.
    T_body = T_true.copy()
    T_body[:3, :3] = T_true[:3, :3] @ Rotation.from_rotvec(0.1 * axis).as_matrix()
    assert pose_errors(T_body, T_true)[0] == pytest.approx(0.1, abs=ROTVEC_TOL)


def test_rotation_about_axis_matches_scipy(rng):
    axis = random_unit(rng)
    angles = np.linspace(-2.0, 2.0, 7)
    expected = np.array([Rotation.from_rotvec(a * axis).as_matrix() for a in angles])
    np.testing.assert_allclose(rotation_about_axis(axis, angles), expected, atol=EXACT_TOL)


def test_check_transform_accepts_and_converts(rng):
    T = random_pose(rng)
    out = check_transform(T.tolist())
    assert out.dtype == np.float64
    np.testing.assert_array_equal(out, T)


def _bad(kind: str) -> np.ndarray:
    T = np.eye(4)
    if kind == "nan":
        T[0, 3] = np.nan
    elif kind == "bottom":
        T[3, 0] = 0.5
    elif kind == "reflection":
        T[:3, :3] = np.diag([1.0, 1.0, -1.0])
    elif kind == "scaled":
        T[:3, :3] *= 1.1
    return T


@pytest.mark.parametrize(
    ("T", "match"),
    [
        pytest.param(np.eye(4)[:3], r"pose must be 4x4, got shape \(3, 4\)", id="shape"),
        pytest.param(_bad("nan"), "pose contains NaN", id="nan"),
        pytest.param(_bad("bottom"), r"pose bottom row must be \[0, 0, 0, 1\]", id="bottom-row"),
        pytest.param(_bad("reflection"), "pose rotation block is not a proper rotation",
                     id="reflection"),
        pytest.param(_bad("scaled"), "pose rotation block is not a proper rotation", id="scaled"),
    ],
)
def test_check_transform_errors(T, match):
    with pytest.raises(InvalidInputError, match=match):
        check_transform(T, name="pose")


def test_quaternion_xyzw_matches_scipy_with_nonnegative_w(rng):
    rotations = Rotation.random(200, random_state=rng)
    for R in rotations.as_matrix():
        q = quaternion_xyzw_from_matrix(R)
        assert q[3] >= 0.0
        assert np.linalg.norm(q) == pytest.approx(1.0, abs=EXACT_TOL)
        reference = Rotation.from_matrix(R).as_quat()  # scipy's order is (x, y, z, w) too
        sign = 1.0 if reference[3] >= 0 else -1.0
        np.testing.assert_allclose(q, sign * reference, atol=EXACT_TOL)
        np.testing.assert_allclose(Rotation.from_quat(q).as_matrix(), R, atol=EXACT_TOL)


def test_quaternion_xyzw_component_order():
    # 90 degrees about +z: (x, y, z, w) = (0, 0, sin 45, cos 45).
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    s = np.sqrt(0.5)
    np.testing.assert_allclose(quaternion_xyzw_from_matrix(R), [0.0, 0.0, s, s], atol=EXACT_TOL)


def test_pose_difference_of_a_stack_is_each_poses(rng):
    """A stack in either argument gives, row by row, the differences of the single poses."""
    T = random_pose(rng)
    stack = np.array([random_pose(rng) for _ in range(5)])
    np.testing.assert_allclose(pose_difference(stack, T), [pose_difference(S, T) for S in stack], rtol=0, atol=1e-15)
    np.testing.assert_allclose(pose_difference(T, stack), [pose_difference(T, S) for S in stack], rtol=0, atol=1e-15)
    assert pose_difference(stack, T).shape == (5, 6) and pose_difference(T, T).shape == (6,)
