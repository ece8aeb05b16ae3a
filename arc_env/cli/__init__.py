"""The ``arc-calib`` command: one module per subcommand.

* ``demo`` (``arc_env.cli.demo``): one calibration episode in the MuJoCo scene (default: the Franka
  Panda, 1920x1080 D415-like camera at a random pose), narrated motion by motion; ``--synthetic``: the
  solver alone on synthetic keypoints, without rendering.
* ``record`` (``arc_env.cli.record``): a simulated episode written as a recording.
* ``calibrate`` (``arc_env.cli.calibrate``): a recording in, a calibration and ROS exports out (no simulator).
* ``run`` (``arc_env.cli.run``): online calibration, a planner driving a ``RobotDriver``.
* ``export`` (``arc_env.cli.export``): rewrite the ROS exports of an existing result (no recalibration).
* ``verify`` (``arc_env.cli.verify``): check a result against a fresh recording or bag, the pose held fixed
  (no simulator).
* ``plan`` (``arc_env.cli.plan``): a motion script out, a timed joint trajectory of exploratory motions for a
  robot's own controller to replay while a bag records (no simulator).

Each subcommand's module is imported only when it runs, so ``calibrate`` never imports the simulator.
"""

from __future__ import annotations

import argparse
import sys

from solver.errors import ArcCalibError, InvalidInputError

#: The realism presets, robot appearances and backgrounds of the simulator (``arc_env.sim.imaging``,
#: ``arc_env.sim.background``; kept here so that ``--help`` does not import the simulator).
REALISMS = ("clean", "realistic")
APPEARANCES = ("painted", "as_shipped", "realistic")
BACKGROUNDS = ("floor", "lab")


def _add_look_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--realism", choices=REALISMS, default="clean",
                        help="clean renders (default), or realistic: sensor noise (~3 grey levels), 8 ms motion "
                             "blur, +-5%% auto-exposure gain, H.264 video, shadows, the realistic appearance")
    parser.add_argument("--appearance", choices=APPEARANCES,
                        help="the robot's surface: painted (uniform speckle; the clean default), as_shipped (the "
                             "model's own materials), realistic (plus sparse screws, seams, labels and cables; "
                             "the realistic default)")
    parser.add_argument("--background", choices=BACKGROUNDS, default="floor",
                        help="what stands behind the robot: the floor alone (default) or a lab's cabinets, shelves, "
                             "posters and boxes, drawn from --seed")


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``arc-calib`` console script."""
    from arc_env.cli.calibrate import add_arguments, add_outline_argument
    from arc_env.cli.viewer import add_rerun_arguments

    parser = argparse.ArgumentParser(prog="arc-calib", description="Markerless camera-to-robot calibration.")
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="run one calibration episode")
    demo.add_argument("--synthetic", action="store_true",
                      help="synthetic Panda kinematics and keypoints, no rendering (solver only)")
    demo.add_argument("--motions", type=int, default=25, help="motion budget (default 25)")
    demo.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    demo.add_argument("--robot", help="a robot of the library (panda, iiwa, xarm6) or an MJCF or URDF file "
                                            "(default: the gymnasium-robotics Panda)")
    demo.add_argument("--base-body", help="the robot's base body (required with a model file)")
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
    _add_look_arguments(demo)
    add_rerun_arguments(demo)
    add_outline_argument(demo)
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
    record.add_argument("--robot", help="a robot of the library (panda, iiwa, xarm6) or an MJCF or URDF file "
                                            "(default: the gymnasium-robotics Panda)")
    record.add_argument("--base-body", help="the robot's base body (required with a model file)")
    record.add_argument("--joint-latency-ms", type=float, default=0.0, metavar="MS",
                        help="stamp the joint log this late relative to the camera (negative: early), as a rig "
                             "whose joint_states clock disagrees with the camera's; default 0")
    record.add_argument("--format", choices=("dir", "bag", "mcap"), default="dir",
                        help="dir: a recording directory (default); bag / mcap: one continuous ROS 2 bag (sqlite3 / "
                             "MCAP storage) with camera_info, images and 200 Hz joint_states, transits included; "
                             "the robot model goes to DIR.robot/")
    record.add_argument("--image-encoding", choices=("rgb8", "jpeg"), default="jpeg",
                        help="a bag's images: rgb8 (sensor_msgs/Image) or jpeg (CompressedImage; default)")
    record.add_argument("--trajectory", metavar="FILE.yaml",
                        help="replay this JointTrajectory YAML (arc-calib plan's) instead of planning motions: the "
                             "arm follows it while the camera renders at --fps and the joints are logged at 200 Hz "
                             "(--motions is ignored; --format dir keeps the motions segmentation finds)")
    record.add_argument("--camera-pose", metavar="FILE",
                        help="the simulated camera's T_camera_base (YAML/JSON, as plan's --camera-pose-guess reads "
                             "it) instead of one sampled from --seed")
    _add_look_arguments(record)
    calibrate = sub.add_parser("calibrate", help="calibrate from a recording; write the result and ROS exports")
    from arc_env.cli.result import add_result_arguments

    add_arguments(calibrate)
    run = sub.add_parser("run", help="calibrate online: a planner drives a robot through a driver")
    run.add_argument("--driver", required=True, metavar="MODULE:CLASS",
                     help="a RobotDriver class or factory (docs/driver.md), e.g. arc_env.sim.driver:SimulatedDriver")
    run.add_argument("--motions", type=int, default=25, help="motion budget (default 25)")
    run.add_argument("--seed", type=int, default=0, help="planner seed (default 0)")
    run.add_argument("--planner", choices=("random", "informed"), default="random",
                     help="motion selection (default random, the paper's); informed scores candidates by the "
                          "information they add (no image test: the twin has no camera image)")
    run.add_argument("--all-motions", action="store_true", help="do not stop at convergence")
    run.add_argument("--overlap", action="store_true",
                     help="track and calibrate each motion while the robot executes the next (the robot does not "
                          "wait for the computer; the planner sees the estimate one motion late)")
    run.add_argument("--record", metavar="DIR", help="also save the sweeps as a recording in DIR")
    run.add_argument("--resume", metavar="DIR",
                     help="continue from the motions of an earlier run's recording (it is read, never written)")
    add_result_arguments(run)
    add_rerun_arguments(run)
    add_outline_argument(run)
    export = sub.add_parser("export", help="rewrite the ROS exports of a result.json without recalibrating")
    from arc_env.cli.export import add_arguments as add_export_arguments

    add_export_arguments(export)
    verify = sub.add_parser("verify", help="check a result.json against a fresh recording or bag (pose fixed): "
                                           "residuals, mask IoU, consistent (exit 0) or inconsistent (exit 1)")
    from arc_env.cli.verify import add_arguments as add_verify_arguments

    add_verify_arguments(verify)
    plan = sub.add_parser("plan", help="write exploratory motions as a timed joint trajectory (JointTrajectory "
                                       "YAML and CSV) for the robot's controller to replay while recording a bag")
    from arc_env.cli.plan import add_arguments as add_plan_arguments

    add_plan_arguments(plan)
    args = parser.parse_args(argv)
    if args.command == "demo" and args.synthetic and args.planner != "random":
        print("arc-calib: --planner informed needs the MuJoCo scene (drop --synthetic)", file=sys.stderr)
        return 2
    if args.command == "demo" and args.synthetic and (args.rerun or args.rerun_save):
        print("arc-calib: --rerun and --rerun-save need the MuJoCo scene (drop --synthetic)", file=sys.stderr)
        return 2
    try:
        if args.command == "demo":
            from arc_env.cli.demo import run_demo, run_synthetic

            return run_synthetic(args) if args.synthetic else run_demo(args)
        if args.command == "record":
            from arc_env.cli.record import run_record

            return run_record(args)
        if args.command == "run":
            from arc_env.cli.run import run_online

            return run_online(args)
        if args.command == "export":
            from arc_env.cli.export import run_export

            return run_export(args)
        if args.command == "verify":
            from arc_env.cli.verify import run_verify

            return run_verify(args)
        if args.command == "plan":
            from arc_env.cli.plan import run_plan

            return run_plan(args)
        from arc_env.cli.calibrate import run_calibrate

        return run_calibrate(args)
    except InvalidInputError as exc:
        print(f"arc-calib {args.command}: {exc}", file=sys.stderr)
        return 2 if args.command in ("calibrate", "record", "run", "export", "plan", "verify") else 1
    except ArcCalibError as exc:
        print(f"arc-calib {args.command}: {exc}", file=sys.stderr)
        return 2 if args.command == "verify" else 1  # verify's 1 means "inconsistent"
    except OSError as exc:
        print(f"arc-calib {args.command}: {exc}", file=sys.stderr)
        return 2 if args.command == "verify" else 1
    except KeyboardInterrupt:  # outputs are committed only at the end, all or nothing: none was written
        print(f"arc-calib {args.command}: interrupted; no result written", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
