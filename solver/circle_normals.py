"""Circle-normal candidates from an image ellipse (paper §IV-C, Eq. 12-14).

The ellipse's matrix Q is also the cone x^T Q x = 0 of rays from the camera centre through it. A
plane cuts that cone in a circle for exactly two plane orientations; each orientation has two signs,
giving the paper's four normals. The sign is the rotation sense: a positive joint turn is a
right-handed rotation about the camera-frame axis R_camera_base @ axis_base, so the sign that agrees
with the observed order of points (increasing delta) is kept, leaving two candidates per trajectory.
"""

from __future__ import annotations

import numpy as np

from solver.arrays import FloatArray
from solver.errors import DegenerateTrajectoryError


def plane_orientations(Q: FloatArray) -> FloatArray:
    """The two unit normals of planes that cut the cone Q in a circle (Eq. 14), signs arbitrary.

    Args:
        Q: (3, 3) float64: a real ellipse's cone matrix in normalized image coordinates.

    Returns:
        (2, 3) float64: unit normals in the camera frame, each with a positive z component.

    Raises:
        DegenerateTrajectoryError: the cone's eigenvalues do not have signs (+, +, -).
    """
    eigval, eigvec = np.linalg.eigh(Q)
    if np.sum(eigval > 0) == 1:  # make the signature (+, +, -)
        eigval, eigvec = -eigval[::-1], eigvec[:, ::-1]
    if not (eigval[0] < 0 < eigval[1] <= eigval[2]):
        raise DegenerateTrajectoryError(f"cone eigenvalues {eigval} are not of an elliptic cone")
    lam3, lam1, lam2 = eigval  # paper's order: lam3 < 0 < lam1 <= lam2
    e3, e2 = eigvec[:, 0], eigvec[:, 2]
    c3 = np.sqrt((lam1 - lam3) / (lam2 - lam3))
    c2 = np.sqrt((lam2 - lam1) / (lam2 - lam3))
    normals = np.array([c3 * e3 + c2 * e2, c3 * e3 - c2 * e2])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return normals * np.where(normals[:, 2:] < 0, -1.0, 1.0)


def rotation_sense(normal: FloatArray, rays: FloatArray, delta: FloatArray) -> float:
    """Signed area swept about ``normal`` by the trajectory as delta increases.

    The rays are cut by the plane normal . X = 1 and the swept area is measured about the points'
    centroid (inside the arc's convex hull, so every step turns the same way).

    Args:
        normal: (3,) float64: a unit plane normal.
        rays: (M, 3) float64: the trajectory's rays (u, v, 1), ordered by frame.
        delta: (M,) float64, radians: joint turn at each frame.

    Returns:
        Positive when a positive turn is right-handed about ``normal``, negative when left-handed.
    """
    X = rays / (rays @ normal)[:, None]
    X = X - X.mean(axis=0)
    steps = np.cross(X[:-1], X[1:]) @ normal
    return float(np.sum(steps * np.sign(np.diff(delta))))


def axis_candidates(Q: FloatArray, rays: FloatArray, delta: FloatArray) -> FloatArray:
    """The two signed rotation-axis candidates of one trajectory: (2, 3) unit vectors, camera frame.

    Args:
        Q: (3, 3) float64: the trajectory's ellipse (cone) matrix.
        rays: (M, 3) float64: the trajectory's rays (u, v, 1).
        delta: (M,) float64, radians: joint turn at each frame.
    """
    return np.array([sensed(n, rays, delta) for n in plane_orientations(Q)])


def sensed(normal: FloatArray, rays: FloatArray, delta: FloatArray) -> FloatArray:
    """``normal`` (3,) signed so that a positive turn is right-handed about it (rays (M, 3), delta (M,))."""
    return normal * (np.sign(rotation_sense(normal, rays, delta)) or 1.0)
