"""A calibration result in the forms ROS users load: easy_handeye2, TF, URDF, xacro and a ROS 2 launch file.

Frames, stated once. ARC-Calib estimates ``T_camera_base``: ``p_camera = T_camera_base @ p_base``, where
the camera frame is the OpenCV *optical* frame (x right, y down, z forward) -- REP 103's
``*_optical_frame`` (e.g. ``camera_color_optical_frame``), not the camera body frame ``camera_link``
(x forward, y left, z up). A TF transform parent -> child holds the child's pose in the parent's frame,
i.e. the map from child coordinates to parent coordinates. With the robot base as parent and the optical
frame as child, every export below therefore carries ``T_base_camera = inv(T_camera_base)``. With a
camera link frame (``ParentChild.to_camera_link``) the child is the camera's body frame instead and the
exports carry ``T_base_link = T_base_camera @ inv(R_LINK_OPTICAL)`` (the ideal REP 103 rotation, no offset).

Safety. Every frame name that reaches an export is checked against ROS naming rules
(``check_frame_name``: letters, digits, ``_`` and ``/``, not starting with a digit), a calibration name
against file-name rules (``check_calib_name``), and every export is produced by a serializer that quotes
or escapes on its own (YAML: ``yaml.safe_dump``; shell: ``shlex.join``; URDF and xacro: ElementTree;
the launch file: Python literals by ``repr``), so a name from a robot file can never become a command,
markup or code.

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
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
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
#: The easy_handeye2 name when nothing better is known (``run`` without ``--record``).
DEFAULT_CALIB_NAME = "arc_calib"
#: Base bodies of shipped models whose ROS description names the link differently: the gymnasium-robotics
#: Panda's MJCF prefixes its bodies (``panda0_link0``); franka_description's URDF calls it ``panda_link0``.
ROS_BASE_FRAMES = {"panda0_link0": "panda_link0"}
#: Where easy_handeye2's ``publish.launch.py name:=NAME`` reads ``NAME.calib``, relative to the home folder.
EASY_HANDEYE2_CALIBRATIONS = Path(".ros2", "easy_handeye2", "calibrations")
#: The camera's optical axes in its ``camera_link`` frame (REP 103): columns are optical x (right) = -y_link,
#: optical y (down) = -z_link, optical z (forward) = +x_link. ``p_link = R_LINK_OPTICAL @ p_optical``.
R_LINK_OPTICAL = np.array([[0.0, 0.0, 1.0],
                           [-1.0, 0.0, 0.0],
                           [0.0, -1.0, 0.0]])
#: ROS names: letters, digits, underscores and slashes, not starting with a digit (REP 144, ROS 2 names).
_FRAME_NAME = re.compile(r"[A-Za-z_/][A-Za-z0-9_/]*")
#: Calibration names become file names (``NAME.calib``) and a launch argument: letters, digits, ``_``, ``-``.
_CALIB_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_-]{0,99}")
#: The xacro namespace (xacro's own URI).
XACRO_NS = "http://www.ros.org/wiki/xacro"
#: The macro the ``.urdf.xacro`` export defines.
XACRO_MACRO = "arc_calib_camera"


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


def check_calib_name(name: object, what: str) -> str:
    """``name`` if it is a safe calibration name (a file name stem), else InvalidInputError.

    Letters, digits, ``_`` and ``-``, 1 to 100 characters, not starting with ``-``: no path separator, no
    dot, nothing a shell or a launch argument would read specially.
    """
    if not isinstance(name, str) or not _CALIB_NAME.fullmatch(name):
        raise InvalidInputError(f"{what} {name!r} is not a valid calibration name: use 1 to 100 letters, digits, "
                                "'_' and '-', not starting with '-'")
    return name


def calib_name_from(source: str) -> str:
    """A calibration name made from a recording's (or any) name: other characters become ``_``.

    ``"lab rig/2024-05-01"`` gives ``lab_rig_2024-05-01``; an empty result gives ``DEFAULT_CALIB_NAME``.
    """
    name = re.sub(r"[^A-Za-z0-9_-]", "_", source).lstrip("-")[:100]
    return name or DEFAULT_CALIB_NAME


def ros_base_frame(base_body: str) -> str:
    """The TF name of a robot model's base body: the body's own name, except the ``ROS_BASE_FRAMES`` renames.

    A URDF's links keep their names in the model, so a URDF robot's base frame is its root link's name as
    the robot's ROS description has it. An MJCF may name bodies otherwise: give ``--base-frame`` then.
    """
    return ROS_BASE_FRAMES.get(base_body, base_body)


def easy_handeye2_install_path(name: str, home: Path | None = None) -> Path:
    """``~/.ros2/easy_handeye2/calibrations/NAME.calib``, where ``publish.launch.py name:=NAME`` reads it.

    Args:
        name: the calibration name (checked with ``check_calib_name``).
        home: the home folder (default: ``Path.home()``, i.e. ``$HOME``).
    """
    folder = (Path.home() if home is None else Path(home)) / EASY_HANDEYE2_CALIBRATIONS
    return folder / (check_calib_name(name, "the calibration name") + ".calib")


@dataclass(frozen=True)
class ParentChild:
    """The TF edge the exports describe.

    Attributes:
        T_base_camera: (4, 4) float64, metres: the child frame's pose in the base frame (``inv(T_camera_base)``
            for the optical frame; ``inv(T_camera_base) @ inv(R_LINK_OPTICAL)`` for a camera link).
        base_frame: the parent frame (the robot's base link); a valid ROS frame name.
        camera_frame: the child frame: the camera's *optical* frame (OpenCV / REP 103 ``*_optical_frame``),
            or its body frame ``camera_link`` when ``optical`` is False; a valid ROS frame name.
        optical: whether the child is the optical frame (True) or the camera link (False).
    """

    T_base_camera: FloatArray
    base_frame: str
    camera_frame: str = DEFAULT_CAMERA_FRAME
    optical: bool = True

    def __post_init__(self) -> None:
        check_frame_name(self.base_frame, "the base frame")
        check_frame_name(self.camera_frame, "the camera frame")
        if self.base_frame == self.camera_frame:
            raise InvalidInputError(f"the base frame and the camera frame are both {self.base_frame!r}: a TF edge "
                                    "joins two different frames")

    @classmethod
    def from_T_camera_base(cls, T_camera_base: FloatArray, base_frame: str,
                           camera_frame: str = DEFAULT_CAMERA_FRAME) -> ParentChild:
        """The edge base -> camera optical frame from ARC-Calib's ``T_camera_base`` (4, 4), metres."""
        T_camera_base = check_transform(T_camera_base, "T_camera_base")
        return cls(np.linalg.inv(T_camera_base), base_frame, camera_frame)

    def to_camera_link(self, link_frame: str) -> ParentChild:
        """The edge base -> ``link_frame``, the camera's REP 103 body frame (x forward, y left, z up).

        For drivers that publish ``camera_link`` -> optical frame themselves: the optical frame's pose
        composed with the ideal rotation between the two, ``T_base_link = T_base_optical @ T_optical_link``
        with ``T_optical_link = [R_LINK_OPTICAL.T, 0]``. The driver's own offset between the two frames
        (a few mm to cm) is not known here and is taken as zero.
        """
        if not self.optical:
            raise InvalidInputError("the edge already ends at the camera link")
        T_optical_link = np.eye(4)
        T_optical_link[:3, :3] = R_LINK_OPTICAL.T
        return replace(self, T_base_camera=self.T_base_camera @ T_optical_link,
                       camera_frame=check_frame_name(link_frame, "the camera link frame"), optical=False)

    @property
    def translation(self) -> FloatArray:
        """(3,) float64, m: the child frame's origin (the optical centre) in the base frame."""
        return self.T_base_camera[:3, 3].copy()

    @property
    def quaternion_xyzw(self) -> FloatArray:
        """(4,) float64, (x, y, z, w), w >= 0: the child frame's orientation in the base frame."""
        return quaternion_xyzw_from_matrix(self.T_base_camera[:3, :3])

    @property
    def rpy(self) -> FloatArray:
        """(3,) float64, rad: URDF's roll, pitch, yaw (fixed axes x, y, z: R = Rz(yaw) Ry(pitch) Rx(roll))."""
        return Rotation.from_matrix(self.T_base_camera[:3, :3]).as_euler("xyz")

    @property
    def joint_name(self) -> str:
        """The URDF joint's name: ``BASE_to_CHILD``."""
        return f"{self.base_frame}_to_{self.camera_frame}"


def _f(v: float) -> str:
    return f"{float(v):.9g}"


def _number(v: float) -> float:
    """A float rounded to the 9 significant digits every export prints."""
    return float(_f(v))


def _header(edge: ParentChild) -> tuple[str, ...]:
    """The header of every text export: what the transform is (no name from any input appears in it)."""
    if edge.optical:
        return ("ARC-Calib markerless calibration. The transform is the pose of the camera's OpenCV optical frame",
                "(x right, y down, z forward) in the robot base frame, i.e. T_base_camera = inv(T_camera_base);",
                "TF parent: the base frame, child: the optical frame. Metres; quaternion (x, y, z, w).")
    return ("ARC-Calib markerless calibration. The transform is the pose of the camera's REP 103 body frame",
            "camera_link (x forward, y left, z up) in the robot base frame: the estimated optical frame's pose",
            "composed with the ideal optical -> camera_link rotation (no offset between the two).",
            "TF parent: the base frame, child: the camera link. Metres; quaternion (x, y, z, w).")


def easy_handeye2_calib(edge: ParentChild, name: str = DEFAULT_CALIB_NAME) -> str:
    """An easy_handeye2 ``.calib`` YAML (eye-on-base): parameters, and transform base -> tracking frame.

    easy_handeye2 publishes ``transform`` with ``robot_base_frame`` as parent and ``tracking_base_frame``
    as child, so the tracking frame is the camera's frame (the child) and the transform is ``T_base_camera``.
    ARC-Calib uses no marker and no effector: those two fields name nothing and are left empty strings.
    Every number is a YAML float (``yaml.safe_load`` gives ``float``, also for values like 1e-05).
    """
    t, q = edge.translation, edge.quaternion_xyzw
    data = {
        "parameters": {
            "name": check_calib_name(name, "the calibration name"),
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
    comments = "".join(f"# {line}\n" for line in (*_header(edge), "easy_handeye2 format (eye on base)."))
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


def tf_script(edge: ParentChild) -> str:
    """``result.tf.sh``: a POSIX shell script that runs the static publisher (written executable)."""
    return ("#!/bin/sh\n" + "".join(f"# {line}\n" for line in _header(edge))
            + "exec " + static_transform_publisher_command(edge) + "\n")


def _joint(edge: ParentChild, parent: str, child: str, name: str) -> ET.Element:
    joint = ET.Element("joint", name=name, type="fixed")
    ET.SubElement(joint, "parent", link=parent)
    ET.SubElement(joint, "child", link=child)
    ET.SubElement(joint, "origin", xyz=" ".join(_f(v) for v in edge.translation),
                  rpy=" ".join(_f(v) for v in edge.rpy))
    return joint


def _xml(root: ET.Element) -> str:
    ET.indent(root)
    return '<?xml version="1.0"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def _comment(edge: ParentChild, *more: str) -> ET.Element:
    """An XML comment of fixed text (no input's name).

    ElementTree does not escape comments and XML forbids ``--`` in one, so none of the texts holds it.
    """
    text = "\n     ".join([*_header(edge), *more])
    assert "--" not in text and not text.endswith("-")
    return ET.Comment(" " + text + " ")


_ONE_PARENT = ("If your camera's driver already publishes this frame under another parent, do not add this",
               "joint: a TF frame has one parent (docs/exports.md: the camera link option).")


def urdf_robot(edge: ParentChild, robot_name: str = DEFAULT_CALIB_NAME) -> str:
    """A standalone URDF: ``<robot>`` with the base link, the camera frame's link and the fixed joint between.

    It passes ``check_urdf`` on its own; to add the camera to an existing robot description use the xacro
    macro (``xacro_macro``) instead. Built with ElementTree: every name is escaped by the serializer.
    """
    robot = ET.Element("robot", name=check_calib_name(robot_name, "the URDF robot name"))
    robot.append(_comment(edge, *_ONE_PARENT))
    ET.SubElement(robot, "link", name=edge.base_frame)
    ET.SubElement(robot, "link", name=edge.camera_frame)
    robot.append(_joint(edge, edge.base_frame, edge.camera_frame, edge.joint_name))
    return _xml(robot)


def urdf_joint(edge: ParentChild) -> str:
    """The fixed joint base -> camera frame alone (a fragment, for tests and printing), built with ElementTree."""
    joint = _joint(edge, edge.base_frame, edge.camera_frame, edge.joint_name)
    ET.indent(joint)
    return ET.tostring(joint, encoding="unicode") + "\n"


def xacro_macro(edge: ParentChild) -> str:
    """A xacro file defining ``<xacro:arc_calib_camera parent="..." child="..."/>`` (``xacro:include``-able).

    The macro adds the child link and the fixed joint ``${parent}_to_${child}``; ``parent`` (the link the
    camera is calibrated against, default: the edge's base frame) and ``child`` (default: the edge's
    camera frame) are parameters, so the same file serves a robot whose base link has a prefix.
    """
    robot = ET.Element("robot", {"xmlns:xacro": XACRO_NS})
    robot.append(_comment(edge, *_ONE_PARENT, f"Use: <xacro:include filename=\"...\"/> then "
                          f"<xacro:{XACRO_MACRO} parent=\"your_base_link\"/>."))
    macro = ET.SubElement(robot, "xacro:macro", name=XACRO_MACRO,
                          params=" ".join([f"parent:={edge.base_frame}", f"child:={edge.camera_frame}"]))
    ET.SubElement(macro, "link", name="${child}")
    macro.append(_joint(edge, "${parent}", "${child}", "${parent}_to_${child}"))
    return _xml(robot)


def launch_file(edge: ParentChild) -> str:
    """A ROS 2 Python launch file starting ``tf2_ros static_transform_publisher`` with the edge.

    The arguments (``static_transform_publisher_args``) enter the file as one Python list literal written by
    ``repr`` of validated strings, so no name can become code. Run with ``ros2 launch ./result.launch.py``.
    """
    args = static_transform_publisher_args(edge)
    lines = [
        '"""ROS 2 launch file written by ARC-Calib: publishes the calibration as a static TF transform.',
        "",
        *_header(edge),
        "Run: ros2 launch /path/to/this_file.launch.py",
        '"""',
        "",
        "from launch import LaunchDescription",
        "from launch_ros.actions import Node",
        "",
        "ARGUMENTS = [",
        *(f"    {key!r}, {value!r}," for key, value in zip(args[0::2], args[1::2], strict=True)),
        "]",
        "",
        "",
        "def generate_launch_description():",
        '    """One tf2_ros static_transform_publisher: the base frame -> the camera frame."""',
        "    return LaunchDescription([",
        '        Node(package="tf2_ros", executable="static_transform_publisher", name="arc_calib_static_tf",',
        "             arguments=ARGUMENTS),",
        "    ])",
    ]
    return "\n".join(lines) + "\n"


#: Export keys, their file suffixes beside ``result.json`` (``result.calib``, ...), and whether executable.
EXPORT_SUFFIXES = {"easy_handeye2": ".calib", "static_transform_publisher": ".tf.sh", "urdf": ".urdf",
                   "xacro": ".urdf.xacro", "launch": ".launch.py"}
#: Exports written with the executable bits (``chmod +x``).
EXECUTABLE_EXPORTS = frozenset({"static_transform_publisher"})


def export_paths(output: Path, folder: Path | None = None) -> dict[str, Path]:
    """The files written for ``output`` (result.json), keyed like ``EXPORT_SUFFIXES``.

    Args:
        output: the result file; its stem names the exports (``result.calib``, ``result.tf.sh``, ...).
        folder: where they go (default: beside ``output``).
    """
    output = Path(output)
    stem = output.stem if output.suffix == ".json" else output.name
    where = output.parent if folder is None else Path(folder)
    return {key: where / (stem + suffix) for key, suffix in EXPORT_SUFFIXES.items()}


def export_texts(edge: ParentChild, calib_name: str = DEFAULT_CALIB_NAME) -> dict[str, str]:
    """The text of every export, keyed like ``export_paths``; ``calib_name`` names the calibration and robot."""
    return {"easy_handeye2": easy_handeye2_calib(edge, calib_name),
            "static_transform_publisher": tf_script(edge),
            "urdf": urdf_robot(edge, calib_name),
            "xacro": xacro_macro(edge),
            "launch": launch_file(edge)}


def _existing_ancestor(path: Path) -> Path:
    for parent in path.parents:
        if parent.is_dir():
            return parent
    return Path(path.anchor or ".")


def write_files_atomic(files: Mapping[Path, str | bytes], modes: Mapping[Path, int] | None = None) -> None:
    """Commit every file (text or bytes) of one run together, or none of them.

    The files are first written into a temporary folder beside their targets (in the nearest existing
    directory, so the moves are renames on one file system); only when all are written are they moved
    into place, creating missing target directories. If anything fails, the files already moved are
    taken back out, files they replaced are restored, directories made for them are removed, and the
    error is raised: none of the new files remains.

    Args:
        files: {target: its content}.
        modes: {target: permission bits} for targets that need other than the default (e.g. ``0o755`` for a
            script); set on the temporary file before it is moved, so a target never exists without them.

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
            if modes and Path(target) in modes:
                tmp.chmod(modes[Path(target)])
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


def frames_dict(edge: ParentChild, optical_frame: str | None = None) -> dict[str, Any]:
    """result.json's ``frames``: the exports' TF parent and child, what the child is, the optical frame's name."""
    if edge.optical:
        return {"parent": edge.base_frame, "child": edge.camera_frame,
                "child_is": "the camera's OpenCV optical frame (REP 103 *_optical_frame), not camera_link",
                "optical_frame": edge.camera_frame}
    return {"parent": edge.base_frame, "child": edge.camera_frame,
            "child_is": "the camera's REP 103 body frame camera_link (x forward, y left, z up): the optical frame "
                        "rotated by the ideal optical -> camera_link rotation, no offset",
            "optical_frame": optical_frame}


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

    @property
    def given_time_offset_s(self) -> float:
        """s: the time offset the joints were read with (``arc_env.robot.timing``)."""
        ...


def result_dict(run: FinishedCalibration, edge: ParentChild, exports: Mapping[str, Path],
                unusable: str = "", calib_name: str = DEFAULT_CALIB_NAME,
                optical_frame: str | None = None) -> dict[str, Any]:
    """The result JSON (see docs/recording-format.md, "Calibration result").

    Args:
        run: the finished calibration.
        edge: the TF edge the exports carry (base -> optical frame, or base -> camera link).
        exports: {key: path} of the exports written (file names are stored).
        unusable: "" for a usable result, else why not (``"usable": false``; covariance and 1-sigma are
            null when the bundle adjustment gave none).
        calib_name: the easy_handeye2 calibration name.
        optical_frame: the optical frame's name when ``edge`` ends at the camera link.
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
        "T_base_camera": np.linalg.inv(T_camera_base).tolist(),
        "covariance": None if s.covariance is None else s.covariance.tolist(),
        "covariance_parameters": ("xi = (omega rad, tau m), camera frame: R = Exp(omega) R_hat, t = t_hat + tau "
                                  "(T_camera_base)"),
        "std": None if s.std is None else {"rotation_deg": np.degrees(s.std[:3]).tolist(),
                                           "translation_mm": (s.std[3:] * 1e3).tolist()},
        "rms_reprojection_px": s.rms_px,
        "time_offset_s": run.given_time_offset_s + (s.time_offset_s or 0.0),
        "time_offset_std_s": s.time_offset_std_s,
        "outlines": None if run.calibrator.outlines is None else {
            "images": run.calibrator.outlines.n_images, "motions": run.calibrator.outlines.n_groups,
            "used": s.outline is not None, "fixed_free_direction": s.start == "outlines", "note": s.outline_note,
            "pairs": None if s.outline is None else s.outline.n_pairs,
            "sigma_px": None if s.outline is None else s.outline.sigma_px,
            "edge_shift_px": None if s.outline is None else s.outline.polarity_offset_px,
            "edge_shift_direction_px": None if s.outline is None else s.outline.polarity_direction_px.tolist(),
            "tracks_covariance_scale": None if s.outline is None else s.outline.prior_scale},
        "stage": s.stage,
        "converged": s.converged,
        "frames": frames_dict(edge, optical_frame),
        "calib_name": calib_name,
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


__all__ = ["DEFAULT_CALIB_NAME", "DEFAULT_CAMERA_FRAME", "EASY_HANDEYE2_CALIBRATIONS", "EXECUTABLE_EXPORTS",
           "EXPORT_SUFFIXES", "RESULT_FORMAT", "ROS_BASE_FRAMES", "R_LINK_OPTICAL", "XACRO_MACRO", "XACRO_NS",
           "FinishedCalibration", "MotionRow", "ParentChild", "calib_name_from", "check_calib_name",
           "check_frame_name", "easy_handeye2_calib", "easy_handeye2_install_path", "export_paths", "export_texts",
           "frames_dict", "launch_file", "result_dict", "ros_base_frame", "static_transform_publisher_args",
           "static_transform_publisher_command", "tf_script", "urdf_joint", "urdf_robot", "write_files_atomic",
           "xacro_macro"]
