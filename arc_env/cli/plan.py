"""``arc-calib plan``: a motion script out -- N exploratory motions and their transits as a timed joint trajectory.

The robot's own controller replays the trajectory while ``ros2 bag record`` records the camera and the joint
states; ``arc-calib calibrate BAG`` finds the motions in the joint stream. Planning, timing and the formats
are ``arc_env.robot.motion_script``'s; this module reads the inputs, checks the outputs and writes them
(all or nothing, ``arc_env.robot.exports.write_files_atomic``). No simulator is involved.

Outputs, from ``--output motions.yaml``:

* ``motions.yaml``: a ``trajectory_msgs/JointTrajectory`` (``header``, ``joint_names``, ``points`` with
  ``positions``, ``velocities`` and ``time_from_start: {sec, nanosec}``);
* ``motions.csv``: the same points, ``t`` then one column per joint (s, rad);
* ``motions.sweeps.yaml``: which span of the trajectory is which exploratory motion (joint, Q, Delta, start
  and stop times, the points it spans), and what the plan was made from.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from arc_env.robot.bag import read_camera_info_yaml
from arc_env.robot.exports import write_files_atomic
from arc_env.robot.model import RobotModel, RobotSource
from arc_env.robot.motion_script import (
    ScriptConfig,
    dump_yaml,
    plan_motion_script,
    read_camera_pose,
    sweeps_document,
    trajectory_csv,
    trajectory_message,
)
from arc_env.robot.obstacles import read_obstacles
from solver.errors import InvalidInputError


def output_paths(output: Path) -> dict[str, Path]:
    """The files ``plan --output X.yaml`` writes: {"trajectory": X.yaml, "csv": X.csv, "sweeps": X.sweeps.yaml}."""
    return {"trajectory": output, "csv": output.with_suffix(".csv"),
            "sweeps": output.with_name(output.stem + ".sweeps.yaml")}


def check_plan_outputs(output: Path, inputs: list[Path], force: bool) -> dict[str, Path]:
    """The output files, after refusing (before any work) any that would overwrite an input or, without force, a file.

    Raises:
        InvalidInputError: the output is not .yaml/.yml, its folder is missing, an output is an input (or
            inside an input folder), is a directory, or exists without ``force``.
    """
    if output.suffix not in (".yaml", ".yml"):
        raise InvalidInputError(f"--output must be a .yaml file (a JointTrajectory), got {output}")
    if not output.parent.is_dir():
        raise InvalidInputError(f"--output: directory {output.parent} does not exist")
    paths = output_paths(output)
    for path in paths.values():
        for source in inputs:
            if path.resolve().is_relative_to(source.resolve()):
                raise InvalidInputError(f"{path}: is the input {source} (or inside it); write the plan elsewhere "
                                        "(ARC-Calib never writes into what it reads)")
        if path.is_dir():
            raise InvalidInputError(f"{path}: is a directory")
        if (path.exists() or path.is_symlink()) and not force:
            raise InvalidInputError(f"{path}: already exists; use --force to replace it")
    return paths


def _parse_start(text: str, n: int) -> np.ndarray:
    try:
        q = np.array([float(v) for v in text.split(",")])
    except ValueError as exc:
        raise InvalidInputError(f"--start must be {n} comma-separated numbers (rad), got {text!r}") from exc
    if q.shape != (n,) or not np.all(np.isfinite(q)):
        raise InvalidInputError(f"--start must be {n} finite comma-separated numbers (rad), got {text!r}")
    return q


def run_plan(args: argparse.Namespace) -> int:
    """``arc-calib plan`` from parsed arguments; returns the exit code."""
    if args.robot and not args.base_body:
        raise InvalidInputError("--robot needs --base-body (the body whose frame is the robot's base)")
    if args.camera_pose_guess and not args.camera_info:
        raise InvalidInputError("--camera-pose-guess needs --camera-info (the image the links must stay inside)")
    config = ScriptConfig(max_speed=args.max_speed, sweep_speed=args.sweep_speed, max_accel=args.max_accel,
                          rest_s=args.rest)
    inputs = [Path(f) for f in (args.robot, args.camera_info, args.camera_pose_guess, args.obstacles) if f]
    paths = check_plan_outputs(Path(args.output), inputs, args.force)
    source = RobotSource(path=args.robot, base_body=args.base_body, home=()) if args.robot else RobotSource()
    obstacles = read_obstacles(args.obstacles) if args.obstacles else ()
    intrinsics = read_camera_info_yaml(args.camera_info) if args.camera_info else None
    guess = read_camera_pose(args.camera_pose_guess) if args.camera_pose_guess else None
    robot = RobotModel.load(source, obstacles=obstacles)
    start = _parse_start(args.start, robot.n_joints) if args.start else None
    script = plan_motion_script(robot, args.motions, intrinsics=intrinsics, T_camera_base_guess=guess, start=start,
                                config=config, rng=np.random.default_rng(args.seed),
                                on_motion=lambda line: print(f"  {line}", file=sys.stderr))
    about = {
        "note": "the exploratory motions of the trajectory beside this file (arc-calib plan); times in s from its "
                "start, angles in rad",
        "trajectory": paths["trajectory"].name,
        "robot": args.robot or "gymnasium-robotics Franka Panda",
        "base_body": source.base_body,
        "seed": args.seed,
        "obstacles": len(obstacles),
        "view_check": "moving links in the guessed camera's image" if guess is not None else "none",
        "max_speed_rad_s": config.max_speed,
        "sweep_speed_rad_s": config.sweep_speed,
        "max_accel_rad_s2": config.max_accel,
        "rest_s": config.rest_s,
    }
    write_files_atomic({paths["trajectory"]: dump_yaml(trajectory_message(script)),
                        paths["csv"]: trajectory_csv(script),
                        paths["sweeps"]: dump_yaml(sweeps_document(script, about))})
    for k, s in enumerate(script.sweeps):
        print(f"motion {k:03d}: {script.joint_names[s.joint]} delta {s.delta:+.3f} rad, "
              f"{s.t_start:.2f}-{s.t_stop:.2f} s")
    print(f"wrote {paths['trajectory']} ({len(script.times)} points, {script.duration:.1f} s, "
          f"{len(script.sweeps)} motions), {paths['csv']} and {paths['sweeps']}")
    return 0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The ``arc-calib plan`` options."""
    parser.add_argument("--output", required=True, metavar="FILE.yaml",
                        help="the JointTrajectory YAML to write; FILE.csv and FILE.sweeps.yaml go beside it")
    parser.add_argument("--motions", type=int, default=12, help="exploratory motions (default 12)")
    parser.add_argument("--seed", type=int, default=0, help="random seed of the motions and transits (default 0)")
    parser.add_argument("--robot", metavar="FILE",
                        help="robot MJCF or URDF file (default: the gymnasium-robotics Panda)")
    parser.add_argument("--base-body", metavar="NAME", help="the robot's base body (required with --robot)")
    parser.add_argument("--camera-info", metavar="FILE",
                        help="a camera_calibration_parsers YAML with the camera's intrinsics (used with "
                             "--camera-pose-guess)")
    parser.add_argument("--camera-pose-guess", metavar="FILE",
                        help="a rough T_camera_base (YAML/JSON: T_camera_base 4x4, T_base_camera 4x4, or translation "
                             "+ quaternion_xyzw of T_camera_base; a result.json works): keep the moving links inside "
                             "the camera's image")
    parser.add_argument("--obstacles", metavar="FILE",
                        help="boxes and spheres in the base frame to keep clear of (YAML/JSON list; see "
                             "docs/motion-script.md)")
    parser.add_argument("--start", metavar="Q1,...,Qn",
                        help="where the arm is when the trajectory starts, rad (default: the model's home; zeros "
                             "clipped to the limits for --robot)")
    parser.add_argument("--max-speed", type=float, default=ScriptConfig.max_speed, metavar="RAD_S",
                        help=f"peak joint speed on transits, rad/s (default {ScriptConfig.max_speed})")
    parser.add_argument("--sweep-speed", type=float, default=ScriptConfig.sweep_speed, metavar="RAD_S",
                        help=f"peak speed of the turning joint on a sweep, rad/s (default {ScriptConfig.sweep_speed})")
    parser.add_argument("--max-accel", type=float, default=ScriptConfig.max_accel, metavar="RAD_S2",
                        help=f"largest joint acceleration, rad/s^2 (default {ScriptConfig.max_accel})")
    parser.add_argument("--rest", type=float, default=ScriptConfig.rest_s, metavar="S",
                        help=f"rest before and after each sweep, s (default {ScriptConfig.rest_s})")
    parser.add_argument("--force", action="store_true", help="replace existing output files")
