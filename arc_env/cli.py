"""The ``arc-calib`` command.

``arc-calib demo`` runs one calibration episode in the MuJoCo scene (default: the Franka Panda,
1920x1080 D415-like camera at a random pose) with random collision-free motions, rendered pixels
and optical-flow tracking, and prints motion by motion what the calibrator made of it.
``arc-calib demo --synthetic`` does the same on synthetic keypoints (the Panda's DH kinematics,
0.5 px noise, 10% bad tracks) without rendering: the solver alone.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from solver import (
    PANDA,
    ArcCalibError,
    Calibrator,
    InvalidInputError,
    SyntheticConfig,
    SyntheticScene,
    d415_intrinsics,
    pose_errors,
    quaternion_xyzw_from_matrix,
    sample_camera_pose,
)


def _demo_synthetic(args: argparse.Namespace) -> int:
    rng = np.random.default_rng(args.seed)
    T_true = sample_camera_pose(rng)
    intrinsics = d415_intrinsics()
    scene = SyntheticScene(PANDA, intrinsics, T_true,
                           SyntheticConfig(noise_px=args.noise, outlier_fraction=args.outliers), rng)
    calibrator = Calibrator(intrinsics, PANDA.axis_and_point)
    print(f"synthetic Franka Panda, camera 1920x1080 fx=fy=1380, {args.noise} px noise, "
          f"{args.outliers:.0%} bad tracks, seed {args.seed}")
    print(f"{'#':>3} {'joint':>5} {'tracks':>6} {'status':>9} {'stage':>8} {'rot err':>10} "
          f"{'trans err':>10} {'1-sigma rot':>11} {'1-sigma t':>10}  note")
    for i in range(args.motions):
        try:
            motion = scene.random_motion(rng)
        except ArcCalibError as exc:
            print(f"arc-calib demo: {exc}", file=sys.stderr)
            return 1
        report = calibrator.add_motion(motion.observation)
        s = calibrator.state
        rot, trans = pose_errors(s.T_camera_base, T_true) if s.T_camera_base is not None else (np.nan, np.nan)
        std_r = f"{np.linalg.norm(s.std[:3]):.1e}" if s.std is not None else "-"
        std_t = f"{np.linalg.norm(s.std[3:]) * 1e3:.2f} mm" if s.std is not None else "-"
        note = report.reason or (f"bundle adjustment only; no axis for the linear stage: {report.stage_one}"
                                 if report.stage_one else "")
        note = note or ("" if s.T_camera_base is not None else s.message)
        print(f"{i + 1:>3} {report.joint + 1:>5} {report.n_tracks:>6} "
              f"{'accepted' if report.accepted else 'rejected':>9} {s.stage:>8} {rot:>10.2e} "
              f"{trans * 1e3:>7.2f} mm {std_r:>11} {std_t:>10}  {note[:70]}"
              + ("  [converged]" if s.converged else ""))
        if s.converged and args.stop_when_converged:
            break
    s = calibrator.state
    print()
    rejected = [r for r in calibrator.reports if not r.accepted]
    print(f"motions: {len(calibrator.reports)} executed, {s.n_accepted} accepted, {s.n_rejected} rejected")
    for r in rejected:
        print(f"  motion {r.index + 1} (joint {r.joint + 1}) rejected: {r.reason}")
    if s.T_camera_base is None:
        print(f"no estimate: {s.message}")
        return 1
    rot, trans = pose_errors(s.T_camera_base, T_true)
    np.set_printoptions(precision=5, suppress=True)
    print(f"T_camera_base ({s.stage}; p_camera = T_camera_base @ p_base, OpenCV optical frame):")
    print(s.T_camera_base)
    q = quaternion_xyzw_from_matrix(s.T_camera_base[:3, :3])
    print(f"translation (m): {s.T_camera_base[:3, 3]}  quaternion (x, y, z, w): {q}")
    if s.std is not None:
        print(f"1-sigma: rotation {np.degrees(s.std[:3])} deg, translation {s.std[3:] * 1e3} mm; "
              f"RMS reprojection {s.rms_px:.3f} px")
    print(f"converged: {s.converged}")
    print(f"final error: rotation {rot:.2e} rad ({np.degrees(rot):.4f} deg), translation {trans * 1e3:.3f} mm")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``arc-calib`` console script."""
    parser = argparse.ArgumentParser(prog="arc-calib", description="Markerless camera-to-robot calibration.")
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="run one calibration episode")
    demo.add_argument("--synthetic", action="store_true",
                      help="synthetic Panda kinematics and keypoints, no rendering (solver only)")
    demo.add_argument("--motions", type=int, default=25, help="motion budget (default 25)")
    demo.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    demo.add_argument("--robot", help="robot MJCF or URDF file (default: the gymnasium-robotics Panda)")
    demo.add_argument("--base-body", help="the robot's base body (required with --robot)")
    demo.add_argument("--width", type=int, default=1920, help="image width, px (default 1920)")
    demo.add_argument("--height", type=int, default=1080, help="image height, px (default 1080)")
    demo.add_argument("--oracle", action="store_true",
                      help="projected mesh points instead of rendering and tracking (simulation floor)")
    demo.add_argument("--overlay", metavar="PATH",
                      help="write a PNG of the robot mask rendered with the estimate over a real frame, "
                           "with the IoU against the true mask")
    demo.add_argument("--noise", type=float, default=0.5,
                      help="keypoint noise, px (--synthetic and --oracle; default 0.5)")
    demo.add_argument("--outliers", type=float, default=0.1, help="fraction of bad tracks (--synthetic; default 0.1)")
    demo.add_argument("--stop-when-converged", action="store_true", help="stop at convergence")
    demo.add_argument("--planner", choices=("random", "informed"), default="random",
                      help="motion selection: random (the paper) or informed (ours; default random)")
    record = sub.add_parser("record", help="simulate an episode and write it as a recording (docs/recording-format.md)")
    record.add_argument("--out", required=True, metavar="DIR",
                        help="the recording directory to create; the ground truth goes to DIR.ground_truth.json")
    record.add_argument("--motions", type=int, default=12, help="motions (default 12)")
    record.add_argument("--seed", type=int, default=0, help="random seed: camera pose and motions (default 0)")
    record.add_argument("--width", type=int, default=1920, help="image width, px (default 1920)")
    record.add_argument("--height", type=int, default=1080, help="image height, px (default 1080)")
    record.add_argument("--fx", type=float, help="focal length, px (default 1380 scaled with the width)")
    record.add_argument("--dist", metavar="K1,K2,P1,P2[,K3]",
                        help="simulate a camera with this OpenCV distortion (frames are distorted pinhole renders)")
    record.add_argument("--video", action="store_true", help="one MP4 per motion instead of PNG frames")
    record.add_argument("--fps", type=float, default=30.0,
                        help="frame rate, Hz; joints turn at 1 rad/s (default 30)")
    record.add_argument("--robot", help="robot MJCF or URDF file (default: the gymnasium-robotics Panda)")
    record.add_argument("--base-body", help="the robot's base body (required with --robot)")
    calibrate = sub.add_parser("calibrate", help="calibrate from a recording; write the result and ROS exports")
    from arc_env.calibrate import add_arguments, add_result_arguments

    add_arguments(calibrate)
    run = sub.add_parser("run", help="calibrate online: a planner drives a robot through a driver")
    run.add_argument("--driver", required=True, metavar="MODULE:CLASS",
                     help="a RobotDriver class or factory (docs/driver.md), e.g. arc_env.driver:SimulatedDriver")
    run.add_argument("--motions", type=int, default=25, help="motion budget (default 25)")
    run.add_argument("--seed", type=int, default=0, help="planner seed (default 0)")
    run.add_argument("--planner", choices=("random", "informed"), default="random",
                     help="motion selection (default random, the paper's); informed scores candidates by the "
                          "information they add (no image test: the twin has no camera image)")
    run.add_argument("--all-motions", action="store_true", help="do not stop at convergence")
    run.add_argument("--record", metavar="DIR", help="also save the sweeps as a recording in DIR")
    add_result_arguments(run)
    args = parser.parse_args(argv)
    if args.command == "demo" and args.synthetic and args.planner != "random":
        print("arc-calib: --planner informed needs the MuJoCo scene (drop --synthetic)", file=sys.stderr)
        return 2
    try:
        if args.command == "demo" and args.synthetic:
            return _demo_synthetic(args)
        if args.command == "demo":
            from arc_env.demo import run_demo  # imports MuJoCo: only when a scene is wanted

            return run_demo(args)
        if args.command == "record":
            from arc_env.record import run_record

            return run_record(args)
        if args.command == "run":
            from arc_env.online import run_online

            return run_online(args)
        from arc_env.calibrate import run_calibrate

        return run_calibrate(args)
    except InvalidInputError as exc:
        print(f"arc-calib {args.command}: {exc}", file=sys.stderr)
        return 2 if args.command in ("calibrate", "record", "run") else 1
    except ArcCalibError as exc:
        print(f"arc-calib {args.command}: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:
        print(f"arc-calib {args.command}: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
