"""``arc-calib calibrate``: a recording or a ROS bag in, ``T_camera_base`` with its uncertainty and ROS exports out.

A bag (``arc_env.robot.bag``: a ROS 2 bag directory, a ``.mcap`` file or a ROS 1 ``.bag``) is read into
the same recording: the motions are the segments of its joint stream where one joint turns alone
(printed, with the spans skipped and why), the robot model comes from ``--robot``/``--base-body``.

For each motion of the recording (``arc_env.robot.recording``): decode its frames, track keypoints on the
moving links, and hand the tracks with the joint offset of every frame to the calibrator
(``arc_env.robot.session.calibrate_recording``), which updates its estimate after every motion (the
paper's Algorithm 1, so the convergence monitor sees the sequence of estimates). With time stamps (format
2, a bag) the joints are read again at the estimated time offset while its correction is large
(``arc_env.robot.session.calibrate_reading_offset``). The result is written
only when it is usable (``arc_env.robot.session``'s module doc); otherwise nothing is written and the
exit code is 1. No simulator is involved: no GL context is created, even with ``--overlay`` (the robot
is drawn by projecting its model with OpenCV).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from arc_env.cli.progress import Progress
from arc_env.cli.result import add_result_arguments, check_frame_names, check_outputs, finish
from arc_env.cli.viewer import add_rerun_arguments, check_rerun_save, open_rerun_log
from arc_env.robot.bag import BagRecording, is_bag, read_bag
from arc_env.robot.exports import calib_name_from, check_frame_name, easy_handeye2_install_path, ros_base_frame
from arc_env.robot.overlay import RobotProjector, draw_overlay
from arc_env.robot.recording import Recording, read_recording
from arc_env.robot.rendering import offscreen_gl_problem
from arc_env.robot.report import ReportCollector, fan_out, report_html
from arc_env.robot.segmentation import SegmentConfig
from arc_env.robot.session import OUTLINE_FRAMES, CalibrationRun, UsableCriteria, calibrate_reading_offset
from solver.arrays import evenly_spaced
from solver.errors import InvalidInputError
from solver.frames import check_transform
from solver.observations import CameraIntrinsics


def render_overlays(run: CalibrationRun, out_dir: Path, n_motions: int = 4) -> dict[Path, bytes]:
    """PNGs of the robot drawn with the estimate over the middle frame of up to ``n_motions`` accepted motions.

    Returns:
        {path in out_dir: PNG bytes}; nothing is written here.
    """
    rec = run.recording
    T_camera_base = run.calibrator.state.T_camera_base
    assert rec is not None and T_camera_base is not None
    projector = RobotProjector(rec.robot, rec.intrinsics)
    accepted = [m for m, d in zip(rec.motions, run.diagnostics, strict=True) if d.accepted]
    pick = [accepted[k] for k in evenly_spaced(len(accepted), n_motions)]
    files: dict[Path, bytes] = {}
    for m in pick:
        k = m.n_frames // 2
        frame = rec.frames(m)[k]
        q = m.q_start.copy()
        q[m.joint] += m.delta[k]
        mask = projector.mask(q, T_camera_base)
        image = draw_overlay(frame, mask, f"motion {m.name}, frame {k}: robot model drawn with the estimate")
        ok, png = cv2.imencode(".png", image)
        if not ok:
            raise OSError(f"OpenCV could not encode the overlay of motion {m.name}")
        files[out_dir / f"overlay_motion_{m.name}.png"] = png.tobytes()
    return files


def _read_ground_truth(path: Path) -> np.ndarray:
    try:
        data = json.loads(Path(path).read_text())
        return check_transform(np.asarray(data["T_camera_base"], dtype=np.float64), f"{path}: T_camera_base")
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InvalidInputError(f"{path}: not a ground-truth file with a T_camera_base: {exc}") from exc


#: The options that only apply to bags (``arc-calib calibrate`` refuses them with a recording directory).
BAG_OPTIONS = ("robot", "base_body", "image_topic", "camera_info_topic", "joint_topic", "camera_info")


def read_input(args: argparse.Namespace, quiet: bool = False) -> Recording:
    """The recording directory or the bag named on the command line."""
    if not is_bag(args.recording):
        given = [f"--{o.replace('_', '-')}" for o in BAG_OPTIONS if getattr(args, o) is not None]
        if given:
            raise InvalidInputError(f"{args.recording}: {', '.join(given)} apply to bags only (a .mcap or .bag file, "
                                    "or a ROS 2 bag directory with metadata.yaml); a recording names its robot "
                                    "and camera itself")
        return read_recording(args.recording, time_offset_s=args.time_offset)
    if not args.robot:
        raise InvalidInputError(f"{args.recording}: a bag needs --robot FILE (the robot's MJCF or URDF) and "
                                "--base-body NAME (default: the model's first body)")
    recording = read_bag(args.recording, args.robot, args.base_body, image_topic=args.image_topic,
                         camera_info_topic=args.camera_info_topic, joint_topic=args.joint_topic,
                         camera_info_file=args.camera_info, time_offset_s=args.time_offset,
                         segmentation=SegmentConfig(min_delta_rad=args.min_delta))
    if not quiet:
        print_segments(recording)
    return recording


def _lens(intrinsics: CameraIntrinsics) -> str:
    """How the summary line names the camera's lens model ("" for a distortion-free pinhole)."""
    if intrinsics.is_fisheye:
        return " with a fisheye lens (OpenCV's equidistant model)"
    return " with distortion" if intrinsics.dist.size and np.any(intrinsics.dist) else ""


def print_segments(bag: BagRecording) -> None:
    """The motions found in the bag's joint stream and the spans skipped, on stderr."""
    t = bag.topics
    print(f"{bag.path}: images {t.image} ({bag.n_images}), joints {t.joints}, camera "
          f"{t.camera_info or bag.camera_source}; time offset {bag.time_offset_s * 1e3:+g} ms", file=sys.stderr)
    names, t0 = bag.joint_names, bag.t0
    print(f"{len(bag.segments)} exploratory motion(s) found in {t.joints} (times from the first image):",
          file=sys.stderr)
    for m, s in zip(bag.motions, bag.segments, strict=True):
        pruned = f"  (pruned: {m.pruned})" if m.pruned else ""
        print(f"  motion {m.name}: {names[int(np.argmax(s.ranges))]} delta {s.delta:+.3f} rad, {s.duration:.2f} s "
              f"({s.t_start - t0:.2f}-{s.t_stop - t0:.2f} s), {m.n_frames} frames{pruned}", file=sys.stderr)
    if bag.skipped:
        print(f"{len(bag.skipped)} span(s) skipped:", file=sys.stderr)
        for s in bag.skipped:
            print(f"  {s.t_start - t0:.2f}-{s.t_stop - t0:.2f} s ({s.duration:.2f} s): {s.reason}", file=sys.stderr)


def run_calibrate(args: argparse.Namespace) -> int:
    """``arc-calib calibrate`` from parsed arguments; returns the exit code (0 only for a usable result)."""
    UsableCriteria(min_motions=args.min_motions, max_std_deg=args.max_std_deg, max_std_mm=args.max_std_mm)
    inputs = [Path(args.recording)] + [Path(f) for f in (args.ground_truth, args.robot, args.camera_info) if f]
    check_frame_names(args)
    source = Path(args.recording).resolve()
    calib_name = args.calib_name or calib_name_from(source.stem if source.is_file() else source.name)
    check_outputs(Path(args.output), inputs, args.force, Path(args.overlay) if args.overlay else None,
                  installed_calib=easy_handeye2_install_path(calib_name) if args.install_calib else None, report=True)
    check_rerun_save(args, inputs, args.force)
    truth = _read_ground_truth(Path(args.ground_truth)) if args.ground_truth else None
    outline_frames = outline_frames_from(args)
    started = time.perf_counter()
    recording = read_input(args)
    base_frame = args.base_frame or ros_base_frame(recording.base_body)
    if args.base_frame is None:
        where = (f"{recording.path / 'robot.json'}: the base body" if not isinstance(recording, BagRecording)
                 else f"--base-body {recording.base_body}")
        check_frame_name(base_frame, f"{where} (or give --base-frame)")
    usable = recording.usable
    print(f"{recording.path}: {len(recording.motions)} motions ({len(usable)} with one moving joint), camera "
          f"{recording.intrinsics.width}x{recording.intrinsics.height}"
          f"{_lens(recording.intrinsics)}, "
          f"robot {recording.model_path.name} (base {recording.base_body}, {len(recording.joint_names)} joints)",
          file=sys.stderr)
    if recording.ignored_joints:
        print(f"note: joints.csv columns ignored (not hinge joints of the arm): {list(recording.ignored_joints)}",
              file=sys.stderr)
    def read(offset: float) -> Recording | BagRecording:  # the joints read at another time offset
        if offset == args.time_offset:
            return recording
        print(f"time offset: reading the joints again at {offset * 1e3:+.2f} ms", file=sys.stderr)
        return read_input(argparse.Namespace(**{**vars(args), "time_offset": offset}), quiet=True)

    log = open_rerun_log(args, recording.robot, recording.intrinsics, f"calibrate {recording.path.name}", truth)
    collected = ReportCollector(truth)
    try:
        with Progress(max(len(recording.motions), 1), "motions", enabled=not args.quiet) as bar:
            run = calibrate_reading_offset(read, args.time_offset, on_motion=bar.step,
                                           observer=fan_out(collected, log), outline_frames=outline_frames)
    except BaseException:
        if log is not None:
            log.abort()
        raise
    if log is not None:
        log.finish(run.calibrator)
        log.close()
        print(f"rerun log: {args.rerun_save}" if args.rerun_save else "rerun log: sent to the viewer", file=sys.stderr)
    overlays = (lambda: render_overlays(run, Path(args.overlay))) if args.overlay else None

    def report(result: dict[str, Any], images: dict[Path, bytes]) -> str:
        return report_html(run, result, collected, recording.intrinsics, images, truth)

    return finish(run, args, base_frame, overlays, truth, started, calib_name, report)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The ``arc-calib calibrate`` options."""
    parser.add_argument("recording", help="the recording directory (docs/recording-format.md), or a ROS bag: a "
                                          "ROS 2 bag directory (sqlite3 or MCAP), a .mcap file or a ROS 1 .bag")
    add_result_arguments(parser)
    parser.add_argument("--overlay", metavar="DIR", help="write PNGs of the robot drawn with the estimate here")
    add_input_arguments(parser)
    parser.add_argument("--ground-truth", metavar="FILE",
                        help="a <recording>.ground_truth.json (simulated recordings): also print the true error")
    add_outline_argument(parser)
    add_rerun_arguments(parser)


def add_outline_argument(parser: argparse.ArgumentParser) -> None:
    """``--outline-frames N``: the outline stage (``SessionConfig.outline_frames``), for calibrate, run and demo."""
    parser.add_argument("--outline-frames", type=int, default=None, metavar="N",
                        help="combine the tracks' pose with the robot's outlines in N images per motion (its model "
                             f"rendered offscreen: needs EGL or OSMesa); default {OUTLINE_FRAMES} where an offscreen "
                             "GL context can be made, else 0 with a note; 0: the tracks alone")


def outline_frames_from(args: argparse.Namespace) -> int:
    """The outline stage's images per motion from ``--outline-frames`` (``add_outline_argument``).

    Not given: ``OUTLINE_FRAMES`` where an offscreen GL context can be made (``offscreen_gl_problem``), else 0 with a
    note on stderr. Given and above 0 where none can be made: an error that says why and what to install.
    """
    asked = getattr(args, "outline_frames", None)
    if asked is not None and asked < 0:
        raise InvalidInputError(f"--outline-frames must be >= 0, got {asked}")
    if asked == 0:
        return 0
    problem = offscreen_gl_problem()
    if not problem:
        return OUTLINE_FRAMES if asked is None else int(asked)
    if asked is not None:
        raise InvalidInputError(f"--outline-frames {asked}: the outline stage renders the robot's model, and {problem}")
    print(f"note: the outline stage is off (the tracks alone; --outline-frames 0 says so and skips this check): "
          f"{problem}", file=sys.stderr)
    return 0


def add_input_arguments(parser: argparse.ArgumentParser, time_offset_default: str = "default 0") -> None:
    """The options that read a recording or a bag (``read_input``): ``--time-offset`` and the bag group.

    ``time_offset_default`` ends the ``--time-offset`` help (``verify``'s default is the result's offset).
    """
    parser.add_argument("--time-offset", type=float, default=0.0, metavar="SECONDS",
                        help="d = t_joint - t_camera, s: the joints at an exposure stamped t are read at t + d "
                             "(d > 0: joint stamps late; record --joint-latency-ms 20 is d = 0.020). Needs time "
                             f"stamps (recording format 2 or a bag); {time_offset_default}")
    bag = parser.add_argument_group("bags", "options for a ROS bag input (topics are found by message type)")
    bag.add_argument("--robot", metavar="FILE", help="the robot's MJCF or URDF (required for a bag)")
    bag.add_argument("--base-body", metavar="NAME",
                     help="the body the result is expressed in (default: the model's first body)")
    bag.add_argument("--image-topic", help="the sensor_msgs/Image or CompressedImage topic, when several")
    bag.add_argument("--camera-info-topic", help="the sensor_msgs/CameraInfo topic, when several")
    bag.add_argument("--joint-topic", help="the sensor_msgs/JointState topic, when several")
    bag.add_argument("--camera-info", metavar="FILE",
                     help="a camera_calibration_parsers YAML with the intrinsics, instead of a CameraInfo topic")
    bag.add_argument("--min-delta", type=float, default=SegmentConfig.min_delta_rad, metavar="RAD",
                     help="smallest turn of one joint that counts as an exploratory motion, rad (default "
                          f"{SegmentConfig.min_delta_rad})")
