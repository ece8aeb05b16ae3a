"""Independent synthetic geometry for the solver tests: circles, poses and a plain pinhole.

Nothing here calls the solver's own geometry helpers: points are moved with scipy's Rotation and
projected with numpy, so the tests compare the solver against a separate construction.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from solver.arrays import FloatArray

#: The house test camera: 1920x1080, fx = fy = 1380 px, principal point at the image centre.
WIDTH, HEIGHT = 1920, 1080
FX = FY = 1380.0
CX, CY = 959.5, 539.5
K = np.array([[FX, 0.0, CX], [0.0, FY, CY], [0.0, 0.0, 1.0]])
FOCAL = np.array([FX, FY])


def unit(v: FloatArray) -> FloatArray:
    """v / |v| along the last axis."""
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def random_unit(rng: np.random.Generator) -> FloatArray:
    """A uniformly random unit 3-vector."""
    return unit(rng.normal(size=3))


def tilted_unit(rng: np.random.Generator, towards: FloatArray, max_angle: float) -> FloatArray:
    """A random unit vector within ``max_angle`` rad of the unit vector ``towards``."""
    towards = unit(towards)
    side = unit(np.cross(towards, random_unit(rng)))
    angle = rng.uniform(0.0, max_angle)
    return Rotation.from_rotvec(angle * side).apply(towards)


def perpendicular(n: FloatArray) -> FloatArray:
    """A unit vector perpendicular to n (Gram-Schmidt on the least aligned basis vector)."""
    helper = np.eye(3)[int(np.argmin(np.abs(n)))]
    return unit(helper - (helper @ n) * n)


def circle_points(centre: FloatArray, axis: FloatArray, radius: float, angles: FloatArray,
                  start: FloatArray | None = None) -> FloatArray:
    """Points of a 3-D circle: a start point turned about the line (centre, +axis) by ``angles``.

    Args:
        centre: (3,) m.
        axis: (3,) unit normal of the circle; positive angles are right-handed about it.
        radius: m.
        angles: (M,) rad.
        start: (3,) unit direction of the angle-0 point from the centre (perpendicular to axis).

    Returns:
        (M, 3) float64, m.
    """
    axis = unit(axis)
    start = perpendicular(axis) if start is None else unit(start)
    turns = Rotation.from_rotvec(np.outer(np.asarray(angles, dtype=np.float64), axis))
    return turns.apply(radius * start) + np.asarray(centre, dtype=np.float64)


def project_normalized(points_cam: FloatArray) -> FloatArray:
    """Plain pinhole: (M, 3) camera-frame points (z > 0) -> (M, 2) normalized (x/z, y/z)."""
    points_cam = np.asarray(points_cam, dtype=np.float64)
    assert np.all(points_cam[:, 2] > 0), "synthetic point behind the camera"
    return points_cam[:, :2] / points_cam[:, 2:]


def pixels_from_normalized(uv: FloatArray) -> FloatArray:
    """Distortion-free pixels of normalized coordinates for the house camera."""
    return uv * FOCAL + np.array([CX, CY])


def homogeneous(uv: FloatArray) -> FloatArray:
    """(M, 2) -> (M, 3) rays (u, v, 1)."""
    return np.column_stack([uv, np.ones(uv.shape[0])])


def circle_cone(centre: FloatArray, axis: FloatArray, radius: float) -> FloatArray:
    """Exact cone matrix Q (3, 3) of the rays through a 3-D circle, from the geometry alone.

    A ray x meets the circle's plane n . X = h at X = h x / (n . x); requiring |X - c| = r gives
    x^T Q x = 0 with Q = h^2 I - h (n c^T + c n^T) + (|c|^2 - r^2) n n^T.
    """
    n, c = unit(axis), np.asarray(centre, dtype=np.float64)
    h = float(n @ c)
    return (h * h * np.eye(3) - h * (np.outer(n, c) + np.outer(c, n))
            + (c @ c - radius**2) * np.outer(n, n))


def random_pose(rng: np.random.Generator, distance: float = 1.5) -> FloatArray:
    """A random T_camera_base (4, 4) whose base origin is ~``distance`` m in front of the camera."""
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=rng).as_matrix()
    T[:3, 3] = np.array([rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.2), distance])
    return T


def angle_between(a: FloatArray, b: FloatArray) -> float:
    """Angle (rad) between two 3-vectors, accurate for tiny angles."""
    a, b = unit(a), unit(b)
    return float(np.arctan2(np.linalg.norm(np.cross(a, b)), a @ b))
