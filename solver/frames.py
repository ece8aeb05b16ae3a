"""Frames, transforms and pose errors: the conventions are defined here and nowhere else.

* Camera frame: the OpenCV optical frame, x right, y down, z forward.
* ``T_camera_base``: 4x4 homogeneous transform with ``p_camera = T_camera_base @ p_base``.
* Rotation vectors are axis * angle (radians); quaternions at the edges are (x, y, z, w).
* A 6-vector pose perturbation is (omega, tau): ``R = Exp(omega) @ R_hat``, ``t = t_hat + tau``,
  both expressed in the camera frame. Covariances of T_camera_base use this parameterization.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from solver.arrays import FloatArray
from solver.errors import InvalidInputError


def transform_from_rt(R: FloatArray, t: FloatArray) -> FloatArray:
    """Build a 4x4 transform from R: (3, 3) and t: (3,) metres."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def check_transform(T: FloatArray, name: str = "transform") -> FloatArray:
    """Validate a 4x4 rigid transform and return it as float64.

    Raises:
        InvalidInputError: wrong shape, non-finite, bottom row not [0, 0, 0, 1], or R not in SO(3).
    """
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4):
        raise InvalidInputError(f"{name} must be 4x4, got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        raise InvalidInputError(f"{name} contains NaN or infinite values")
    if not np.allclose(T[3], [0, 0, 0, 1]):
        raise InvalidInputError(f"{name} bottom row must be [0, 0, 0, 1], got {T[3]}")
    R = T[:3, :3]
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise InvalidInputError(f"{name} rotation block is not a proper rotation")
    return T


def skew(v: FloatArray) -> FloatArray:
    """Cross-product matrix [v]x of v: (3,) -> (3, 3), or (n, 3) -> (n, 3, 3).

    One product with a constant (3, 9) basis (every entry is +-1 times one of v's components, the others'
    zero products add nothing), not a zeroed array filled slice by slice: the same values for finite v,
    two to three times faster on the rigid front end's stacks; a non-finite component spreads to its row.
    """
    v = np.asarray(v, dtype=np.float64)
    return (v @ _SKEW_BASIS).reshape(v.shape[:-1] + (3, 3))


#: ``skew``'s basis: [v]x flattened row by row = v @ _SKEW_BASIS (read-only).
_SKEW_BASIS = np.zeros((3, 9))
_SKEW_BASIS[2, 1] = _SKEW_BASIS[1, 6] = _SKEW_BASIS[0, 5] = -1.0  # -v2 at (0, 1), -v1 at (2, 0), -v0 at (1, 2)
_SKEW_BASIS[1, 2] = _SKEW_BASIS[2, 3] = _SKEW_BASIS[0, 7] = 1.0  # v1 at (0, 2), v2 at (1, 0), v0 at (2, 1)
_SKEW_BASIS.flags.writeable = False


def project_to_so3(M: FloatArray) -> FloatArray:
    """Nearest rotation to a 3x3 matrix in the Frobenius norm (SVD, det = +1)."""
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def perturb(T: FloatArray, xi: FloatArray) -> FloatArray:
    """Apply a pose perturbation xi = (omega, tau): (6,) to T: R <- Exp(omega) R, t <- t + tau."""
    R = Rotation.from_rotvec(xi[:3]).as_matrix() @ T[:3, :3]
    return transform_from_rt(R, T[:3, 3] + xi[3:])


def pose_difference(T_est: FloatArray, T_true: FloatArray) -> FloatArray:
    """The perturbation xi (6,) with perturb(T_est, xi) == T_true: (rad, rad, rad, m, m, m).

    Either pose may be a stack (..., 4, 4): then xi (..., 6), one per pose.
    """
    omega = Rotation.from_matrix(T_true[..., :3, :3] @ np.swapaxes(T_est[..., :3, :3], -1, -2)).as_rotvec()
    return np.concatenate([omega, T_true[..., :3, 3] - T_est[..., :3, 3]], axis=-1)


def pose_errors(T_est: FloatArray, T_true: FloatArray) -> tuple[float, float]:
    """Rotation error (geodesic angle, rad) and translation error (Euclidean, m) of T_camera_base."""
    xi = pose_difference(T_est, T_true)
    return float(np.linalg.norm(xi[:3])), float(np.linalg.norm(xi[3:]))


def rotation_about_axis(axis: FloatArray, angles: FloatArray) -> FloatArray:
    """Rotations by each angle about a unit axis: axis (3,), angles (M,) rad -> (M, 3, 3)."""
    return Rotation.from_rotvec(np.outer(np.asarray(angles, dtype=np.float64), axis)).as_matrix()


def quaternion_xyzw_from_matrix(R: FloatArray) -> FloatArray:
    """Quaternion (x, y, z, w) of a rotation matrix, with w >= 0."""
    q = Rotation.from_matrix(R).as_quat()
    return q if q[3] >= 0 else -q
