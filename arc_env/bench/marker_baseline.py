"""The marker baseline: eye-to-hand calibration with a ChArUco board on the flange, in the same simulator.

This is what users run today, done the usual way: a ChArUco board (``arc_env.sim.marker_board``) is
fixed to the Panda's flange; the robot visits N collision-free poses where the board is in view and
faces the camera, with well-spread orientations; at each pose the camera image is rendered, the
board detected (``cv2.aruco.CharucoDetector``) and its pose estimated (``matchImagePoints`` +
``cv2.solvePnP``); then the eye-to-hand problem is solved for ``T_camera_base`` and the unknown
board-on-flange pose at once.

Solver: the robot-world/hand-eye formulation ``A_i X = Z B_i`` (OpenCV's
``calibrateRobotWorldHandEye``) with, for a fixed camera and a board on the hand,
``A_i = T_board_camera`` (the inverse of solvePnP's pose), ``B_i = T_flange_base`` (the inverse of
the flange pose from the robot's kinematics), ``X = T_camera_base`` (OpenCV's ``base2world``,
returned directly, no inversion) and ``Z = T_flange_board``'s inverse ``T_board_flange``
(OpenCV's ``gripper2cam``). Method: Shah's closed form (Kronecker product + SVD for the rotations,
then linear least squares for both translations; M. Shah, J. Mechanisms Robotics 5(3), 2013), OpenCV's
``CALIB_ROBOT_WORLD_HAND_EYE_SHAH``. OpenCV 5.0.0's Python package does not bind
``calibrateRobotWorldHandEye`` nor ``calibrateHandEye`` (opencv/opencv#29565, fixed after 5.0.0 by
PR #29584), so ``solve_eye_to_hand`` calls OpenCV when the binding exists and otherwise runs
``shah_robot_world_hand_eye``, our numpy implementation of the same method. It was checked against
OpenCV 4.10.0's ``calibrateRobotWorldHandEye`` (a separate environment) on noisy synthetic inputs:
equal to 1e-15; ``tests/arc_env/bench/test_marker_baseline.py`` repeats that comparison wherever the
binding exists (and is skipped with OpenCV 5.0.0). OpenCV 5.1.0 binds it again, but takes the translations
only as (3, 1) columns (given (3,) vectors it fails an assertion in ``gemm``): they are passed so, which every
release takes.

What the baseline is allowed to know (and what it is not):

* the camera intrinsics (as ARC-Calib does);
* the robot's joint readings and kinematics: the flange pose ``T_base_flange`` per pose, from
  MuJoCo's forward kinematics of the flange body (the board's mount body);
* roughly where the camera is, to aim the board at it: the true camera pose degraded by
  ``aim_position_error_m`` and ``aim_rotation_error_rad`` of random error, drawn once per run. This
  stands in for a person who looks at the camera and jogs the robot so the board faces it. It is
  used only to choose candidate poses; whether a pose is used is decided by detection in the
  rendered image, as a person watching the live image would;
* roughly how the board is mounted (the nominal mount, ``MarkerBoard.T_mount_board``), again only to
  choose poses. The solver never receives the board-on-flange pose: hand-eye estimates it.

Pose choice: random joint configurations (within the limits, ``limit_margin`` away from them) are
kept when, seen from the aimed camera, the board is in front, inside the image, and tilted by at
most ``max_tilt_rad`` from facing it; and when the collision checker (with the board's collision
box) finds the arm free. From that pool, poses are taken by greedy farthest-point sampling on the
flange orientation (the next pose maximizes its smallest rotation angle to the poses taken so far),
so that every prefix of the sequence is spread; each is rendered and kept only if the board is
detected with at least ``min_corners`` ChArUco corners and a PnP reprojection RMS under
``max_reprojection_px``. Transits between poses are not planned (a person jogs the robot).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import cv2
import mujoco
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from arc_env.sim.marker_board import BOARD_BODY, MarkerBoard
from solver.arrays import FloatArray
from solver.errors import InvalidInputError
from solver.frames import perturb, pose_errors, project_to_so3, transform_from_rt
from solver.observations import CameraIntrinsics

if TYPE_CHECKING:
    from arc_env.sim.env import ArcCalibEnv



@dataclass(frozen=True)
class MarkerBaselineConfig:
    """Settings of the marker baseline (see the module doc for what they do).

    Attributes:
        min_corners: ChArUco corners needed to use a view.
        max_reprojection_px: largest PnP reprojection RMS of a used view, px.
        min_marker_perimeter_rate: ArUco detector's smallest marker perimeter as a fraction of the
            image's larger side (OpenCV's default 0.03 drops markers under 14 px at 1920 px wide).
        aim_position_error_m: standard deviation per axis of the aimed camera position, m.
        aim_rotation_error_rad: standard deviation per axis of the aimed camera orientation, rad.
        max_tilt_rad: largest angle between the board's normal and the direction to the aimed camera.
        image_margin_px: the board's corners must project this far inside the image (aimed camera).
        min_depth_m: the board must be at least this far in front of the aimed camera, m.
        limit_margin: fraction of each joint's range kept away from its limits when sampling.
        pool_size: collision-free candidate poses to choose from.
        max_samples: random configurations drawn at most to fill the pool.
    """

    min_corners: int = 6
    max_reprojection_px: float = 1.0
    min_marker_perimeter_rate: float = 0.01
    aim_position_error_m: float = 0.1
    aim_rotation_error_rad: float = 0.05
    max_tilt_rad: float = np.radians(50.0)
    image_margin_px: float = 20.0
    min_depth_m: float = 0.3
    limit_margin: float = 0.05
    pool_size: int = 300
    max_samples: int = 60000

    def __post_init__(self) -> None:
        if self.min_corners < 4:
            raise InvalidInputError(f"min_corners must be >= 4 (PnP), got {self.min_corners}")
        if not 0 < self.max_tilt_rad < np.pi / 2:
            raise InvalidInputError("max_tilt_rad must be in (0, pi/2)")
        if self.pool_size < 1 or self.max_samples < self.pool_size:
            raise InvalidInputError("need pool_size >= 1 and max_samples >= pool_size")


@dataclass(frozen=True)
class BoardDetection:
    """One detected board.

    Attributes:
        corners_px: (K, 2) float64, ChArUco corners in the image, px.
        object_points: (K, 3) float64, the same corners in the board frame, m.
        T_camera_board: (4, 4) board pose from PnP (``p_camera = T_camera_board @ p_board``).
        reprojection_px: RMS reprojection error of the PnP pose, px.
    """

    corners_px: FloatArray
    object_points: FloatArray
    T_camera_board: FloatArray
    reprojection_px: float


@dataclass(frozen=True)
class BoardView:
    """One pose the robot visited with the board detected.

    Attributes:
        q: (n_joints,) rad.
        T_base_flange: (4, 4) the mount body's pose in the base frame (robot kinematics).
        detection: the board seen at q.
    """

    q: FloatArray
    T_base_flange: FloatArray
    detection: BoardDetection


@dataclass
class MarkerRun:
    """What ``MarkerBaseline.run`` did.

    Attributes:
        views: the used views, in visiting order.
        rejected: poses visited whose image gave no usable board (count).
        estimates: per number of views n (1-based, up to len(views)): ``T_camera_base`` from the
            first n views, or None (fewer than 3 views or a failed solve).
        T_flange_board: the final hand-eye estimate of the board on the flange, or None.
        seconds: wall time of {"select", "render", "detect", "solve"}.
    """

    views: list[BoardView] = field(default_factory=list)
    rejected: int = 0
    estimates: list[FloatArray | None] = field(default_factory=list)
    T_flange_board: FloatArray | None = None
    seconds: dict[str, float] = field(default_factory=dict)

    @property
    def T_camera_base(self) -> FloatArray | None:
        """The estimate from all views (None without one)."""
        return self.estimates[-1] if self.estimates else None


def make_detector(board: MarkerBoard, intrinsics: CameraIntrinsics,
                  config: MarkerBaselineConfig | None = None) -> cv2.aruco.CharucoDetector:
    """OpenCV's ChArUco detector for ``board`` with the camera's intrinsics and our detector settings."""
    if intrinsics.is_fisheye:
        raise InvalidInputError("the marker baseline detects and poses the board with OpenCV's pinhole model "
                                "(cv2.aruco, cv2.solvePnP); a fisheye camera is not supported")
    config = config or MarkerBaselineConfig()
    charuco = cv2.aruco.CharucoParameters()
    charuco.cameraMatrix = intrinsics.K
    charuco.distCoeffs = intrinsics.dist
    params = cv2.aruco.DetectorParameters()
    params.minMarkerPerimeterRate = config.min_marker_perimeter_rate
    return cv2.aruco.CharucoDetector(board.cv_board(), charuco, params)


def detect_board(image: NDArray[np.uint8], board: MarkerBoard, intrinsics: CameraIntrinsics,
                 detector: cv2.aruco.CharucoDetector | None = None, min_corners: int = 6) -> BoardDetection | None:
    """Detect the board in an image and estimate its pose.

    Args:
        image: (H, W, 3) RGB or (H, W) grey uint8.
        board: the board.
        intrinsics: the camera.
        detector: a detector from ``make_detector`` (made here if None).
        min_corners: fewer ChArUco corners (or collinear ones) give None.

    Returns:
        The detection, or None when the board is not found well enough for a pose.
    """
    gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
    detector = detector if detector is not None and not intrinsics.is_fisheye else make_detector(board, intrinsics)
    corners, ids, _, _ = detector.detectBoard(gray)
    if corners is None or ids is None or len(corners) < max(min_corners, 4):
        return None
    cv_board = detector.getBoard()
    if cv_board.checkCharucoCornersCollinear(ids):
        return None
    obj, img = cv_board.matchImagePoints(corners, ids)
    obj, img = obj.reshape(-1, 3).astype(np.float64), img.reshape(-1, 2).astype(np.float64)
    ok, rvec, tvec = cv2.solvePnP(obj, img, intrinsics.K, intrinsics.dist)
    if not ok:
        return None
    projected, _ = cv2.projectPoints(obj, rvec, tvec, intrinsics.K, intrinsics.dist)
    rms = float(np.sqrt(np.mean(np.sum((projected.reshape(-1, 2) - img) ** 2, axis=1))))
    T_camera_board = transform_from_rt(cv2.Rodrigues(rvec)[0], tvec.reshape(3))
    return BoardDetection(img, obj, T_camera_board, rms)


def shah_robot_world_hand_eye(T_A: FloatArray, T_B: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Solve ``A_i X = Z B_i`` for X and Z by Shah's closed form (numpy).

    Rotations: with column-major vec, ``vec(R_X) = (R_B^T kron R_A^T) vec(R_Z)`` for every i, so
    ``M = sum_i kron(R_B_i, R_A_i)`` is ``n vec(R_Z) vec(R_X)^T`` without noise: its leading left and
    right singular vectors give R_Z and R_X (scaled, signed by det > 0, projected onto SO(3)).
    Translations: ``R_A_i t_X - t_Z = R_Z t_B_i - t_A_i``, stacked, by least squares.

    Args:
        T_A: (N, 4, 4), N >= 3.
        T_B: (N, 4, 4).

    Returns:
        X (4, 4) and Z (4, 4).
    """
    R_A, t_A, R_B, t_B = T_A[:, :3, :3], T_A[:, :3, 3], T_B[:, :3, :3], T_B[:, :3, 3]
    M = sum(np.kron(rb, ra) for ra, rb in zip(R_A, R_B, strict=True))
    U, _, Vt = np.linalg.svd(M)
    R_Z = U[:, 0].reshape(3, 3, order="F")
    R_X = Vt[0].reshape(3, 3, order="F")
    if np.linalg.det(R_X) < 0:  # the singular pair's common sign
        R_X, R_Z = -R_X, -R_Z
    R_X, R_Z = project_to_so3(R_X), project_to_so3(R_Z)
    n = len(T_A)
    lhs = np.zeros((3 * n, 6))
    rhs = np.zeros(3 * n)
    for i in range(n):
        lhs[3 * i:3 * i + 3, :3] = R_A[i]
        lhs[3 * i:3 * i + 3, 3:] = -np.eye(3)
        rhs[3 * i:3 * i + 3] = R_Z @ t_B[i] - t_A[i]
    t = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
    return transform_from_rt(R_X, t[:3]), transform_from_rt(R_Z, t[3:])


def solve_eye_to_hand(T_base_flange: FloatArray, T_camera_board: FloatArray,
                      use_opencv: bool | None = None) -> tuple[FloatArray, FloatArray]:
    """Eye-to-hand calibration: the fixed camera's ``T_camera_base`` and the board on the flange.

    Args:
        T_base_flange: (N, 4, 4) flange (board mount) poses in the base frame, from the robot.
        T_camera_board: (N, 4, 4) board poses in the camera frame, from PnP.
        use_opencv: True: ``cv2.calibrateRobotWorldHandEye`` (Shah), an error if it is not bound;
            False: ``shah_robot_world_hand_eye``; None: OpenCV when available.

    Returns:
        T_camera_base (4, 4) and T_flange_board (4, 4).

    Raises:
        InvalidInputError: fewer than 3 poses, mismatched counts, or OpenCV asked for but not bound.
    """
    T_base_flange = np.asarray(T_base_flange, dtype=np.float64)
    T_camera_board = np.asarray(T_camera_board, dtype=np.float64)
    if T_base_flange.ndim != 3 or T_base_flange.shape[1:] != (4, 4) or T_camera_board.shape != T_base_flange.shape:
        raise InvalidInputError(f"need two (N, 4, 4) stacks of equal N, got {T_base_flange.shape} and "
                                f"{T_camera_board.shape}")
    if len(T_base_flange) < 3:
        raise InvalidInputError(f"eye-to-hand calibration needs at least 3 poses, got {len(T_base_flange)}")
    T_board_camera = np.linalg.inv(T_camera_board)  # A_i: OpenCV's world2cam
    T_flange_base = np.linalg.inv(T_base_flange)  # B_i: OpenCV's base2gripper
    has_cv = hasattr(cv2, "calibrateRobotWorldHandEye")
    if use_opencv and not has_cv:
        raise InvalidInputError(f"this OpenCV ({cv2.__version__}) does not bind calibrateRobotWorldHandEye")
    if has_cv and use_opencv is not False:
        R_x, t_x, R_z, t_z = cv2.calibrateRobotWorldHandEye(
            list(T_board_camera[:, :3, :3]), list(T_board_camera[:, :3, 3:]),  # (3, 1) translations: OpenCV
            list(T_flange_base[:, :3, :3]), list(T_flange_base[:, :3, 3:]),  # 5.1's binding rejects (3,) ones
            method=cv2.CALIB_ROBOT_WORLD_HAND_EYE_SHAH)
        X, Z = transform_from_rt(R_x, np.ravel(t_x)), transform_from_rt(R_z, np.ravel(t_z))
    else:
        X, Z = shah_robot_world_hand_eye(T_board_camera, T_flange_base)
    return X, np.linalg.inv(Z)


def _pose(data: mujoco.MjData, body: int, T_base_world: FloatArray) -> FloatArray:
    return T_base_world @ transform_from_rt(data.xmat[body].reshape(3, 3).copy(), data.xpos[body].copy())


class MarkerBaseline:
    """Runs the marker baseline in an ``ArcCalibEnv`` whose scene carries a marker board.

    Args:
        env: the environment after ``reset`` (its scene must have ``marker_board`` set; its camera pose
            is the one to calibrate).
        rng: random generator (the aiming error and pose sampling); None seeds one from the env.
        config: settings.

    Raises:
        InvalidInputError: the env's scene has no marker board, or ``reset`` was not called.
    """

    def __init__(self, env: ArcCalibEnv, rng: np.random.Generator | None = None,
                 config: MarkerBaselineConfig | None = None):
        board = env.config.scene.marker_board
        if board is None:
            raise InvalidInputError("the marker baseline needs a scene with SceneConfig(marker_board=MarkerBoard())")
        if env.session.calibrator is None:
            raise InvalidInputError("call env.reset() before running the marker baseline")
        self.env, self.board = env, board
        self.config = config or MarkerBaselineConfig()
        self.rng = rng if rng is not None else np.random.default_rng(env.np_random.integers(2**31 - 1))
        s = env.scene
        self._mount = mujoco.mj_name2id(s.model, mujoco.mjtObj.mjOBJ_BODY, board.mount_body)
        self._board_body = mujoco.mj_name2id(s.model, mujoco.mjtObj.mjOBJ_BODY, BOARD_BODY)
        self._T_base_world = np.linalg.inv(s.robot.T_world_base)
        self._data = mujoco.MjData(s.model)
        self._data.qpos[:] = s.data.qpos
        c = self.config
        xi = np.concatenate([self.rng.normal(0.0, c.aim_rotation_error_rad, 3),
                             self.rng.normal(0.0, c.aim_position_error_m, 3)])
        # The aimed camera: the true one with a person's error, for choosing poses only.
        T_base_camera = np.linalg.inv(env.T_camera_base_true)
        T_base_camera_aim = perturb(T_base_camera, xi)
        self.T_camera_base_aim = np.linalg.inv(T_base_camera_aim)
        self._detector = make_detector(board, s.intrinsics, c)

    # -- poses ---------------------------------------------------------------------------------
    def flange_pose(self, q: FloatArray) -> FloatArray:
        """The mount body's pose in the base frame at q: (n_joints,) rad -> (4, 4)."""
        s = self.env.scene
        self._data.qpos[s.robot.qpos_adr] = q
        mujoco.mj_kinematics(s.model, self._data)
        return _pose(self._data, self._mount, self._T_base_world)

    def true_board_pose(self, q: FloatArray) -> FloatArray:
        """The board body's true pose in the base frame at q (for tests; never given to the solver)."""
        s = self.env.scene
        self._data.qpos[s.robot.qpos_adr] = q
        mujoco.mj_kinematics(s.model, self._data)
        return _pose(self._data, self._board_body, self._T_base_world)

    def _aim_ok(self, T_base_flange: FloatArray) -> float | None:
        """The tilt (rad) of the board from facing the aimed camera if the pose is usable, else None."""
        c, board, intr = self.config, self.board, self.env.scene.intrinsics
        T_camera_board = self.T_camera_base_aim @ T_base_flange @ board.T_mount_board
        w, h = board.size_m
        corners = np.array([[0, 0, 0], [w, 0, 0], [w, h, 0], [0, h, 0], [w / 2, h / 2, 0]], dtype=np.float64)
        pc = corners @ T_camera_board[:3, :3].T + T_camera_board[:3, 3]
        if np.any(pc[:, 2] < c.min_depth_m):
            return None
        uv = pc[:, :2] / pc[:, 2:] * np.diag(intr.K)[:2] + intr.K[:2, 2]
        m = c.image_margin_px
        if np.any(uv < m) or np.any(uv[:, 0] > intr.width - 1 - m) or np.any(uv[:, 1] > intr.height - 1 - m):
            return None
        to_camera = -pc[4] / np.linalg.norm(pc[4])  # from the board centre to the camera, camera frame
        face_normal = -T_camera_board[:3, 2]  # the printed face looks along the board's -z
        tilt = float(np.arccos(np.clip(face_normal @ to_camera, -1.0, 1.0)))
        return tilt if tilt <= c.max_tilt_rad else None

    def candidate_pool(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Random collision-free configurations with the board aimed at the camera.

        Returns:
            q (P, n_joints) rad, T_base_flange (P, 4, 4) and tilt (P,) rad; P <= pool_size (0 if none).
        """
        s, c = self.env.scene, self.config
        span = s.robot.upper - s.robot.lower
        lo, hi = s.robot.lower + c.limit_margin * span, s.robot.upper - c.limit_margin * span
        qs, poses, tilts = [], [], []
        for _ in range(c.max_samples):
            q = self.rng.uniform(lo, hi)
            T_base_flange = self.flange_pose(q)
            tilt = self._aim_ok(T_base_flange)
            if tilt is None or self.env.session.checker.in_collision(q)[0]:
                continue
            qs.append(q)
            poses.append(T_base_flange)
            tilts.append(tilt)
            if len(qs) >= c.pool_size:
                break
        n = s.robot.n_joints
        if not qs:
            return np.zeros((0, n)), np.zeros((0, 4, 4)), np.zeros(0)
        return np.array(qs), np.array(poses), np.array(tilts)

    # -- the run -------------------------------------------------------------------------------
    def run(self, n_poses: int) -> MarkerRun:
        """Visit up to ``n_poses`` poses with the board detected and calibrate after each.

        Returns:
            The run; ``len(run.views)`` < n_poses when the pool ran out of detectable poses.
        """
        if n_poses < 1:
            raise InvalidInputError(f"n_poses must be >= 1, got {n_poses}")
        s = self.env.scene
        out = MarkerRun(seconds={"select": 0.0, "render": 0.0, "detect": 0.0, "solve": 0.0})
        t0 = time.perf_counter()
        qs, poses, tilts = self.candidate_pool()
        out.seconds["select"] += time.perf_counter() - t0
        if len(qs) == 0:
            return out
        R = Rotation.from_matrix(poses[:, :3, :3])
        remaining = np.ones(len(qs), dtype=bool)
        nearest = np.full(len(qs), np.inf)  # smallest rotation angle to a visited pose
        saved = s.robot.q
        try:
            while len(out.views) < n_poses and remaining.any():
                t0 = time.perf_counter()
                if not out.views:
                    k = int(np.argmin(np.where(remaining, tilts, np.inf)))  # start facing the camera
                else:
                    k = int(np.argmax(np.where(remaining, nearest, -np.inf)))
                remaining[k] = False
                out.seconds["select"] += time.perf_counter() - t0
                t0 = time.perf_counter()
                s.robot.set_q(qs[k])
                image = s.render()
                t1 = time.perf_counter()
                det = detect_board(image, self.board, s.intrinsics, self._detector, self.config.min_corners)
                t2 = time.perf_counter()
                out.seconds["render"] += t1 - t0
                out.seconds["detect"] += t2 - t1
                if det is None or det.reprojection_px > self.config.max_reprojection_px:
                    out.rejected += 1
                    continue
                nearest = np.minimum(nearest, (R * R[k].inv()).magnitude())
                out.views.append(BoardView(qs[k].copy(), poses[k], det))
                out.estimates.append(self._solve(out))
                out.seconds["solve"] += time.perf_counter() - t2
        finally:
            s.robot.set_q(saved)
        return out

    def _solve(self, run: MarkerRun) -> FloatArray | None:
        if len(run.views) < 3:
            return None
        T_base_flange = np.array([v.T_base_flange for v in run.views])
        T_camera_board = np.array([v.detection.T_camera_board for v in run.views])
        try:
            T_camera_base, T_flange_board = solve_eye_to_hand(T_base_flange, T_camera_board)
        except (np.linalg.LinAlgError, cv2.error):
            return None
        run.T_flange_board = T_flange_board
        return T_camera_base

    def errors(self, run: MarkerRun) -> list[tuple[float, float] | None]:
        """True (rotation rad, translation m) error of each prefix estimate (simulation only)."""
        return [None if T_camera_base is None else pose_errors(T_camera_base, self.env.T_camera_base_true)
                for T_camera_base in run.estimates]
