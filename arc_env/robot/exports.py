"""A calibration result in the forms ROS users load: easy_handeye2 ``.calib``, a TF line, a URDF joint.

Frames, stated once. ARC-Calib estimates ``T_camera_base``: ``p_camera = T_camera_base @ p_base``, where
the camera frame is the OpenCV *optical* frame (x right, y down, z forward) -- REP 103's
``*_optical_frame`` (e.g. ``camera_color_optical_frame``), not the camera body frame ``camera_link``
(x forward, y left, z up). A TF transform parent -> child holds the child's pose in the parent's frame,
i.e. the map from child coordinates to parent coordinates. With the robot base as parent and the optical
frame as child, every export below therefore carries ``T_base_camera = inv(T_camera_base)``.

Each function returns text; ``result_dict`` builds ``result.json`` (``docs/recording-format.md``,
"Calibration result"). ``write_files_atomic`` is the one writer of every output: temporary files
beside the targets, renamed into place only when all are written.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from scipy.spatial.transform import Rotation

from solver.arrays import FloatArray
from solver.frames import check_transform, quaternion_xyzw_from_matrix
from solver.pipeline import Calibrator

#: Result file format written by ``calibrate`` and ``run``.
RESULT_FORMAT = "arc-calib result 1"

#: Default child frame: the colour camera's optical frame as RealSense's ROS 2 driver names it.
DEFAULT_CAMERA_FRAME = "camera_color_optical_frame"


@dataclass(frozen=True)
class ParentChild:
    """The TF edge the exports describe.

    Attributes:
        T_base_camera: (4, 4) float64: the optical frame's pose in the base frame (``inv(T_camera_base)``).
        base_frame: the parent frame (the robot's base link).
        camera_frame: the child frame: the camera's *optical* frame (OpenCV / REP 103 ``*_optical_frame``).
    """

    T_base_camera: FloatArray
    base_frame: str
    camera_frame: str = DEFAULT_CAMERA_FRAME

    @classmethod
    def from_T_camera_base(cls, T_camera_base: FloatArray, base_frame: str,
                           camera_frame: str = DEFAULT_CAMERA_FRAME) -> ParentChild:
        """The edge base -> camera optical frame from ARC-Calib's ``T_camera_base`` (4, 4)."""
        T_camera_base = check_transform(T_camera_base, "T_camera_base")
        return cls(np.linalg.inv(T_camera_base), base_frame, camera_frame)

    @property
    def translation(self) -> FloatArray:
        """(3,) float64, m: the optical centre in the base frame."""
        return self.T_base_camera[:3, 3].copy()

    @property
    def quaternion_xyzw(self) -> FloatArray:
        """(4,) float64, (x, y, z, w), w >= 0: the optical frame's orientation in the base frame."""
        return quaternion_xyzw_from_matrix(self.T_base_camera[:3, :3])

    @property
    def rpy(self) -> FloatArray:
        """(3,) float64, rad: URDF's roll, pitch, yaw (fixed axes x, y, z: R = Rz(yaw) Ry(pitch) Rx(roll))."""
        return Rotation.from_matrix(self.T_base_camera[:3, :3]).as_euler("xyz")


def _f(v: float) -> str:
    return f"{float(v):.9g}"


def easy_handeye2_calib(edge: ParentChild, name: str = "arc_calib") -> str:
    """An easy_handeye2 ``.calib`` YAML (eye-on-base): parameters, and transform base -> tracking frame.

    easy_handeye2 publishes ``transform`` with ``robot_base_frame`` as parent and ``tracking_base_frame``
    as child, so the tracking frame is the camera's optical frame and the transform is ``T_base_camera``.
    ARC-Calib uses no marker and no effector: those two fields name nothing and are left empty strings.
    """
    t, q = edge.translation, edge.quaternion_xyzw
    return (
        "# ARC-Calib markerless calibration, easy_handeye2 format (eye on base).\n"
        f"# transform: pose of {edge.camera_frame} (OpenCV optical frame: x right, y down, z forward)\n"
        f"# in {edge.base_frame}, i.e. T_base_camera = inv(T_camera_base); TF parent {edge.base_frame},\n"
        f"# child {edge.camera_frame}. Metres; quaternion (x, y, z, w).\n"
        "parameters:\n"
        f"  name: {name}\n"
        "  calibration_type: eye_on_base\n"
        f"  robot_base_frame: {edge.base_frame}\n"
        "  robot_effector_frame: ''\n"
        f"  tracking_base_frame: {edge.camera_frame}\n"
        "  tracking_marker_frame: ''\n"
        "  freehand_robot_movement: false\n"
        "  move_group_namespace: /\n"
        "  move_group: manipulator\n"
        "transform:\n"
        "  translation:\n"
        f"    x: {_f(t[0])}\n"
        f"    y: {_f(t[1])}\n"
        f"    z: {_f(t[2])}\n"
        "  rotation:\n"
        f"    x: {_f(q[0])}\n"
        f"    y: {_f(q[1])}\n"
        f"    z: {_f(q[2])}\n"
        f"    w: {_f(q[3])}\n"
    )


def static_transform_publisher_args(edge: ParentChild) -> list[str]:
    """Arguments of ``ros2 run tf2_ros static_transform_publisher``, in its named-argument form.

    That form (ROS 2 Humble and later) takes the translation, the quaternion (x, y, z, w), then the
    parent (``--frame-id``) and the child (``--child-frame-id``).
    """
    t, q = edge.translation, edge.quaternion_xyzw
    return ["--x", _f(t[0]), "--y", _f(t[1]), "--z", _f(t[2]),
            "--qx", _f(q[0]), "--qy", _f(q[1]), "--qz", _f(q[2]), "--qw", _f(q[3]),
            "--frame-id", edge.base_frame, "--child-frame-id", edge.camera_frame]


def static_transform_publisher_command(edge: ParentChild) -> str:
    """The full ``ros2 run tf2_ros static_transform_publisher ...`` line."""
    return "ros2 run tf2_ros static_transform_publisher " + " ".join(static_transform_publisher_args(edge))


def urdf_joint(edge: ParentChild, joint_name: str | None = None) -> str:
    """A URDF fixed joint base -> optical frame (and the optical frame's empty link)."""
    t, rpy = edge.translation, edge.rpy
    joint_name = joint_name or f"{edge.base_frame}_to_{edge.camera_frame}"
    return (
        f"<!-- ARC-Calib: {edge.camera_frame} is the camera's OpenCV optical frame (x right, y down,\n"
        f"     z forward), posed in {edge.base_frame}: T_base_camera = inv(T_camera_base). If your camera's\n"
        f"     driver already publishes {edge.camera_frame} under its camera_link, do not add this joint:\n"
        "     a TF frame has one parent (see docs/exports.md). -->\n"
        f'<link name="{edge.camera_frame}"/>\n'
        f'<joint name="{joint_name}" type="fixed">\n'
        f'  <parent link="{edge.base_frame}"/>\n'
        f'  <child link="{edge.camera_frame}"/>\n'
        f'  <origin xyz="{_f(t[0])} {_f(t[1])} {_f(t[2])}" rpy="{_f(rpy[0])} {_f(rpy[1])} {_f(rpy[2])}"/>\n'
        "</joint>\n"
    )


def export_paths(output: Path) -> dict[str, Path]:
    """The files written beside ``output`` (result.json): .calib, .tf.sh, .urdf.xml."""
    output = Path(output)
    stem = output.with_suffix("") if output.suffix == ".json" else output
    return {"easy_handeye2": stem.with_name(stem.name + ".calib"),
            "static_transform_publisher": stem.with_name(stem.name + ".tf.sh"),
            "urdf_joint": stem.with_name(stem.name + ".urdf.xml")}


def export_texts(edge: ParentChild) -> dict[str, str]:
    """The text of every export, keyed like ``export_paths``."""
    return {"easy_handeye2": easy_handeye2_calib(edge),
            "static_transform_publisher": (
                "#!/bin/sh\n"
                f"# Publish the ARC-Calib result: parent {edge.base_frame}, child {edge.camera_frame} (the\n"
                "# camera's OpenCV optical frame); the transform is T_base_camera = inv(T_camera_base).\n"
                + static_transform_publisher_command(edge) + "\n"),
            "urdf_joint": urdf_joint(edge)}


def write_files_atomic(files: dict[Path, str | bytes]) -> None:
    """Write every file (text or bytes) through a temporary file beside it, then rename them all.

    The renames start only when every file is written, so a failure leaves no file half-written.
    """
    tmps: list[tuple[Path, Path]] = []
    try:
        for path, content in files.items():
            tmp = path.with_name(f".{path.name}.tmp")
            tmps.append((tmp, path))
            if isinstance(content, bytes):
                tmp.write_bytes(content)
            else:
                tmp.write_text(content)
        for tmp, path in tmps:
            tmp.replace(path)
    finally:
        for tmp, _ in tmps:
            tmp.unlink(missing_ok=True)


class MotionRow(Protocol):
    """One motion's line of ``result.json`` (``arc_env.robot.session.MotionDiagnostic``)."""

    motion: str
    joint: str | None
    frames: int
    tracks: int
    accepted: bool
    reason: str
    inlier_tracks: int
    linear: bool
    axis_error_rad: float | None
    plane_distance_m: float | None
    note: str


class FinishedCalibration(Protocol):
    """What ``result.json`` is made of (``arc_env.robot.session.CalibrationRun``)."""

    source: str
    calibrator: Calibrator
    diagnostics: Sequence[MotionRow]
    seconds: dict[str, float]

    @property
    def n_accepted(self) -> int:
        """Motions informing the estimate."""
        ...


def result_dict(run: FinishedCalibration, edge: ParentChild, exports: dict[str, Path]) -> dict[str, Any]:
    """The result JSON (see docs/recording-format.md, "Calibration result")."""
    s = run.calibrator.state
    T_camera_base = s.T_camera_base
    assert T_camera_base is not None and s.covariance is not None and s.std is not None
    return {
        "format": RESULT_FORMAT,
        "source": run.source,
        "convention": ("p_camera = T_camera_base @ p_base; camera frame = OpenCV optical frame (x right, y down, "
                       "z forward); metres, radians; quaternions (x, y, z, w)"),
        "T_camera_base": T_camera_base.tolist(),
        "translation": T_camera_base[:3, 3].tolist(),
        "quaternion": quaternion_xyzw_from_matrix(T_camera_base[:3, :3]).tolist(),
        "T_base_camera": edge.T_base_camera.tolist(),
        "covariance": s.covariance.tolist(),
        "covariance_parameters": ("xi = (omega rad, tau m), camera frame: R = Exp(omega) R_hat, t = t_hat + tau "
                                  "(T_camera_base)"),
        "std": {"rotation_deg": np.degrees(s.std[:3]).tolist(), "translation_mm": (s.std[3:] * 1e3).tolist()},
        "rms_reprojection_px": s.rms_px,
        "stage": s.stage,
        "converged": s.converged,
        "frames": {"parent": edge.base_frame, "child": edge.camera_frame,
                   "child_is": "the camera's OpenCV optical frame (REP 103 *_optical_frame), not camera_link"},
        "motions": {"total": len(run.diagnostics), "accepted": run.n_accepted,
                    "rejected": len(run.diagnostics) - run.n_accepted},
        "per_motion": [
            {"motion": d.motion, "joint": d.joint, "frames": d.frames, "tracks": d.tracks, "accepted": d.accepted,
             "reason": d.reason, "inlier_tracks": d.inlier_tracks, "linear_stage": d.linear,
             "axis_error_rad": d.axis_error_rad, "plane_distance_m": d.plane_distance_m, "note": d.note}
            for d in run.diagnostics],
        "exports": {k: p.name for k, p in exports.items()},
        "seconds": {k: round(v, 2) for k, v in run.seconds.items()},
    }
