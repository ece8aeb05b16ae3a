"""Capture a benchmark episode's calibrator inputs once, or replay a capture through the solver as it is now.

Capture (renders; minutes per realistic 1080p motion)::

    MUJOCO_GL=egl python scripts/replay_solver.py capture runs/as3.pkl --pose 3 --motions 6 --appearance as_shipped

Replay (the solver alone, with the robot's outlines rendered from its model; about a minute)::

    MUJOCO_GL=egl python scripts/replay_solver.py replay runs/as3.pkl

prints, per motion: the joint turned, the state's stage and start, the true error, the truth's chi-square in the
state's covariance, and why there is no pose or why the outlines were not used. Captures are pickles
(``arc_env.bench.capture``): replay only your own.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from arc_env.bench.capture import capture_episode, load_capture, replay, save_capture  # noqa: E402
from arc_env.bench.episodes import EpisodeSpec, truth_chi2  # noqa: E402
from arc_env.robot.library import ROBOT_NAMES  # noqa: E402
from arc_env.robot.session import OUTLINE_FRAMES  # noqa: E402
from arc_env.sim.imaging import APPEARANCES, REALISMS  # noqa: E402
from solver.errors import ArcCalibError  # noqa: E402
from solver.frames import pose_difference  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit code."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    cap = sub.add_parser("capture", help="run a benchmark episode and save its calibrator's inputs")
    cap.add_argument("out", type=Path)
    cap.add_argument("--robot", choices=ROBOT_NAMES, default="panda")
    cap.add_argument("--pose", type=int, default=0)
    cap.add_argument("--seed", type=int, default=0)
    cap.add_argument("--motions", type=int, default=6)
    cap.add_argument("--size", default="1920x1080", help="WxH")
    cap.add_argument("--realism", choices=REALISMS, default="realistic")
    cap.add_argument("--appearance", choices=APPEARANCES)
    cap.add_argument("--outline-frames", type=int, default=OUTLINE_FRAMES)
    rep = sub.add_parser("replay", help="feed a capture to the solver as it is now")
    rep.add_argument("capture", type=Path)
    args = parser.parse_args(argv)
    if args.command == "capture":
        width, height = (int(v) for v in args.size.lower().split("x"))
        spec = EpisodeSpec("random", args.pose, args.seed, args.motions, width, height, False, args.realism,
                           args.appearance, args.robot, args.outline_frames)
        capture = capture_episode(spec)
        save_capture(capture, args.out)
        print(f"wrote {args.out}: {len(capture.calls)} motions of {spec.key}")
        return 0
    try:
        capture = load_capture(args.capture)
    except ArcCalibError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"{args.capture}: {capture.spec.key}, {len(capture.calls)} motions")
    for k, ((observation, _, _), state) in enumerate(zip(capture.calls, replay(capture), strict=True)):
        line = f"{k + 1:3d} joint {observation.joint}  {state.stage:8s} {state.start or '-':9s}"
        if state.T_camera_base is not None:
            xi = pose_difference(state.T_camera_base, capture.T_true)
            line += f" {np.linalg.norm(xi[:3]):.2e} rad {np.linalg.norm(xi[3:]) * 1e3:7.2f} mm"
            chi2 = truth_chi2(state, capture.T_true)
            if chi2 is not None:
                line += f"  chi2 {chi2:6.1f}"
        why = state.message or state.outline_note
        print(line + (f"  | {why}" if why else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
