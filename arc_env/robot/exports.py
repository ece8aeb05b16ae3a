"""A calibration result in the forms ROS users load: easy_handeye2 ``.calib``, a TF line, a URDF joint.

Frames, stated once. ARC-Calib estimates ``T_camera_base``: ``p_camera = T_camera_base @ p_base``, where
the camera frame is the OpenCV *optical* frame (x right, y down, z forward) -- REP 103's
``*_optical_frame`` (e.g. ``camera_color_optical_frame``), not the camera body frame ``camera_link``
(x forward, y left, z up). A TF transform parent -> child holds the child's pose in the parent's frame,
i.e. the map from child coordinates to parent coordinates. With the robot base as parent and the optical
frame as child, every export below therefore carries ``T_base_camera = inv(T_camera_base)``.

Safety. Every frame name that reaches an export is checked against ROS naming rules
(``check_frame_name``: letters, digits, ``_`` and ``/``, not starting with a digit), and every export is
produced by a serializer that quotes or escapes on its own (YAML: ``yaml.safe_dump``; shell:
``shlex.join``; URDF: ElementTree), so a name from a robot file can never become a command or markup.

Each function returns text; ``result_dict`` builds ``result.json`` (``docs/recording-format.md``,
"Calibration result"). ``write_files_atomic`` is the one writer of every output: all files of a run are
written into a temporary folder beside their targets and moved into place only when all are written;
if any step fails, none of the new files remains and files they were to replace are put back.
"""

from __future__ import annotations

import contextlib
import os
import re
import shlex
import shutil
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from solver.arrays import FloatArray
from solver.errors import InvalidInputError
from solver.frames import check_transform, quaternion_xyzw_from_matrix
from solver.pipeline import Calibrator, FocalCheck

#: Result file format written by ``calibrate`` and ``run``.
RESULT_FORMAT = "arc-calib result 1"

#: Default child frame: the colour camera's optical frame as RealSense's ROS 2 driver names it.
DEFAULT_CAMERA_FRAME = "camera_color_optical_frame"
#: ROS names: letters, digits, underscores and slashes, not starting with a digit (REP 144, ROS 2 names).
_FRAME_NAME = re.compile(r"[A-Za-z_/][A-Za-z0-9_/]*")


def check_frame_name(name: object, what: str) -> str:
    """``name`` if it is a valid ROS frame name, else InvalidInputError saying which name and why.

    Args:
        name: the candidate (a robot's base body, ``--base-frame``, ``--camera-frame``, ...).
        what: where it comes from, for the message.
    """
    if not isinstance(name, str) or not _FRAME_NAME.fullmatch(name):
        raise InvalidInputError(f"{what} {name!r} is not a valid ROS frame name: use letters, digits, '_' and '/', "
                                "not starting with a digit")
    return name


@dataclass(frozen=True)
class ParentChild:
    """The TF edge the exports describe.

    Attributes:
        T_base_camera: (4, 4) float64: the optical frame's pose in the base frame (``inv(T_camera_base)``).
        base_frame: the parent frame (the robot's base link); a valid ROS frame name.
        camera_frame: the child frame: the camera's *optical* frame (OpenCV / REP 103 ``*_optical_frame``);
            a valid ROS frame name.
    """

    T_base_camera: FloatArray
    base_frame: str
    camera_frame: str = DEFAULT_CAMERA_FRAME

    def __post_init__(self) -> None:
        check_frame_name(self.base_frame, "the base frame")
        check_frame_name(self.camera_frame, "the camera frame")

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


def _number(v: float) -> float:
    """A float rounded to the 9 significant digits every export prints."""
    return float(_f(v))


#: The header of every text export: what the transform is (no name from any input appears in it).
_HEADER = ("ARC-Calib markerless calibration. The transform is the pose of the camera's OpenCV optical frame",
           "(x right, y down, z forward) in the robot base frame, i.e. T_base_camera = inv(T_camera_base);",
           "TF parent: the base frame, child: the optical frame. Metres; quaternion (x, y, z, w).")


def easy_handeye2_calib(edge: ParentChild, name: str = "arc_calib") -> str:
    """An easy_handeye2 ``.calib`` YAML (eye-on-base): parameters, and transform base -> tracking frame.

    easy_handeye2 publishes ``transform`` with ``robot_base_frame`` as parent and ``tracking_base_frame``
    as child, so the tracking frame is the camera's optical frame and the transform is ``T_base_camera``.
    ARC-Calib uses no marker and no effector: those two fields name nothing and are left empty strings.
    """
    t, q = edge.translation, edge.quaternion_xyzw
    data = {
        "parameters": {
            "name": check_frame_name(name, "the calibration name"),
            "calibration_type": "eye_on_base",
            "robot_base_frame": edge.base_frame,
            "robot_effector_frame": "",
            "tracking_base_frame": edge.camera_frame,
            "tracking_marker_frame": "",
            "freehand_robot_movement": False,
            "move_group_namespace": "/",
            "move_group": "manipulator",
        },
        "transform": {
            "translation": {k: _number(v) for k, v in zip("xyz", t, strict=True)},
            "rotation": {k: _number(v) for k, v in zip("xyzw", q, strict=True)},
        },
    }
    comments = "".join(f"# {line}\n" for line in (*_HEADER, "easy_handeye2 format (eye on base)."))
    return comments + yaml.safe_dump(data, sort_keys=False, default_flow_style=False)


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
    """The full ``ros2 run tf2_ros static_transform_publisher ...`` line, every word shell-quoted."""
    return shlex.join(["ros2", "run", "tf2_ros", "static_transform_publisher",
                       *static_transform_publisher_args(edge)])


def urdf_joint(edge: ParentChild, joint_name: str | None = None) -> str:
    """A URDF fixed joint base -> optical frame (and the optical frame's empty link), built with ElementTree."""
    t, rpy = edge.translation, edge.rpy
    joint_name = check_frame_name(joint_name or f"{edge.base_frame}_to_{edge.camera_frame}", "the URDF joint name")
    comment = ET.Comment(" " + "\n     ".join([*_HEADER, "If your camera's driver already publishes this optical frame "
                                                  "under its camera_link, do not add this joint:",
                                                  "a TF frame has one parent (see docs/exports.md)."]) + " ")
    link = ET.Element("link", name=edge.camera_frame)
    joint = ET.Element("joint", name=joint_name, type="fixed")
    ET.SubElement(joint, "parent", link=edge.base_frame)
    ET.SubElement(joint, "child", link=edge.camera_frame)
    ET.SubElement(joint, "origin", xyz=" ".join(_f(v) for v in t), rpy=" ".join(_f(v) for v in rpy))
    ET.indent(joint)
    return "\n".join(ET.tostring(e, encoding="unicode") for e in (comment, link, joint)) + "\n"


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
            "static_transform_publisher": ("#!/bin/sh\n" + "".join(f"# {line}\n" for line in _HEADER)
                                           + static_transform_publisher_command(edge) + "\n"),
            "urdf_joint": urdf_joint(edge)}


def _existing_ancestor(path: Path) -> Path:
    for parent in path.parents:
        if parent.is_dir():
            return parent
    return Path(path.anchor or ".")


def write_files_atomic(files: dict[Path, str | bytes]) -> None:
    """Commit every file (text or bytes) of one run together, or none of them.

    The files are first written into a temporary folder beside their targets (in the nearest existing
    directory, so the moves are renames on one file system); only when all are written are they moved
    into place, creating missing target directories. If anything fails, the files already moved are
    taken back out, files they replaced are restored, directories made for them are removed, and the
    error is raised: none of the new files remains.

    Raises:
        InvalidInputError: a target is an existing directory (nothing is written).
        OSError: writing or moving failed (nothing is left behind).
    """
    targets = [Path(p) for p in files]
    for path in targets:
        if path.is_dir():
            raise InvalidInputError(f"{path}: is a directory, not a file to write")
    staging: dict[Path, Path] = {}  # existing ancestor -> temporary folder in it
    staged: list[tuple[Path, Path]] = []  # (temporary file, target)
    moved: list[tuple[Path, Path | None]] = []  # (target, backup of what it replaced)
    made: list[Path] = []  # directories created for targets, outermost first
    try:
        for content, target in zip(files.values(), targets, strict=True):
            base = _existing_ancestor(target)
            if base not in staging:
                staging[base] = Path(tempfile.mkdtemp(prefix=".arc-calib-", dir=base))
            tmp = staging[base] / f"{len(staged):04d}"
            if isinstance(content, bytes):
                tmp.write_bytes(content)
            else:
                tmp.write_text(content)
            staged.append((tmp, target))
        for tmp, target in staged:
            for parent in reversed(target.parents):
                if not parent.exists():
                    parent.mkdir()
                    made.append(parent)
            backup = None
            if target.exists() or target.is_symlink():
                backup = tmp.with_name(tmp.name + ".previous")
                os.replace(target, backup)
            try:
                os.replace(tmp, target)
            except BaseException:
                if backup is not None:
                    os.replace(backup, target)
                raise
            moved.append((target, backup))
    except BaseException:
        for target, backup in reversed(moved):
            with contextlib.suppress(OSError):
                target.unlink()
            if backup is not None:
                os.replace(backup, target)
        for directory in reversed(made):
            with contextlib.suppress(OSError):
                directory.rmdir()
        raise
    finally:
        for folder in staging.values():
            shutil.rmtree(folder, ignore_errors=True)


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
    focal_check: FocalCheck | None

    @property
    def n_accepted(self) -> int:
        """Motions informing the estimate."""
        ...


def result_dict(run: FinishedCalibration, edge: ParentChild, exports: dict[str, Path],
                unusable: str = "") -> dict[str, Any]:
    """The result JSON (see docs/recording-format.md, "Calibration result").

    ``unusable``: "" for a usable result, else why not (``"usable": false``; covariance and 1-sigma are
    null when the bundle adjustment gave none).
    """
    s = run.calibrator.state
    T_camera_base = s.T_camera_base
    assert T_camera_base is not None
    return {
        "format": RESULT_FORMAT,
        "usable": not unusable,
        "unusable_reason": unusable,
        "source": run.source,
        "convention": ("p_camera = T_camera_base @ p_base; camera frame = OpenCV optical frame (x right, y down, "
                       "z forward); metres, radians; quaternions (x, y, z, w)"),
        "T_camera_base": T_camera_base.tolist(),
        "translation": T_camera_base[:3, 3].tolist(),
        "quaternion": quaternion_xyzw_from_matrix(T_camera_base[:3, :3]).tolist(),
        "T_base_camera": edge.T_base_camera.tolist(),
        "covariance": None if s.covariance is None else s.covariance.tolist(),
        "covariance_parameters": ("xi = (omega rad, tau m), camera frame: R = Exp(omega) R_hat, t = t_hat + tau "
                                  "(T_camera_base)"),
        "std": None if s.std is None else {"rotation_deg": np.degrees(s.std[:3]).tolist(),
                                           "translation_mm": (s.std[3:] * 1e3).tolist()},
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
        "intrinsics_check": None if run.focal_check is None else {
            "focal_fits": run.focal_check.fits, "best_focal_scale": run.focal_check.best_scale,
            "rms_given_px": run.focal_check.rms_given_px, "rms_best_px": run.focal_check.rms_best_px},
        "exports": {k: p.name for k, p in exports.items()},
        "seconds": {k: round(v, 2) for k, v in run.seconds.items()},
    }
