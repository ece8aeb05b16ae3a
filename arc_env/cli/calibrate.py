"""``arc-calib calibrate``: a recording in, ``T_camera_base`` with its uncertainty and ROS exports out.

For each motion of the recording (``arc_env.robot.recording``): decode its frames, track keypoints on the
moving links, and hand the tracks with the joint offset of every frame to the calibrator
(``arc_env.robot.session.calibrate_recording``), which updates its estimate after every motion (the
paper's Algorithm 1, so the convergence monitor sees the sequence of estimates). The result is written
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

import cv2
import numpy as np

from arc_env.cli.progress import Progress
from arc_env.cli.result import add_result_arguments, check_frame_names, check_outputs, finish
from arc_env.robot.exports import check_frame_name
from arc_env.robot.overlay import RobotProjector, draw_overlay
from arc_env.robot.recording import read_recording
from arc_env.robot.session import CalibrationRun, UsableCriteria, calibrate_recording
from solver.arrays import evenly_spaced
from solver.errors import InvalidInputError
from solver.frames import check_transform


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


def run_calibrate(args: argparse.Namespace) -> int:
    """``arc-calib calibrate`` from parsed arguments; returns the exit code (0 only for a usable result)."""
    UsableCriteria(min_motions=args.min_motions, max_std_deg=args.max_std_deg, max_std_mm=args.max_std_mm)
    inputs = [Path(args.recording)] + ([Path(args.ground_truth)] if args.ground_truth else [])
    check_outputs(Path(args.output), inputs, args.force, Path(args.overlay) if args.overlay else None)
    check_frame_names(args)
    truth = _read_ground_truth(Path(args.ground_truth)) if args.ground_truth else None
    started = time.perf_counter()
    recording = read_recording(args.recording, time_offset_s=args.time_offset)
    if args.base_frame is None:
        check_frame_name(recording.base_body, f"{recording.path / 'robot.json'}: the base body (or give --base-frame)")
    usable = recording.usable
    print(f"{recording.path}: {len(recording.motions)} motions ({len(usable)} with one moving joint), camera "
          f"{recording.intrinsics.width}x{recording.intrinsics.height}"
          f"{' with distortion' if recording.intrinsics.dist.size and np.any(recording.intrinsics.dist) else ''}, "
          f"robot {recording.model_path.name} (base {recording.base_body}, {len(recording.joint_names)} joints)",
          file=sys.stderr)
    if recording.ignored_joints:
        print(f"note: joints.csv columns ignored (not hinge joints of the arm): {list(recording.ignored_joints)}",
              file=sys.stderr)
    with Progress(max(len(recording.motions), 1), "motions", enabled=not args.quiet) as bar:
        run = calibrate_recording(recording, on_motion=bar.step)
    overlays = (lambda: render_overlays(run, Path(args.overlay))) if args.overlay else None
    return finish(run, args, args.base_frame or recording.base_body, overlays, truth, started)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The ``arc-calib calibrate`` options."""
    parser.add_argument("recording", help="the recording directory (docs/recording-format.md)")
    add_result_arguments(parser)
    parser.add_argument("--overlay", metavar="DIR", help="write PNGs of the robot drawn with the estimate here")
    parser.add_argument("--time-offset", type=float, default=0.0, metavar="SECONDS",
                        help="d = t_joint - t_camera, s: the joints at an exposure stamped t are read at t + d "
                             "(d > 0: joint stamps late; record --joint-latency-ms 20 is d = 0.020). Needs time "
                             "stamps (recording format 2 or a bag); default 0")
    parser.add_argument("--ground-truth", metavar="FILE",
                        help="a <recording>.ground_truth.json (simulated recordings): also print the true error")
