"""ARC-Calib's geometric solver: keypoint tracks of exploratory motions -> T_camera_base.

Pure numpy/scipy/OpenCV; never imports MuJoCo. Pipeline modules, in the paper's order:
``conics`` -> ``circle_normals`` -> ``reference_lines`` (assembled per motion in ``motion``) ->
``calibration`` (linear, with pruning) -> ``refinement`` (bundle adjustment) -> ``convergence``;
``pipeline.Calibrator`` runs them incrementally. Conventions live in ``frames``. Beside them, ``outlines`` fits
the pose to the robot's occluding contours against the image's edges (not yet part of the Calibrator).
"""

from solver.calibration import (
    AxisCorrespondence,
    check_observable,
    consistency_errors,
    pose_family,
    solve_consensus,
    solve_linear,
    solve_minimal,
)
from solver.camera import normalized_from_pixels, pixels_from_camera_points
from solver.conics import ConicFit, fit_conics_independent, fit_conics_shared, fit_ellipse_direct
from solver.convergence import ConvergenceConfig, ConvergenceMonitor
from solver.errors import (
    ArcCalibError,
    DegenerateMotionError,
    DegenerateTrajectoryError,
    InsufficientMotionsError,
    InvalidInputError,
    NonRigidTracksError,
    TimeOffsetError,
    UnobservablePoseError,
)
from solver.frames import (
    check_transform,
    perturb,
    pose_difference,
    pose_errors,
    quaternion_xyzw_from_matrix,
    transform_from_rt,
)
from solver.kinematics import PANDA, AxisFunction, DHChain
from solver.motion import MotionConfig, MotionGeometry, estimate_motion_geometry
from solver.observations import CameraIntrinsics, KeypointTrack, MotionObservation
from solver.pipeline import CalibrationState, Calibrator, CalibratorConfig, FocalCheck, MotionReport
from solver.refinement import RefinementConfig, RefinementResult, build_track_set, pose_information, refine
from solver.synthetic import (
    SyntheticConfig,
    SyntheticMotion,
    SyntheticScene,
    d415_intrinsics,
    look_at,
    sample_camera_pose,
)

__all__ = [
    "PANDA",
    "ArcCalibError",
    "AxisCorrespondence",
    "AxisFunction",
    "CalibrationState",
    "Calibrator",
    "CalibratorConfig",
    "CameraIntrinsics",
    "ConicFit",
    "ConvergenceConfig",
    "ConvergenceMonitor",
    "DHChain",
    "DegenerateMotionError",
    "DegenerateTrajectoryError",
    "FocalCheck",
    "InsufficientMotionsError",
    "InvalidInputError",
    "KeypointTrack",
    "MotionConfig",
    "MotionGeometry",
    "MotionObservation",
    "MotionReport",
    "NonRigidTracksError",
    "RefinementConfig",
    "RefinementResult",
    "SyntheticConfig",
    "SyntheticMotion",
    "SyntheticScene",
    "TimeOffsetError",
    "UnobservablePoseError",
    "build_track_set",
    "check_observable",
    "check_transform",
    "consistency_errors",
    "d415_intrinsics",
    "estimate_motion_geometry",
    "fit_conics_independent",
    "fit_conics_shared",
    "fit_ellipse_direct",
    "look_at",
    "normalized_from_pixels",
    "perturb",
    "pose_information",
    "pixels_from_camera_points",
    "pose_difference",
    "pose_family",
    "pose_errors",
    "quaternion_xyzw_from_matrix",
    "refine",
    "sample_camera_pose",
    "solve_consensus",
    "solve_linear",
    "solve_minimal",
    "transform_from_rt",
]
