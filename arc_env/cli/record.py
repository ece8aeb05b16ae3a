"""``arc-calib record``: a simulated episode written as a recording (``arc_env.sim.record``)."""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from arc_env.cli.progress import Progress
from arc_env.robot.library import robot_from_arguments
from arc_env.robot.motion_script import read_camera_pose, read_trajectory
from arc_env.sim.distortion import parse_dist
from arc_env.sim.record import RecordSettings, ground_truth_path, record_episode


def run_record(args: argparse.Namespace) -> int:
    """``arc-calib record`` from parsed arguments; returns the exit code."""
    robot = robot_from_arguments(args.robot, args.base_body)
    dist = tuple(parse_dist(args.dist)) if args.dist else ()
    camera_pose = read_camera_pose(args.camera_pose) if args.camera_pose else None
    duration = float(read_trajectory(args.trajectory).times[-1]) if args.trajectory else 0.0
    settings = RecordSettings(out=Path(args.out), motions=args.motions, seed=args.seed, width=args.width,
                              height=args.height, fx=args.fx, dist=dist, video=args.video, fps=args.fps,
                              robot=robot, realism=args.realism, appearance=args.appearance,
                              joint_latency_s=args.joint_latency_ms / 1000.0, format=args.format,
                              image_encoding=args.image_encoding,
                              trajectory=Path(args.trajectory) if args.trajectory else None, camera_pose=camera_pose,
                              background=args.background)
    started = time.perf_counter()
    steps, unit = (max(1, math.ceil(duration)), "s of trajectory") if args.trajectory else (settings.motions,
                                                                                           "motions recorded")
    with Progress(steps, unit) as bar:
        truth = record_episode(settings, on_motion=bar.step)
    kind = {"dir": "", "bag": "ROS 2 bag (sqlite3) ", "mcap": "ROS 2 bag (MCAP) "}[settings.format]
    media = args.image_encoding if settings.format != "dir" else "MP4" if settings.video else "PNG"
    what = f"{args.trajectory} replayed, {duration:.1f} s" if args.trajectory else f"{settings.motions} motions"
    print(f"wrote {kind}{settings.out} ({what}, {settings.width}x{settings.height}, "
          f"{media}{', distorted' if dist else ''}"
          f"{f', joint log {args.joint_latency_ms:+g} ms' if args.joint_latency_ms else ''}) in "
          f"{time.perf_counter() - started:.1f} s")
    print(f"ground truth (not part of the recording): {ground_truth_path(settings.out)}")
    if settings.format != "dir":
        print(f"robot model (beside it): {truth['robot_model']}; calibrate with:\n  arc-calib calibrate {settings.out} "
              f"--robot {truth['robot_model']} --base-body {truth['base_body']} --output result.json"
              f"{f' --time-offset {settings.joint_latency_s:g}' if settings.joint_latency_s else ''}")
    np.set_printoptions(precision=5, suppress=True)
    print(f"T_camera_base (true):\n{np.asarray(truth['T_camera_base'])}")
    return 0
