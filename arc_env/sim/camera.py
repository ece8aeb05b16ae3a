"""MuJoCo's camera frame versus the OpenCV optical frame: the one conversion, and the intrinsics.

A MuJoCo camera looks along its local -z with +y up in the image; the OpenCV optical frame
(``solver.frames``) looks along +z with +y down. The two share x and differ by a half turn about
x: ``R_world_mjcam = R_world_optical @ diag(1, -1, -1)``. Everything in ``arc_env`` that places or
reads a MuJoCo camera goes through the two functions below.

MuJoCo renders a symmetric pinhole (principal point at the image centre, fx = fy) from its
vertical field of view; ``fovy_from_intrinsics`` converts and refuses intrinsics it cannot honour.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from solver.arrays import FloatArray
from solver.errors import InvalidInputError
from solver.frames import check_transform, transform_from_rt
from solver.observations import CameraIntrinsics

#: Rotation from the OpenCV optical frame to MuJoCo's camera frame (and back: it is its own inverse).
R_OPTICAL_MJCAM = np.diag([1.0, -1.0, -1.0])


def mujoco_camera_from_optical(T_world_camera: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Place a MuJoCo camera: optical-frame pose in the world -> (pos (3,) m, quat (4,) w, x, y, z).

    Args:
        T_world_camera: (4, 4) float64: the OpenCV optical frame in the world frame
            (``p_world = T_world_camera @ p_camera``).

    Returns:
        pos and quat for ``model.cam_pos`` / ``model.cam_quat`` (MuJoCo's w-first order) of a camera
        attached to the world body.
    """
    T_world_camera = check_transform(T_world_camera, "T_world_camera")
    R_world_mjcam = T_world_camera[:3, :3] @ R_OPTICAL_MJCAM
    x, y, z, w = Rotation.from_matrix(R_world_mjcam).as_quat()
    return T_world_camera[:3, 3].copy(), np.array([w, x, y, z])


def optical_from_mujoco_camera(pos: FloatArray, xmat: FloatArray) -> FloatArray:
    """Read a MuJoCo camera back: ``data.cam_xpos`` (3,) m and ``data.cam_xmat`` (9,) -> T_world_camera (4, 4)."""
    R_world_mjcam = np.asarray(xmat, dtype=np.float64).reshape(3, 3)
    return transform_from_rt(R_world_mjcam @ R_OPTICAL_MJCAM, np.asarray(pos, dtype=np.float64))


def fovy_from_intrinsics(intrinsics: CameraIntrinsics, tol_px: float = 0.5) -> float:
    """MuJoCo's vertical field of view (degrees) for a symmetric pinhole camera.

    Raises:
        InvalidInputError: the camera has distortion, fx != fy, or its principal point is more than
            ``tol_px`` from the image centre ((W - 1) / 2, (H - 1) / 2): MuJoCo cannot render it.
    """
    K = intrinsics.K
    if intrinsics.dist.size and np.any(intrinsics.dist != 0):
        raise InvalidInputError("the simulator renders undistorted images; give dist = zeros")
    if abs(K[0, 0] - K[1, 1]) > 1e-9 * K[0, 0]:
        raise InvalidInputError(f"the simulator needs fx == fy, got fx={K[0, 0]}, fy={K[1, 1]}")
    centre = np.array([(intrinsics.width - 1) / 2, (intrinsics.height - 1) / 2])
    if np.any(np.abs(K[:2, 2] - centre) > tol_px):
        raise InvalidInputError(f"the simulator needs the principal point at the image centre {centre}, "
                                f"got {K[:2, 2]}")
    return float(np.degrees(2.0 * np.arctan(intrinsics.height / (2.0 * K[1, 1]))))
