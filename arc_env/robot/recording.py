"""Calibration recordings (``docs/recording-format.md``): read and validate them, write them.

A recording is a directory: ``camera.json`` (OpenCV intrinsics), ``robot.json`` (an MJCF or URDF model
and its base body), and ``motions/NNN/`` with ``joints.csv`` (one row of joint positions per frame) and
the frames as ``frames/000000.png ...`` or one ``video.mp4``.

``read_recording`` checks everything that can be checked without decoding images (files, headers, counts,
joint names, finite values, the image size, which joint moves) and raises ``InvalidInputError`` naming the
file or motion; a motion where no joint or several joints move is *pruned* (``RecordedMotion.pruned``
says why), not fatal. ``Recording.frames`` decodes one motion's images and raises ``InvalidInputError``
naming the file when one does not decode.

The robot's kinematics come from the model itself, compiled by MuJoCo (``arc_env.robot.model.RobotModel``,
no simulator): ``Recording.kinematics`` is the Gamma(Q, J) the solver takes, over ``Recording.joint_names`` (the model's
hinge joints below the base body, in tree order). For each motion, Q is row 0 of ``joints.csv`` (joints
it does not list stay at the model's default), J is the one joint that moves and delta per frame is
q_J(frame) - q_J(frame 0).

Format 2 (told apart per motion by joints.csv's header, ``t,...`` instead of ``frame,...``): joints.csv
is a time series at the robot's own rate (joint clock) and ``frames.csv`` (``frame,t``) gives every frame's
exposure time (camera clock); the joints at each exposure are interpolated linearly after shifting by the
time offset (``arc_env.robot.timing``: d = t_joint - t_camera), and the swept joint's velocity at each
exposure is kept (``RecordedMotion.joint_velocity``) for a later time-offset estimate.

``RecordingWriter`` writes the format (``arc-calib record`` uses it) into a temporary directory that is
renamed into place only when the recording is complete.
"""

from __future__ import annotations

import csv
import json
import shutil
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import mujoco
import numpy as np

from arc_env.robot.exports import write_files_atomic
from arc_env.robot.model import RobotModel, RobotSource, panda_mjcf_dir, robot_spec
from arc_env.robot.timing import check_times, joints_at_times
from solver.arrays import FloatArray, ImageArray
from solver.errors import InvalidInputError
from solver.kinematics import AxisFunction
from solver.observations import MAX_IMAGE_SIDE, CameraIntrinsics

#: Newest version of ``docs/recording-format.md`` this module reads (it reads 1 and 2; ``RecordingWriter``
#: writes 1, or 2 when given times).
FORMAT_VERSION = 2
#: A joint "moves" in a motion when its positions span more than this, rad (0.57 degrees): well above
#: encoder noise and servo jitter (~1e-4 rad), well below an exploratory turn (>= 0.2 rad).
MOVING_THRESHOLD_RAD = 0.01
#: A joint value may exceed the model's limits by this much (rad) before the recording is refused: readings
#: of a real arm sit at or slightly past its nominal limits, never a radian beyond.
JOINT_RANGE_SLACK_RAD = 1.0
#: Fewest usable motions a recording must hold (the linear calibration needs 3).
MIN_MOTIONS = 3
#: Distortion models by ROS's names (``sensor_msgs/CameraInfo.distortion_model``; camera.json's optional
#: "distortion_model"), with the numbers of coefficients each takes. plumb_bob and rational_polynomial are
#: OpenCV's pinhole distortion (k1 k2 p1 p2[ k3[ k4 k5 k6]]), equidistant its fisheye model (k1 k2 k3 k4).
DISTORTION_MODELS = {"plumb_bob": (0, 4, 5), "rational_polynomial": (8,), "equidistant": (4,)}
#: Other names of ``DISTORTION_MODELS`` entries.
DISTORTION_MODEL_SYNONYMS = {"fisheye": "equidistant"}
#: The ``CameraIntrinsics.model`` of each of ``DISTORTION_MODELS``.
CAMERA_MODEL_OF = {"plumb_bob": "pinhole", "rational_polynomial": "pinhole", "equidistant": "fisheye"}
VIDEO_NAME = "video.mp4"
FRAMES_CSV = "frames.csv"
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@dataclass(frozen=True)
class RecordedMotion:
    """One motion of a recording, validated (frames not decoded).

    Attributes:
        index: 0-based position in the recording (motions are read in name order).
        name: the directory name, e.g. "007".
        path: the motion's directory.
        n_frames: F, frames (= rows of joints.csv).
        frame_paths: F PNG files, or empty when the motion is a video.
        video: the video file, or None.
        q_start: (N,) float64, rad: Q, row 0 over ``Recording.joint_names``.
        joint: index into ``Recording.joint_names`` of the joint that moves; None when pruned.
        delta: (F,) float64, rad: q_J(frame) - q_J(frame 0); zeros when pruned.
        pruned: "" or why the motion cannot be used (no joint moves, several move).
        times: (F,) float64, s: each frame's exposure time on the camera clock (format 2, bags); None in
            format 1.
        joint_velocity: (F,) float64, rad/s: joint J's velocity at each exposure (the joint series' finite
            difference, interpolated like the positions); None in format 1 and when pruned. What a
            time-offset estimate needs: delta(t + dd) ~ delta(t) + joint_velocity * dd.
    """

    index: int
    name: str
    path: Path
    n_frames: int
    frame_paths: tuple[Path, ...]
    video: Path | None
    q_start: FloatArray
    joint: int | None
    delta: FloatArray
    pruned: str
    times: FloatArray | None = None
    joint_velocity: FloatArray | None = None

    @property
    def count_file(self) -> Path:
        """The file whose rows count the frames: frames.csv (format 2) or joints.csv (format 1)."""
        return self.path / (FRAMES_CSV if self.times is not None else "joints.csv")

    @property
    def label(self) -> str:
        """How messages name the motion: ``motion 007 (<dir>)``."""
        return f"motion {self.name} ({self.path})"


class Recording:
    """A validated recording; built by ``read_recording``.

    Attributes:
        path: the recording directory.
        intrinsics: the camera (camera.json).
        model_path: the robot model file (robot.json's "model", resolved).
        base_body: the body the result is expressed in.
        robot: the robot model compiled by MuJoCo (kinematics, geometry for overlays).
        joint_names: the arm's hinge joints below the base, in tree order (Q's order).
        motions: every motion, pruned ones included.
        ignored_joints: joints.csv columns that are joints of the model but not arm hinges (e.g.
            gripper fingers): read, checked for finite values, otherwise ignored.
        time_offset_s: d = t_joint - t_camera (``arc_env.robot.timing``) the joints were read with, s.
        camera_source: the file the intrinsics came from (messages name it).
    """

    def __init__(self, path: Path, intrinsics: CameraIntrinsics, model_path: Path, base_body: str,
                 robot: RobotModel, motions: list[RecordedMotion], ignored_joints: tuple[str, ...],
                 time_offset_s: float = 0.0, camera_source: str | None = None):
        self.path = path
        self.time_offset_s = time_offset_s
        self.camera_source = camera_source or str(path / "camera.json")
        self.intrinsics = intrinsics
        self.model_path = model_path
        self.base_body = base_body
        self.robot = robot
        self.joint_names = tuple(robot.joint_names)
        self.motions = motions
        self.ignored_joints = ignored_joints

    @property
    def kinematics(self) -> AxisFunction:
        """Gamma(q, joint) -> (axis (3,), point (3,) m) in the base frame, from MuJoCo."""
        return self.robot.axis_and_point

    @property
    def usable(self) -> list[RecordedMotion]:
        """The motions not pruned by the joint check."""
        return [m for m in self.motions if not m.pruned]

    def frames(self, motion: RecordedMotion) -> list[ImageArray]:
        """Decode one motion's frames: F images (H, W, 3) uint8 RGB.

        Raises:
            InvalidInputError: a PNG or the video does not decode, the video holds a different number
                of frames than joints.csv has rows, or an image is not the camera's size.
        """
        try:
            return self._frames(motion)
        except cv2.error as exc:  # OpenCV's own failure on a damaged file
            raise InvalidInputError(f"{motion.label}: OpenCV failed to decode its frames: {exc}") from exc

    def _frames(self, motion: RecordedMotion) -> list[ImageArray]:
        cam = self.intrinsics
        images: list[ImageArray] = []
        if motion.video is None:
            for p in motion.frame_paths:
                bgr = cv2.imread(str(p), cv2.IMREAD_COLOR)
                if bgr is None:
                    raise InvalidInputError(f"{p}: the PNG does not decode (corrupt or truncated)")
                images.append(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
        else:
            capture = cv2.VideoCapture(str(motion.video))
            try:
                if not capture.isOpened():
                    raise InvalidInputError(f"{motion.video}: the video does not open (corrupt or unsupported)")
                while True:
                    ok, bgr = capture.read()
                    if not ok:
                        break
                    images.append(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
                    if len(images) > motion.n_frames:
                        break
            finally:
                capture.release()
            if len(images) != motion.n_frames:
                raise InvalidInputError(
                    f"{motion.video}: decoded {len(images)}{'+' if len(images) > motion.n_frames else ''} frames, "
                    f"but {motion.count_file} has {motion.n_frames} rows (corrupt or truncated video?)")
        for k, image in enumerate(images):
            if image.shape[:2] != (cam.height, cam.width):
                where = motion.frame_paths[k] if motion.video is None else f"{motion.video} frame {k}"
                raise InvalidInputError(f"{where}: image is {image.shape[1]}x{image.shape[0]}, "
                                        f"camera.json says {cam.width}x{cam.height}")
        return images


# -- reading ---------------------------------------------------------------------------------------
def _check_regular_file(path: Path, missing: str) -> None:
    """InvalidInputError unless ``path`` is a regular file (a FIFO or device would block or never end)."""
    if not path.exists():
        raise InvalidInputError(f"{path}: missing ({missing})")
    if not path.is_file():
        raise InvalidInputError(f"{path}: not a regular file (a directory, FIFO or device?)")


def _load_json(path: Path) -> dict:
    _check_regular_file(path, "a recording needs camera.json, robot.json and motions/")
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InvalidInputError(f"{path}: not valid JSON: {exc}") from exc
    if not isinstance(data, dict):
        raise InvalidInputError(f"{path}: must hold a JSON object, got {type(data).__name__}")
    return data


def read_camera(path: Path) -> CameraIntrinsics:
    """camera.json -> CameraIntrinsics (K, dist, width, height, optional distortion_model); errors name the file."""
    data = _load_json(path)
    missing = [k for k in ("width", "height", "K") if k not in data]
    if missing:
        raise InvalidInputError(f"{path}: missing key(s) {missing}; expected width, height, K and optional dist")
    try:
        width, height = data["width"], data["height"]
        sides_ok = all(isinstance(v, int) and not isinstance(v, bool) and 16 <= v <= MAX_IMAGE_SIDE
                       for v in (width, height))
        if not sides_ok:
            raise InvalidInputError(f"width and height must be integers in 16..{MAX_IMAGE_SIDE}, "
                                    f"got {width!r}, {height!r}")
        K = np.asarray(data["K"], dtype=np.float64)
        dist = np.asarray(data.get("dist") or [], dtype=np.float64).reshape(-1)
        if "distortion_model" not in data:
            return CameraIntrinsics(K=K, dist=dist, width=width, height=height)
        name = data["distortion_model"]
        name = DISTORTION_MODEL_SYNONYMS.get(name, name) if isinstance(name, str) else None
        if name not in DISTORTION_MODELS:
            raise InvalidInputError(f"distortion_model {data['distortion_model']!r} is not supported; supported: "
                                    f"{sorted(DISTORTION_MODELS)} (or no distortion_model: OpenCV's pinhole model)")
        if dist.size not in DISTORTION_MODELS[name]:
            raise InvalidInputError(f"distortion_model {name!r} takes {DISTORTION_MODELS[name]} coefficients "
                                    f"in dist, got {dist.size}")
        return CameraIntrinsics(K=K, dist=dist, width=width, height=height, model=CAMERA_MODEL_OF[name])
    except (InvalidInputError, TypeError, ValueError) as exc:
        raise InvalidInputError(f"{path}: {exc}") from exc


def _first_body(model_path: Path) -> str:
    try:
        body = mujoco.MjSpec.from_file(str(model_path)).worldbody.first_body()
    except Exception as exc:  # MuJoCo raises ValueError with the parser's message
        raise InvalidInputError(f"robot model {model_path} could not be loaded: {exc}") from exc
    if body is None or not body.name:
        raise InvalidInputError(f"robot model {model_path}: no named body below the world; give robot.json a base")
    return str(body.name)


def read_robot(path: Path) -> tuple[Path, str, RobotModel]:
    """robot.json -> (model file, base body, the compiled RobotModel); errors name the file."""
    data = _load_json(path)
    model = data.get("model")
    if not isinstance(model, str) or not model:
        raise InvalidInputError(f"{path}: 'model' must be the path of an MJCF or URDF file")
    model_path = Path(model) if Path(model).is_absolute() else path.parent / model
    if not model_path.is_file():
        raise InvalidInputError(f"{path}: robot model {model_path} does not exist")
    base = data.get("base")
    if base is not None and (not isinstance(base, str) or not base):
        raise InvalidInputError(f"{path}: 'base' must be a body name")
    base = base or _first_body(model_path)
    try:
        robot = RobotModel.load(RobotSource(path=str(model_path), base_body=base, home=()))
    except InvalidInputError as exc:
        raise InvalidInputError(f"{path}: {exc}") from exc
    return model_path, base, robot


def _csv_rows(path: Path, missing: str) -> list[list[str]]:
    """The non-blank rows of a CSV file (header first), at least a header and one row."""
    _check_regular_file(path, missing)
    try:
        with path.open(newline="") as f:
            rows = [r for r in csv.reader(f) if r and any(cell.strip() for cell in r)]
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise InvalidInputError(f"{path}: unreadable: {exc}") from exc
    if len(rows) < 2:
        raise InvalidInputError(f"{path}: needs a header and at least one row, got {len(rows)} line(s)")
    return rows


def _read_joints_csv(path: Path) -> tuple[list[str], FloatArray, FloatArray | None]:
    """joints.csv -> (joint names, (M, n) positions rad, None or (M,) times s).

    Format 1 (header ``frame,...``): one row per frame, frame numbers checked; times None. Format 2
    (header ``t,...``): one row per joint sample, t (joint clock, s) finite and strictly increasing.
    """
    rows = _csv_rows(path, "every motion needs joints.csv")
    header = [h.strip() for h in rows[0]]
    if header[0] not in ("frame", "t") or len(header) < 2:
        raise InvalidInputError(f"{path}: header must be 'frame,<joint name>,...', got {','.join(header)!r} "
                                "(or 't,<joint name>,...' beside a frames.csv: format 2)")
    timed = header[0] == "t"
    names = header[1:]
    duplicated = sorted({n for n in names if names.count(n) > 1})
    if duplicated:
        raise InvalidInputError(f"{path}: joint(s) {duplicated} appear more than once in the header")
    values = np.empty((len(rows) - 1, len(names)))
    times = np.empty(len(rows) - 1)
    for k, row in enumerate(rows[1:]):
        line = k + 2
        where = f"{path} line {line} ({'sample' if timed else 'frame'} {k})"
        if len(row) != len(header):
            raise InvalidInputError(f"{path} line {line}: {len(row)} values, the header has {len(header)}")
        try:
            first = float(row[0]) if timed else int(row[0])
            values[k] = [float(v) for v in row[1:]]
        except ValueError as exc:
            raise InvalidInputError(f"{path} line {line}: not a number: {exc}") from exc
        if timed:
            times[k] = first
        elif first != k:
            raise InvalidInputError(f"{path} line {line}: frame {first}, expected {k} (rows in frame order from 0)")
        bad = [names[j] for j in np.nonzero(~np.isfinite(values[k]))[0]]
        if bad:
            raise InvalidInputError(f"{where}: joint(s) {bad} are NaN or infinite")
    if timed:
        _check_column_times(path, times)
    return names, values, (times if timed else None)


def _check_column_times(path: Path, times: FloatArray) -> None:
    """A CSV's t column finite and strictly increasing; the message gives the line."""
    try:
        check_times(times, str(path))
    except InvalidInputError:
        step = np.diff(times)
        bad = np.nonzero(~np.isfinite(times))[0]
        k = int(bad[0]) if bad.size else int(np.nonzero(step <= 0)[0][0]) + 1
        why = ("t is NaN or infinite" if bad.size else
               f"t = {float(times[k])!r} s repeats the previous row (duplicate time)" if step[k - 1] == 0 else
               f"t = {float(times[k])!r} s is earlier than the previous row's {float(times[k - 1])!r} s "
               "(t must increase)")
        raise InvalidInputError(f"{path} line {k + 2}: {why}") from None


def _read_frames_csv(path: Path) -> FloatArray:
    """frames.csv (``frame,t``) -> (F,) exposure times s (camera clock); frame numbers 0, 1, ... in order."""
    rows = _csv_rows(path, "a joints.csv with a t column (format 2) needs frames.csv: frame,t")
    header = [h.strip() for h in rows[0]]
    if header != ["frame", "t"]:
        raise InvalidInputError(f"{path}: header must be 'frame,t', got {','.join(header)!r}")
    times = np.empty(len(rows) - 1)
    for k, row in enumerate(rows[1:]):
        line = k + 2
        if len(row) != 2:
            raise InvalidInputError(f"{path} line {line}: {len(row)} values, the header has 2")
        try:
            frame, times[k] = int(row[0]), float(row[1])
        except ValueError as exc:
            raise InvalidInputError(f"{path} line {line}: not a number: {exc}") from exc
        if frame != k:
            raise InvalidInputError(f"{path} line {line}: frame {frame}, expected {k} (rows in frame order from 0)")
    _check_column_times(path, times)
    return times


def _check_joint_range(path: Path, names: list[str], values: FloatArray, robot: RobotModel,
                       row: str = "frame") -> None:
    """Every arm joint's value within its limits give or take ``JOINT_RANGE_SLACK_RAD`` (names file, line, joint)."""
    for i, name in enumerate(robot.joint_names):
        if name not in names:
            continue
        column = values[:, names.index(name)]
        lo, hi = robot.lower[i] - JOINT_RANGE_SLACK_RAD, robot.upper[i] + JOINT_RANGE_SLACK_RAD
        bad = np.nonzero((column < lo) | (column > hi))[0]
        if bad.size:
            k = int(bad[0])
            raise InvalidInputError(f"{path} line {k + 2} ({row} {k}): {name} = {column[k]:g} rad is outside its "
                                    f"limits [{robot.lower[i]:.3f}, {robot.upper[i]:.3f}] by more than "
                                    f"{JOINT_RANGE_SLACK_RAD:g} rad (degrees instead of radians? another robot?)")


def _png_size(path: Path) -> tuple[int, int]:
    """(width, height) from a PNG's header; InvalidInputError if it is not a PNG."""
    try:
        with path.open("rb") as f:
            head = f.read(24)
    except OSError as exc:
        raise InvalidInputError(f"{path}: unreadable: {exc}") from exc
    if len(head) < 24 or head[:8] != _PNG_SIGNATURE or head[12:16] != b"IHDR":
        raise InvalidInputError(f"{path}: not a PNG file (corrupt or truncated header)")
    width, height = struct.unpack(">II", head[16:24])
    return int(width), int(height)


def _check_images(motion_dir: Path, n_rows: int, camera: CameraIntrinsics,
                  csv_path: Path) -> tuple[tuple[Path, ...], Path | None]:
    """The frames' files (PNGs or a video), as many as csv_path has rows, of the camera's size."""
    frames_dir, video = motion_dir / "frames", motion_dir / VIDEO_NAME
    size = f"{camera.width}x{camera.height}"
    if frames_dir.is_dir() and video.exists():
        raise InvalidInputError(f"{motion_dir}: has both frames/ and {VIDEO_NAME}; keep one")
    if frames_dir.is_dir():
        pngs = sorted(p for p in frames_dir.iterdir() if p.suffix.lower() == ".png")
        if len(pngs) != n_rows:
            raise InvalidInputError(f"{frames_dir}: {len(pngs)} PNG frames but {csv_path} has {n_rows} rows")
        paths = tuple(frames_dir / f"{k:06d}.png" for k in range(n_rows))
        for p in paths:
            _check_regular_file(p, f"frames are numbered 000000.png to {n_rows - 1:06d}.png")
            w, h = _png_size(p)
            if (w, h) != (camera.width, camera.height):
                raise InvalidInputError(f"{p}: image is {w}x{h}, camera.json says {size}")
        return paths, None
    if video.exists():
        _check_regular_file(video, "")
        capture = cv2.VideoCapture(str(video))
        try:
            if not capture.isOpened():
                raise InvalidInputError(f"{video}: the video does not open (corrupt or unsupported)")
            count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
            w, h = int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)), int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT))
        finally:
            capture.release()
        if count <= 0:
            raise InvalidInputError(f"{video}: holds no readable frames (corrupt?)")
        if count != n_rows:
            raise InvalidInputError(f"{video}: {count} frames but {csv_path} has {n_rows} rows")
        if (w, h) != (camera.width, camera.height):
            raise InvalidInputError(f"{video}: video is {w}x{h}, camera.json says {size}")
        return (), video
    raise InvalidInputError(f"{motion_dir}: missing frames/ (PNGs) or {VIDEO_NAME}")


def _classify(names: list[str], values: FloatArray, joint_names: tuple[str, ...], default: FloatArray,
              threshold: float) -> tuple[FloatArray, int | None, FloatArray, str]:
    """Q, J, delta and "" (or why the motion is pruned) from one motion's joint table."""
    q = default.copy()
    column = {n: j for j, n in enumerate(names)}
    for i, n in enumerate(joint_names):
        if n in column:
            q[i] = values[0, column[n]]
    spans = {n: float(np.ptp(values[:, column[n]])) for n in joint_names if n in column}
    moving = [n for n, s in spans.items() if s > threshold]
    n_frames = values.shape[0]
    if n_frames < 3:
        return q, None, np.zeros(n_frames), f"only {n_frames} frame(s); a sweep needs at least 3"
    if not moving:
        top = max(spans.items(), key=lambda kv: kv[1]) if spans else ("-", 0.0)
        return q, None, np.zeros(n_frames), (f"no joint moves (largest span: {top[0]} {top[1]:.4f} rad, "
                                             f"threshold {threshold} rad)")
    if len(moving) > 1:
        listed = ", ".join(f"{n} {spans[n]:.3f} rad" for n in moving)
        return q, None, np.zeros(n_frames), f"{len(moving)} joints move ({listed}); an exploratory motion turns one"
    name = moving[0]
    col = values[:, column[name]]
    return q, joint_names.index(name), col - col[0], ""


def read_recording(path: str | Path, moving_threshold: float = MOVING_THRESHOLD_RAD,
                   min_motions: int = MIN_MOTIONS, time_offset_s: float = 0.0) -> Recording:
    """Read and validate a recording (images are checked by header; decoded by ``Recording.frames``).

    Args:
        path: the recording directory.
        moving_threshold: rad; a joint moves when its positions span more than this.
        min_motions: fewest motions that must survive the joint check.
        time_offset_s: d = t_joint - t_camera, s (``arc_env.robot.timing``): format 2 motions read their
            joints at each exposure time + d; a nonzero d is refused for format 1 motions (no times).

    Returns:
        The recording, with pruned motions marked (``RecordedMotion.pruned``).

    Raises:
        InvalidInputError: naming the file or motion: a missing file, invalid JSON or intrinsics, a
            model that does not load, an unknown joint name, a non-numeric, NaN or infinite joint
            value, frame numbers out of order, a frame count that differs from the row count, a PNG or
            video that is not one or does not open, images of another size than camera.json's, or
            fewer than ``min_motions`` usable motions (the message lists why each was pruned). Format 2:
            a frames.csv missing or malformed, times not finite or not strictly increasing, an exposure
            outside the joint samples' span, or a frames.csv beside a format 1 joints.csv.
    """
    if not np.isfinite(time_offset_s):
        raise InvalidInputError(f"the time offset must be finite, got {time_offset_s}")
    root = Path(path)
    if not root.is_dir():
        raise InvalidInputError(f"{root}: not a directory (a recording is a directory; see docs/recording-format.md)")
    camera = read_camera(root / "camera.json")
    model_path, base, robot = read_robot(root / "robot.json")
    joint_names = tuple(robot.joint_names)
    default = robot.default_q
    model_joints = {robot.model.joint(j).name for j in range(robot.model.njnt)}
    motions_dir = root / "motions"
    if not motions_dir.is_dir():
        raise InvalidInputError(f"{motions_dir}: missing (a recording holds its motions in motions/NNN/)")
    dirs = []
    for entry in sorted(motions_dir.iterdir()):
        if entry.name.startswith("."):
            continue  # hidden files (.DS_Store, editor swap files) are not motions
        if not entry.is_dir():
            raise InvalidInputError(f"{entry}: not a motion directory (a file, or a broken or looping symlink?); "
                                    "motions/ holds one directory per motion")
        dirs.append(entry)
    if not dirs:
        raise InvalidInputError(f"{motions_dir}: holds no motion directories")
    motions: list[RecordedMotion] = []
    ignored: set[str] = set()
    for index, d in enumerate(dirs):
        csv_path = d / "joints.csv"
        names, values, joint_times = _read_joints_csv(csv_path)
        unknown = [n for n in names if n not in model_joints]
        if unknown:
            raise InvalidInputError(f"{csv_path}: unknown joint(s) {unknown}; joints of {model_path.name} "
                                    f"below {base!r}: {list(joint_names)}")
        ignored.update(n for n in names if n not in joint_names)
        _check_joint_range(csv_path, names, values, robot, "frame" if joint_times is None else "sample")
        frame_times = velocities = None
        if joint_times is None:
            if (d / FRAMES_CSV).exists():
                raise InvalidInputError(f"{d / FRAMES_CSV}: exposure times need a joints.csv with a t column "
                                        f"(format 2); {csv_path} starts with 'frame' (format 1: one row per frame)")
            if time_offset_s:
                raise InvalidInputError(f"{csv_path}: a time offset needs time stamps, and this motion has none "
                                        "(format 1: one row per frame); drop --time-offset or record format 2")
        else:
            frame_times = _read_frames_csv(d / FRAMES_CSV)
            if len(joint_times) < 2:
                raise InvalidInputError(f"{csv_path}: {len(joint_times)} sample; interpolation needs at least 2")
            values, velocities = joints_at_times(frame_times, joint_times, values, time_offset_s,
                                                 f"{d / FRAMES_CSV} against {csv_path}")
        count_file = csv_path if frame_times is None else d / FRAMES_CSV
        frame_paths, video = _check_images(d, values.shape[0], camera, count_file)
        q, joint, delta, pruned = _classify(names, values, joint_names, default, moving_threshold)
        joint_velocity = None
        if velocities is not None and joint is not None:
            joint_velocity = velocities[:, names.index(joint_names[joint])]
        motions.append(RecordedMotion(index, d.name, d, values.shape[0], frame_paths, video, q, joint,
                                      delta, pruned, frame_times, joint_velocity))
    recording = Recording(root, camera, model_path, base, robot, motions, tuple(sorted(ignored)), time_offset_s)
    usable = recording.usable
    if len(usable) < min_motions:
        why = "; ".join(f"motion {m.name}: {m.pruned}" for m in motions if m.pruned)
        raise InvalidInputError(f"{root}: too few usable motions: {len(usable)} of {len(motions)} "
                                f"(need {min_motions})" + (f"; pruned: {why}" if why else ""))
    return recording


# -- writing ---------------------------------------------------------------------------------------
def _copy_assets(spec: mujoco.MjSpec, source_dir: Path, robot_dir: Path) -> None:
    """Copy the mesh, height-field, skin and texture files a spec references into robot_dir/assets."""
    assets = robot_dir / "assets"
    used: dict[str, Path] = {}
    kinds = [(spec.meshes, spec.meshdir), (spec.hfields, spec.meshdir), (spec.skins, spec.meshdir),
             (spec.textures, spec.texturedir)]
    for items, folder in kinds:
        for item in items:
            if not getattr(item, "file", ""):
                continue
            src = Path(item.file)
            if not src.is_absolute():
                src = source_dir / folder / src
            name, k = src.name, 1
            while name in used and used[name] != src:
                name = f"{src.stem}_{k}{src.suffix}"
                k += 1
            used[name] = src
            assets.mkdir(parents=True, exist_ok=True)
            if not (assets / name).exists():
                shutil.copyfile(src, assets / name)
            item.file = name
    spec.meshdir = "assets"
    spec.texturedir = "assets"
    spec.modelfiledir = str(robot_dir)  # to_xml compiles: relative files resolve from here


def write_robot_model(source: RobotSource, robot_dir: Path) -> tuple[str, str]:
    """Write the robot's model as one self-contained MJCF in robot_dir (meshes copied beside it).

    Returns:
        (the model's file name inside robot_dir, the base body).
    """
    robot_dir.mkdir(parents=True, exist_ok=True)
    spec = robot_spec(source)
    source_dir = panda_mjcf_dir() if source.path is None else Path(source.path).parent
    _copy_assets(spec, source_dir, robot_dir)
    name = "robot.xml"
    (robot_dir / name).write_text(spec.to_xml())
    return name, source.base_body


class RecordingWriter:
    """Writes a recording into ``out.partial/`` and renames it to ``out`` on ``close``.

    Args:
        out: the recording directory to create (must not exist).
        intrinsics: written to camera.json.
        robot: the model to copy into ``robot/`` and reference from robot.json.
        video: write one MP4 per motion (cv2.VideoWriter, mp4v) instead of PNG frames.
        fps: the video's frame rate (metadata only; joints.csv gives the timing that matters).
    """

    def __init__(self, out: Path, intrinsics: CameraIntrinsics, robot: RobotSource, video: bool = False,
                 fps: float = 30.0):
        self.out = Path(out)
        if self.out.exists():
            raise InvalidInputError(f"{self.out}: already exists; choose a new directory")
        self.tmp = self.out.with_name(self.out.name + ".partial")
        if self.tmp.exists():
            shutil.rmtree(self.tmp)
        self.tmp.mkdir(parents=True)
        try:
            self._start(intrinsics, robot)
        except BaseException:
            self.abort()
            raise
        self.video = video
        self.fps = fps
        self.n_motions = 0

    def _start(self, intrinsics: CameraIntrinsics, robot: RobotSource) -> None:
        self.intrinsics = intrinsics
        K = intrinsics.K
        camera = {"width": intrinsics.width, "height": intrinsics.height, "K": K.tolist()}
        if intrinsics.dist.size:
            camera["dist"] = intrinsics.dist.tolist()
        if intrinsics.is_fisheye:
            camera["distortion_model"] = "equidistant"
        write_files_atomic({self.tmp / "camera.json": json.dumps(camera, indent=2) + "\n"})
        model, base = write_robot_model(robot, self.tmp / "robot")
        write_files_atomic({self.tmp / "robot.json": json.dumps({"model": f"robot/{model}", "base": base}, indent=2)
                            + "\n"})
        (self.tmp / "motions").mkdir()

    def add_motion(self, joint_names: Sequence[str], positions: FloatArray, frames: Sequence[ImageArray],
                   frame_times: FloatArray | None = None, joint_times: FloatArray | None = None) -> Path:
        """Write one motion: F frames (H, W, 3) uint8 RGB and the joints' positions for joint_names.

        Format 1 (no times): positions (F, n) rad, one row per frame. Format 2: frame_times (F,) s
        (camera clock, frames.csv) and positions (M, n) rad sampled at joint_times (M,) s (joint clock).
        """
        positions = np.asarray(positions, dtype=np.float64)
        timed = frame_times is not None
        if timed != (joint_times is not None):
            raise InvalidInputError("give both frame_times and joint_times (format 2) or neither (format 1)")
        rows = len(joint_times) if joint_times is not None else len(frames)
        if positions.shape != (rows, len(joint_names)):
            raise InvalidInputError(f"positions must be ({rows}, {len(joint_names)}), got {positions.shape}")
        if frame_times is not None and len(frame_times) != len(frames):
            raise InvalidInputError(f"{len(frame_times)} frame times for {len(frames)} frames")
        d = self.tmp / "motions" / f"{self.n_motions:03d}"
        d.mkdir()
        with (d / "joints.csv").open("w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["t" if timed else "frame", *joint_names])
            for k, row in enumerate(positions):
                first = repr(float(joint_times[k])) if joint_times is not None else k
                w.writerow([first, *(repr(float(v)) for v in row)])
        if frame_times is not None:
            with (d / FRAMES_CSV).open("w", newline="") as f:
                w = csv.writer(f)
                w.writerow(["frame", "t"])
                w.writerows([k, repr(float(t))] for k, t in enumerate(frame_times))
        if self.video:
            write_video(d / VIDEO_NAME, frames, self.fps)
        else:
            (d / "frames").mkdir()
            for k, frame in enumerate(frames):
                if not cv2.imwrite(str(d / "frames" / f"{k:06d}.png"), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR)):
                    raise OSError(f"OpenCV could not write {d / 'frames' / f'{k:06d}.png'}")
        self.n_motions += 1
        return d

    def close(self) -> Path:
        """Move the finished recording into place; returns its path."""
        self.tmp.rename(self.out)
        return self.out

    def abort(self) -> None:
        """Remove the partial recording."""
        shutil.rmtree(self.tmp, ignore_errors=True)


def write_video(path: Path, frames: Sequence[ImageArray], fps: float = 30.0) -> None:
    """Write RGB frames (H, W, 3) uint8 as an MP4 (mp4v) with cv2.VideoWriter."""
    h, w = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
    if not writer.isOpened():
        raise OSError(f"OpenCV could not open a video writer for {path} (mp4v)")
    try:
        for frame in frames:
            writer.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    finally:
        writer.release()


__all__ = [
    "FORMAT_VERSION",
    "FRAMES_CSV",
    "MIN_MOTIONS",
    "JOINT_RANGE_SLACK_RAD",
    "MOVING_THRESHOLD_RAD",
    "RecordedMotion",
    "Recording",
    "RecordingWriter",
    "read_camera",
    "read_recording",
    "read_robot",
    "write_robot_model",
    "write_video",
]
