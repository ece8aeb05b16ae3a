"""Calibrate from a ROS bag: ROS 2 (sqlite3 or MCAP storage, a bag directory or one ``.mcap`` file) or ROS 1.

``read_bag`` reads a bag with ``rosbags`` (``rosbags.highlevel.AnyReader``) into a ``BagRecording``, the
same ``Recording`` that ``arc-calib calibrate`` calibrates from a recording directory:

* **Topics are found by message type**: ``sensor_msgs/Image`` or ``sensor_msgs/CompressedImage`` (the
  frames), ``sensor_msgs/CameraInfo`` (the intrinsics; or ``camera_info_file``, a camera_calibration_parsers
  YAML), ``sensor_msgs/JointState`` (the joints). When a type has several topics, the caller chooses
  (``--image-topic``, ``--camera-info-topic``, ``--joint-topic``); the message lists the candidates.
* **Clocks**: an image's ``header.stamp`` is its exposure time (camera clock); a JointState's
  ``header.stamp`` is its joint clock. The joints at an exposure are interpolated linearly at
  stamp + time offset (``arc_env.robot.timing``: d = t_joint - t_camera).
* **Motions** come from the joint states alone (``arc_env.robot.segmentation``): each span where one
  joint turns alone is a motion; its frames are the images exposed during it; Q is the joints at its
  first frame and delta per frame the turning joint's offset from there (as in a recording).
* **Images**: ``Image`` in rgb8, bgr8, mono8, rgba8, bgra8; ``CompressedImage`` in any format OpenCV
  decodes (jpeg, png). ``BagRecording.frames`` reads and decodes one motion's images from the bag.
* **CameraInfo**: K, and D by ``distortion_model``: plumb_bob (4 or 5 coefficients), rational_polynomial
  (8; OpenCV's order k1 k2 p1 p2 k3 k4 k5 k6); an empty model with zero D is no distortion. ``equidistant``
  (4: k1 k2 k3 k4; "fisheye" is read as its synonym) is OpenCV's fisheye model: a ``CameraIntrinsics`` with
  ``model="fisheye"``, which ``solver.camera`` projects through ``cv2.fisheye`` (zero D is still the
  equidistant lens, not a pinhole).

Every problem -- a file that is not a bag, a corrupt or truncated chunk, a missing topic, an unknown
joint name, clocks that never overlap -- raises ``InvalidInputError`` with one line naming the bag and
the topic (and the message number where there is one). ``BagWriter`` writes such a bag (``arc-calib record
--format bag|mcap``; tests).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml
from rosbags.highlevel import AnyReader
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from arc_env.robot.model import RobotModel, RobotSource
from arc_env.robot.recording import (
    CAMERA_MODEL_OF,
    DISTORTION_MODEL_SYNONYMS,
    DISTORTION_MODELS,
    MIN_MOTIONS,
    MOVING_THRESHOLD_RAD,
    RecordedMotion,
    Recording,
    _classify,
    _first_body,
)
from arc_env.robot.segmentation import SegmentConfig, Span, segment_motions
from arc_env.robot.timing import check_times, exposures_in_span, joints_at_times
from solver.arrays import FloatArray, ImageArray
from solver.errors import InvalidInputError
from solver.observations import CameraIntrinsics

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
JOINT_STATE = "sensor_msgs/msg/JointState"
#: ``sensor_msgs/Image`` encodings read: channels and the OpenCV conversion to RGB (None: already RGB).
IMAGE_ENCODINGS: dict[str, tuple[int, int | None]] = {
    "rgb8": (3, None), "bgr8": (3, cv2.COLOR_BGR2RGB), "mono8": (1, cv2.COLOR_GRAY2RGB),
    "rgba8": (4, cv2.COLOR_RGBA2RGB), "bgra8": (4, cv2.COLOR_BGRA2RGB),
}
#: The storages ``BagWriter`` writes: ROS 2 sqlite3, ROS 2 MCAP, ROS 1.
STORAGES = ("sqlite3", "mcap", "ros1")


def is_bag(path: str | Path) -> bool:
    """Whether a calibrate input is a bag: a ``.mcap`` or ``.bag`` file, or a directory with metadata.yaml."""
    p = Path(path)
    return p.suffix in (".mcap", ".bag") or (p.is_dir() and (p / "metadata.yaml").is_file())


def _stamp(header: Any) -> int:
    """A header's stamp in ns."""
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


# -- intrinsics -------------------------------------------------------------------------------------------
def intrinsics_from_camera_info(model: str, K: FloatArray, D: FloatArray, width: int, height: int,
                                where: str) -> CameraIntrinsics:
    """CameraInfo fields -> CameraIntrinsics, honouring distortion_model.

    Args:
        model: the distortion_model string.
        K: (9,) or (3, 3) float64, px: the camera matrix.
        D: (k,) float64: the distortion coefficients in ROS's order (OpenCV's for these models).
        width: image width, px.
        height: image height, px.
        where: how messages name the source (a topic, a file).

    Raises:
        InvalidInputError: an unsupported distortion model, a coefficient count the model does not have, or
            intrinsics ``CameraIntrinsics`` refuses (a zero K: an uncalibrated camera; a fisheye K with skew).
    """
    D = np.asarray(D, dtype=np.float64).reshape(-1)
    model = (model or "").strip()
    model = DISTORTION_MODEL_SYNONYMS.get(model, model)
    if model == "" and not np.any(D):
        D = np.zeros(0)
    elif model not in DISTORTION_MODELS:
        raise InvalidInputError(f"{where}: distortion_model {model!r} is not supported; supported: "
                                f"{sorted(DISTORTION_MODELS)} (or an empty model with no coefficients)")
    elif D.size not in DISTORTION_MODELS[model]:
        raise InvalidInputError(f"{where}: distortion_model {model!r} takes {DISTORTION_MODELS[model]} "
                                f"coefficients, got {D.size}")
    K = np.asarray(K, dtype=np.float64).reshape(3, 3)
    if not K[0, 0] or not K[1, 1]:
        raise InvalidInputError(f"{where}: K has a zero focal length (an uncalibrated camera); calibrate the "
                                "camera's intrinsics first, or give them with --camera-info FILE")
    try:
        if CAMERA_MODEL_OF.get(model) == "fisheye":
            return CameraIntrinsics(K=K, dist=D, width=int(width), height=int(height), model="fisheye")
        return CameraIntrinsics(K=K, dist=D if np.any(D) else np.zeros(0), width=int(width), height=int(height))
    except InvalidInputError as exc:
        raise InvalidInputError(f"{where}: {exc}") from exc


def read_camera_info_yaml(path: str | Path) -> CameraIntrinsics:
    """A camera_calibration_parsers YAML (image_width, image_height, camera_matrix, distortion_model,
    distortion_coefficients) -> CameraIntrinsics; errors name the file.
    """  # noqa: D205
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise InvalidInputError(f"{path}: not a readable YAML file: {exc}") from exc
    try:
        K = np.asarray(data["camera_matrix"]["data"], dtype=np.float64)
        dist = data.get("distortion_coefficients") or {}
        D = np.asarray(dist.get("data") or [], dtype=np.float64)
        width, height = data["image_width"], data["image_height"]
        model = data.get("distortion_model") or ""
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise InvalidInputError(f"{path}: not a camera_calibration_parsers YAML (image_width, image_height, "
                                "camera_matrix.data, distortion_model, distortion_coefficients.data): "
                                f"{exc!r}") from exc
    if K.size != 9:
        raise InvalidInputError(f"{path}: camera_matrix.data must hold 9 numbers, got {K.size}")
    return intrinsics_from_camera_info(model, K, D, width, height, str(path))


# -- images ---------------------------------------------------------------------------------------------
def decode_image(msg: Any, msgtype: str, where: str) -> ImageArray:
    """An Image or CompressedImage message -> (H, W, 3) uint8 RGB; errors name ``where``."""
    if msgtype == COMPRESSED_IMAGE:
        bgr = cv2.imdecode(np.frombuffer(bytes(msg.data), np.uint8), cv2.IMREAD_COLOR)
        if bgr is None:
            raise InvalidInputError(f"{where}: the compressed image (format {msg.format!r}) does not decode")
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    encoding = str(msg.encoding).lower()
    if encoding not in IMAGE_ENCODINGS:
        raise InvalidInputError(f"{where}: image encoding {msg.encoding!r} is not supported; supported: "
                                f"{sorted(IMAGE_ENCODINGS)} (or a CompressedImage topic)")
    channels, conversion = IMAGE_ENCODINGS[encoding]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.frombuffer(bytes(msg.data), np.uint8)
    if step < w * channels or data.size < h * step:
        raise InvalidInputError(f"{where}: {data.size} bytes for a {w}x{h} {encoding} image with step {step} "
                                "(truncated message?)")
    pixels = data[:h * step].reshape(h, step)[:, :w * channels].reshape(h, w, channels)
    if conversion is None:
        return pixels.copy()
    return cv2.cvtColor(pixels[..., 0] if channels == 1 else pixels, conversion)


# -- reading --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BagTopics:
    """The topics a bag is read from (camera_info None when the intrinsics come from a file)."""

    image: str
    image_type: str
    camera_info: str | None
    joints: str


@contextmanager
def _open(path: Path) -> Iterator[AnyReader]:
    """An open AnyReader on the bag; failing to open it is an InvalidInputError naming the bag."""
    try:
        reader = AnyReader([path])
        reader.open()
    except Exception as exc:  # rosbags raises its own errors, sqlite3's, MCAP's, struct's, OSError...
        raise InvalidInputError(f"{path}: not a readable ROS bag ({type(exc).__name__}: {exc})") from exc
    try:
        yield reader
    finally:
        reader.close()


def _choose(topics: dict[str, str], types: tuple[str, ...], given: str | None, option: str, path: Path,
            prefer: Callable[[str], bool] | None = None) -> str:
    """The one topic of one of ``types``: the given one, the only one, or the one ``prefer`` singles out."""
    what = " or ".join(t.replace("/msg/", "/") for t in types)
    candidates = sorted(t for t, ty in topics.items() if ty in types)
    if given is not None:
        if given not in topics:
            raise InvalidInputError(f"{path}: {option} {given}: no such topic; {what} topics: {candidates}")
        if topics[given] not in types:
            raise InvalidInputError(f"{path}: {option} {given} is a {topics[given]}, not a {what}; "
                                    f"{what} topics: {candidates}")
        return given
    if not candidates:
        raise InvalidInputError(f"{path}: no {what} topic in the bag (its topics: "
                                f"{sorted(f'{t} ({ty})' for t, ty in topics.items())})")
    if len(candidates) > 1 and prefer is not None and sum(map(prefer, candidates)) == 1:
        return next(c for c in candidates if prefer(c))
    if len(candidates) > 1:
        raise InvalidInputError(f"{path}: several {what} topics: {candidates}; choose one with {option}")
    return candidates[0]


def _messages(reader: AnyReader, path: Path, topic: str, start: int | None = None,
              stop: int | None = None) -> Iterator[tuple[int, int, Any]]:
    """(message number, log time ns, message) of one topic; read errors name the topic and the message."""
    connections = [c for c in reader.connections if c.topic == topic]
    k = -1
    try:
        for k, (connection, log_time, raw) in enumerate(reader.messages(connections, start=start, stop=stop)):
            try:
                msg = reader.deserialize(raw, connection.msgtype)
            except Exception as exc:  # a message that does not deserialize (corrupt data)
                raise InvalidInputError(f"{path}: topic {topic} message #{k} does not deserialize: {exc}") from exc
            yield k, log_time, msg
    except InvalidInputError:
        raise
    except Exception as exc:  # a corrupt chunk, a truncated file, a decompression error
        raise InvalidInputError(f"{path}: topic {topic}: reading message #{k + 1} failed "
                                f"(corrupt or truncated bag?): {type(exc).__name__}: {exc}") from exc


def _read_joint_states(reader: AnyReader, path: Path, topic: str, robot: RobotModel,
                       model_name: str) -> tuple[FloatArray, FloatArray, tuple[str, ...]]:
    """(t (M,) s joint clock, positions (M, n) rad over the arm's joints, ignored joint names)."""
    arm = list(robot.joint_names)
    model_joints = {robot.model.joint(j).name for j in range(robot.model.njnt)}
    where = f"{path}: topic {topic}"
    stamps: list[int] = []
    rows: list[FloatArray] = []
    present: list[str] | None = None
    ignored: set[str] = set()
    default = robot.default_q
    for k, _, msg in _messages(reader, path, topic):
        names = list(msg.name)
        position = np.asarray(msg.position, dtype=np.float64)
        if len(position) != len(names):
            raise InvalidInputError(f"{where} message #{k}: {len(names)} names but {len(position)} positions")
        unknown = [n for n in names if n not in model_joints]
        if unknown:
            raise InvalidInputError(f"{where} message #{k}: joint {unknown[0]!r} is not a joint of {model_name}; "
                                    f"its arm joints: {arm}")
        ignored.update(n for n in names if n not in arm)
        mine = [n for n in names if n in arm]
        if not mine:
            continue  # e.g. a gripper's own joint_states
        if present is None:
            present = mine
        elif sorted(mine) != sorted(present):
            raise InvalidInputError(f"{where} message #{k}: arm joints {sorted(mine)}, earlier messages "
                                    f"{sorted(present)}; every message must carry the same arm joints")
        values = position[[names.index(n) for n in mine]]
        if not np.all(np.isfinite(values)):
            bad = [n for n, v in zip(mine, values, strict=True) if not np.isfinite(v)]
            raise InvalidInputError(f"{where} message #{k}: joint(s) {bad} are NaN or infinite")
        stamp = _stamp(msg.header)
        if stamp == 0:
            raise InvalidInputError(f"{where} message #{k}: header.stamp is zero; the joint states need their "
                                    "clock's stamps")
        q = default.copy()
        q[[arm.index(n) for n in mine]] = values
        stamps.append(stamp)
        rows.append(q)
    if not rows:
        raise InvalidInputError(f"{where}: no joint states of the arm's joints {arm}")
    t = np.asarray(stamps, dtype=np.float64) * 1e-9
    check_times(t, f"{where} header stamps")
    return t, np.asarray(rows), tuple(sorted(ignored))


def _read_camera_info(reader: AnyReader, path: Path, topic: str) -> CameraIntrinsics:
    for _, _, msg in _messages(reader, path, topic):
        K = msg.k if hasattr(msg, "k") else msg.K
        D = msg.d if hasattr(msg, "d") else msg.D
        return intrinsics_from_camera_info(msg.distortion_model, K, D, msg.width, msg.height,
                                           f"{path}: topic {topic}")
    raise InvalidInputError(f"{path}: topic {topic}: holds no CameraInfo message")


def _index_images(reader: AnyReader, path: Path, topic: str, msgtype: str,
                  camera: CameraIntrinsics) -> tuple[FloatArray, list[int], list[int]]:
    """(exposure times (F,) s camera clock, their stamps ns, their log times ns); the first image decoded."""
    stamps: list[int] = []
    log_times: list[int] = []
    for k, log_time, msg in _messages(reader, path, topic):
        stamp = _stamp(msg.header)
        if not stamps:
            image = decode_image(msg, msgtype, f"{path}: topic {topic} message #{k}")
            if image.shape[:2] != (camera.height, camera.width):
                raise InvalidInputError(f"{path}: topic {topic} message #{k}: image is {image.shape[1]}x"
                                        f"{image.shape[0]}, the camera info says {camera.width}x{camera.height}")
        if stamp == 0:
            raise InvalidInputError(f"{path}: topic {topic} message #{k}: header.stamp is zero; the images need "
                                    "their exposure time stamps")
        stamps.append(stamp)
        log_times.append(log_time)
    if not stamps:
        raise InvalidInputError(f"{path}: topic {topic}: holds no images")
    t = np.asarray(stamps, dtype=np.float64) * 1e-9
    check_times(t, f"{path}: topic {topic} header stamps")
    return t, stamps, log_times


class BagRecording(Recording):
    """A bag read as a recording (``read_bag``): motions from the segmentation, frames from the bag.

    Attributes (beyond ``Recording``'s):
        topics: the topics read.
        segments: the spans of the joint stream that became motions, in order (motion k is segments[k]).
        skipped: the spans skipped, with their reasons.
        n_images: images on the image topic.
        t0: s, camera clock: the first image's stamp (messages give times from it).
    """

    topics: BagTopics
    segments: list[Span]
    skipped: list[Span]
    n_images: int
    t0: float
    _stamps: dict[str, list[int]]
    _log_times: dict[str, tuple[int, int]]

    def _frames(self, motion: RecordedMotion) -> list[ImageArray]:
        wanted = self._stamps[motion.name]
        start, stop = self._log_times[motion.name]
        where = f"{self.path}: topic {self.topics.image}"
        found: dict[int, ImageArray] = {}
        with _open(self.path) as reader:
            for k, _, msg in _messages(reader, self.path, self.topics.image, start, stop + 1):
                stamp = _stamp(msg.header)
                if stamp in wanted:
                    image = decode_image(msg, self.topics.image_type, f"{where} message at stamp {stamp * 1e-9:.6f} s")
                    if image.shape[:2] != (self.intrinsics.height, self.intrinsics.width):
                        cam = self.intrinsics
                        raise InvalidInputError(f"{where} message #{k}: image is {image.shape[1]}x{image.shape[0]}, "
                                                f"the camera info says {cam.width}x{cam.height}")
                    found[stamp] = image
        missing = [s for s in wanted if s not in found]
        if missing:
            raise InvalidInputError(f"{where}: the image stamped {missing[0] * 1e-9:.6f} s was not found again")
        return [found[s] for s in wanted]


def read_bag(path: str | Path, robot_path: str | Path, base_body: str | None = None, *,
             image_topic: str | None = None, camera_info_topic: str | None = None, joint_topic: str | None = None,
             camera_info_file: str | Path | None = None, time_offset_s: float = 0.0,
             segmentation: SegmentConfig | None = None, moving_threshold: float = MOVING_THRESHOLD_RAD,
             min_motions: int = MIN_MOTIONS) -> BagRecording:
    """Read a bag into a recording: topics, intrinsics, joint stream, segmentation, frames per motion.

    Args:
        path: a ROS 2 bag directory (sqlite3 or MCAP), a ``.mcap`` file or a ROS 1 ``.bag``.
        robot_path: the robot's MJCF or URDF.
        base_body: the body the result is expressed in (None: the model's first body below the world).
        image_topic: the image topic when the bag has several.
        camera_info_topic: the CameraInfo topic when it has several (ignored with camera_info_file).
        joint_topic: the JointState topic when it has several.
        camera_info_file: a camera_calibration_parsers YAML to use instead of a CameraInfo topic.
        time_offset_s: d = t_joint - t_camera, s (``arc_env.robot.timing``).
        segmentation: how motions are found (``SegmentConfig()`` by default).
        moving_threshold: rad; a joint moves over a motion's frames when it spans more than this.
        min_motions: fewest usable motions.

    Raises:
        InvalidInputError: one line naming the bag and the topic (and message): see the module doc.
    """
    path = Path(path)
    if not np.isfinite(time_offset_s):
        raise InvalidInputError(f"the time offset must be finite, got {time_offset_s}")
    if not path.exists():
        raise InvalidInputError(f"{path}: does not exist")
    model_path = Path(robot_path)
    if not model_path.is_file():
        raise InvalidInputError(f"--robot {model_path}: no such file (the robot's MJCF or URDF)")
    base = base_body or _first_body(model_path)
    robot = RobotModel.load(RobotSource(path=str(model_path), base_body=base, home=()))
    segmentation = segmentation or SegmentConfig()
    with _open(path) as reader:
        topics = {t: info.msgtype for t, info in reader.topics.items()}
        image = _choose(topics, (IMAGE, COMPRESSED_IMAGE), image_topic, "--image-topic", path)
        joints = _choose(topics, (JOINT_STATE,), joint_topic, "--joint-topic", path)
        info_topic = None
        if camera_info_file is not None:
            camera = read_camera_info_yaml(camera_info_file)
        else:
            namespace = image.rsplit("/", 1)[0] + "/"
            info_topic = _choose(topics, (CAMERA_INFO,), camera_info_topic, "--camera-info-topic", path,
                                 prefer=lambda t: t.startswith(namespace))
            camera = _read_camera_info(reader, path, info_topic)
        bag_topics = BagTopics(image, topics[image], info_topic, joints)
        t_joints, q_joints, ignored = _read_joint_states(reader, path, joints, robot, model_path.name)
        t_images, stamps, log_times = _index_images(reader, path, image, topics[image], camera)
    inside = exposures_in_span(t_images, t_joints, time_offset_s)
    if not inside.any():
        raise InvalidInputError(
            f"{path}: no image on {image} was exposed while {joints} has joint states: images at "
            f"[{t_images[0]:.3f}, {t_images[-1]:.3f}] s (camera clock), joint states at [{t_joints[0]:.3f}, "
            f"{t_joints[-1]:.3f}] s (joint clock), time offset {time_offset_s:+g} s: clocks that never overlap?")
    names = list(robot.joint_names)
    segments, skipped = segment_motions(t_joints, q_joints, names, segmentation)
    if not segments:
        why = "; ".join(f"{s.t_start:.2f}-{s.t_stop:.2f} s: {s.reason}" for s in skipped[:5])
        raise InvalidInputError(f"{path}: topic {joints}: no exploratory motion (one joint turning alone by >= "
                                f"{segmentation.min_delta_rad} rad) in {len(skipped)} moving span(s)"
                                + (f"; {why}" if why else ""))
    motions: list[RecordedMotion] = []
    motion_stamps: dict[str, list[int]] = {}
    motion_logs: dict[str, tuple[int, int]] = {}
    shifted = t_images + time_offset_s
    for index, seg in enumerate(segments):
        name = f"{index:03d}"
        picked = np.nonzero((shifted >= seg.t_start) & (shifted <= seg.t_stop))[0]
        times = t_images[picked]
        if picked.size:
            positions, velocities = joints_at_times(times, t_joints, q_joints, time_offset_s, f"{path}: {joints}")
        else:
            positions, velocities = np.zeros((0, len(names))), np.zeros((0, len(names)))
        q, joint, delta, pruned = (_classify(names, positions, tuple(names), robot.default_q, moving_threshold)
                                   if picked.size else (robot.default_q, None, np.zeros(0), "no image exposed "
                                                        f"during it ({seg.t_start:.3f}-{seg.t_stop:.3f} s)"))
        if not picked.size:
            q = q_joints[seg.first].copy()
        velocity = velocities[:, joint] if joint is not None else None
        motions.append(RecordedMotion(index, name, path, int(picked.size), (), None, q, joint, delta, pruned,
                                      times, velocity))
        motion_stamps[name] = [stamps[k] for k in picked]
        motion_logs[name] = ((log_times[picked[0]], log_times[picked[-1]]) if picked.size else (0, 0))
    recording = BagRecording(path, camera, model_path, base, robot, motions, ignored, time_offset_s,
                             camera_source=str(camera_info_file) if camera_info_file else f"{path}: {info_topic}")
    recording.topics = bag_topics
    recording.segments = segments
    recording.skipped = skipped
    recording.n_images = len(t_images)
    recording.t0 = float(t_images[0])
    recording._stamps = motion_stamps
    recording._log_times = motion_logs
    usable = recording.usable
    if len(usable) < min_motions:
        why = "; ".join(f"motion {m.name}: {m.pruned}" for m in motions if m.pruned)
        raise InvalidInputError(f"{path}: too few usable motions: {len(usable)} of {len(motions)} segments "
                                f"(need {min_motions}); {len(skipped)} spans skipped"
                                + (f"; pruned: {why}" if why else ""))
    return recording


# -- writing --------------------------------------------------------------------------------------------
class BagWriter:
    """Writes camera_info, images and joint states as a real bag with the rosbags writer.

    Args:
        path: the bag to create: a directory (ROS 2, sqlite3 or MCAP storage) or a ``.bag`` file (ROS 1).
        storage: "sqlite3", "mcap" or "ros1".
        image_encoding: rgb8, bgr8, mono8 (``sensor_msgs/Image``), or jpeg, png (``CompressedImage``).
        image_topic, camera_info_topic, joint_topic: where they go.
        frame_id: the camera's optical frame (the images' and camera_info's header.frame_id).
        jpeg_quality: JPEG quality, 0-100.
        compress: compress the bag's chunks (ROS 1: LZ4 chunks; ROS 2 MCAP: zstd chunks; sqlite3: none).
    """

    def __init__(self, path: str | Path, storage: str = "sqlite3", image_encoding: str = "rgb8",
                 image_topic: str = "/camera/color/image_raw", camera_info_topic: str = "/camera/color/camera_info",
                 joint_topic: str = "/joint_states", frame_id: str = "camera_color_optical_frame",
                 jpeg_quality: int = 95, compress: bool = False):
        if storage not in STORAGES:
            raise InvalidInputError(f"storage must be one of {STORAGES}, got {storage!r}")
        if image_encoding not in ("rgb8", "bgr8", "mono8", "jpeg", "png"):
            raise InvalidInputError(f"image encoding must be rgb8, bgr8, mono8, jpeg or png, got {image_encoding!r}")
        self.path = Path(path)
        self.ros1 = storage == "ros1"
        self.typestore = get_typestore(Stores.ROS1_NOETIC if self.ros1 else Stores.ROS2_HUMBLE)
        self.encoding = image_encoding
        self.frame_id = frame_id
        self.jpeg_quality = jpeg_quality
        compressed = image_encoding in ("jpeg", "png")
        if compressed and not image_topic.endswith("/compressed"):
            image_topic += "/compressed"
        if self.ros1:
            self.writer: Any = Writer1(self.path)
            if compress:
                self.writer.set_compression(Writer1.CompressionFormat.LZ4)
        else:
            plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
            self.writer = Writer2(self.path, version=9, storage_plugin=plugin)
            if compress and storage == "mcap":
                self.writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        self.writer.open()
        add = self.writer.add_connection
        self.image_type = COMPRESSED_IMAGE if compressed else IMAGE
        self.image_conn = add(image_topic, self.image_type, typestore=self.typestore)
        self.info_conn = add(camera_info_topic, CAMERA_INFO, typestore=self.typestore)
        self.joint_conn = add(joint_topic, JOINT_STATE, typestore=self.typestore)

    def _header(self, stamp_ns: int, frame_id: str) -> Any:
        types = self.typestore.types
        stamp = types["builtin_interfaces/msg/Time"](sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000)
        if self.ros1:
            return types["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=frame_id)
        return types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)

    def _write(self, connection: Any, msgtype: str, stamp_ns: int, msg: Any) -> None:
        data = (self.typestore.serialize_ros1(msg, msgtype) if self.ros1
                else self.typestore.serialize_cdr(msg, msgtype))
        self.writer.write(connection, stamp_ns, data)

    def camera_info(self, stamp_ns: int, intrinsics: CameraIntrinsics, distortion_model: str = "") -> None:
        """Write one CameraInfo: K, D (plumb_bob for 4-5 coefficients, rational_polynomial for 8, equidistant for
        a fisheye); ``distortion_model`` overrides the name (tests write wrong ones).
        """  # noqa: D205
        D = np.asarray(intrinsics.dist, dtype=np.float64)
        model = distortion_model or ("equidistant" if intrinsics.is_fisheye else
                                     "rational_polynomial" if D.size == 8 else "plumb_bob")
        if model == "plumb_bob" and D.size == 0:
            D = np.zeros(5)
        K = np.asarray(intrinsics.K, dtype=np.float64)
        P = np.hstack([K, np.zeros((3, 1))]).reshape(-1)
        types = self.typestore.types
        roi = types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        fields = {"d": D, "k": K.reshape(-1), "r": np.eye(3).reshape(-1), "p": P}
        if self.ros1:
            fields = {name.upper(): value for name, value in fields.items()}
        msg = types[CAMERA_INFO](header=self._header(stamp_ns, self.frame_id), height=intrinsics.height,
                                 width=intrinsics.width, distortion_model=model, binning_x=0, binning_y=0, roi=roi,
                                 **fields)
        self._write(self.info_conn, CAMERA_INFO, stamp_ns, msg)

    def image(self, stamp_ns: int, rgb: ImageArray) -> None:
        """Write one frame (H, W, 3) uint8 RGB stamped stamp_ns (its exposure time)."""
        types = self.typestore.types
        header = self._header(stamp_ns, self.frame_id)
        if self.image_type == COMPRESSED_IMAGE:
            params = [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality] if self.encoding == "jpeg" else []
            ok, buf = cv2.imencode(".jpg" if self.encoding == "jpeg" else ".png",
                                   cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), params)
            if not ok:
                raise OSError(f"OpenCV could not encode a {self.encoding} frame")
            msg = types[COMPRESSED_IMAGE](header=header, format=self.encoding, data=buf.reshape(-1))
        else:
            pixels = {"rgb8": rgb, "bgr8": rgb[..., ::-1],
                      "mono8": cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)[..., None]}[self.encoding]
            pixels = np.ascontiguousarray(pixels)
            h, w, c = pixels.shape
            msg = types[IMAGE](header=header, height=h, width=w, encoding=self.encoding, is_bigendian=0,
                               step=w * c, data=pixels.reshape(-1))
        self._write(self.image_conn, self.image_type, stamp_ns, msg)

    def joints(self, stamp_ns: int, names: Sequence[str], positions: FloatArray,
               velocities: FloatArray | None = None) -> None:
        """Write one JointState: positions (n,) rad (and velocities (n,) rad/s) of names, stamped stamp_ns."""
        msg = self.typestore.types[JOINT_STATE](
            header=self._header(stamp_ns, ""), name=list(names), position=np.asarray(positions, np.float64),
            velocity=np.asarray(velocities if velocities is not None else [], np.float64),
            effort=np.zeros(0))
        self._write(self.joint_conn, JOINT_STATE, stamp_ns, msg)

    def close(self) -> Path:
        """Finish the bag; returns its path."""
        self.writer.close()
        return self.path

    def abort(self) -> None:
        """Stop writing and remove the partial bag."""
        self.writer.abort()


__all__ = [
    "CAMERA_INFO",
    "COMPRESSED_IMAGE",
    "IMAGE",
    "IMAGE_ENCODINGS",
    "JOINT_STATE",
    "BagRecording",
    "BagTopics",
    "BagWriter",
    "decode_image",
    "intrinsics_from_camera_info",
    "is_bag",
    "read_bag",
    "read_camera_info_yaml",
]
