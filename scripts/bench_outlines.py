"""The camera pose from the robot's outlines on rendered benchmark episodes, against the tracks' estimate.

For each robot, camera pose and seed: renders the episode's first motions (random planner, the episode's tracker and
calibrator), then fits the pose to the robot's occluding contours in a few frames of each sweep
(``solver.outlines.fit_outline_pose``) from the calibrator's estimate after the last motion, the model's contours
rendered from the robot as shipped (``arc_env.bench.outlines``). Prints per run both errors against the truth, the
outline fit's error along the optical axis, its pairs and times, then the medians; ``--json PATH`` writes
{"runs": [...], "median": {...}}.

Example (a few minutes a run at 1080p with camera effects):
    MUJOCO_GL=egl python scripts/bench_outlines.py --realism realistic --robots panda,iiwa --poses 0,2
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from arc_env.bench.episodes import EpisodeSpec  # noqa: E402
from arc_env.bench.outlines import OutlineRun, run_outline_episode, run_record  # noqa: E402
from arc_env.robot.library import parse_robot_names  # noqa: E402
from arc_env.sim.imaging import APPEARANCES, REALISMS  # noqa: E402
from solver.outlines import OutlineConfig  # noqa: E402


def _pair(error: tuple[float, float] | None) -> str:
    return "-" if error is None else f"{error[0]:.2e} / {error[1] * 1e3:6.2f}mm"


def medians(runs: list[OutlineRun]) -> dict[str, float | int | None]:
    """Median errors over the runs that have them: rad, m."""
    def median(values: list[float]) -> float | None:
        return float(np.median(values)) if values else None

    fitted = [r for r in runs if r.outline_error is not None]
    started = [r for r in runs if r.start_error is not None]
    return {"runs": len(runs), "fitted": len(fitted),
            "start_rot_rad": median([r.start_error[0] for r in started]),  # type: ignore[index]
            "start_trans_m": median([r.start_error[1] for r in started]),  # type: ignore[index]
            "outline_rot_rad": median([r.outline_error[0] for r in fitted]),  # type: ignore[index]
            "outline_trans_m": median([r.outline_error[1] for r in fitted]),  # type: ignore[index]
            "outline_depth_m": median([r.outline_depth_error_m for r in fitted]),  # type: ignore[misc]
            "seconds_fit": median([r.seconds_fit for r in fitted])}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--realism", choices=REALISMS, default="realistic")
    parser.add_argument("--appearance", choices=APPEARANCES, default=None,
                        help="the robot's look in the images (default: the realism's)")
    parser.add_argument("--robots", default="panda", help="comma-separated robots of the library")
    parser.add_argument("--size", default="1920x1080", help="image size WxH")
    parser.add_argument("--poses", default="0", help="comma-separated benchmark camera poses")
    parser.add_argument("--seeds", type=int, default=1, help="seeds 0..N-1 per pose")
    parser.add_argument("--motions", type=int, default=8, help="motions rendered before the fit (default 8)")
    parser.add_argument("--frames-per-motion", type=int, default=3, help="frames of each sweep the fit uses")
    parser.add_argument("--stride", type=int, default=3, help="keep every N-th contour point")
    parser.add_argument("--json", type=Path, help="write the runs and medians to this file")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.lower().split("x"))
    robots = parse_robot_names(args.robots)
    poses = [int(p) for p in args.poses.split(",")]
    runs: list[OutlineRun] = []
    print(f"{'robot':<7} {'pose':>4} {'seed':>4} {'tracks (start)':>24} {'outlines':>24} {'depth':>8} "
          f"{'pairs':>6} {'px':>5} {'fit s':>6} {'episode s':>9}")
    for robot in robots:
        for pose in poses:
            for seed in range(args.seeds):
                spec = EpisodeSpec("random", pose, seed, args.motions, width, height, False, args.realism,
                                   args.appearance, robot)
                run = run_outline_episode(spec, args.frames_per_motion, args.stride, OutlineConfig())
                runs.append(run)
                depth = "-" if run.outline_depth_error_m is None else f"{run.outline_depth_error_m * 1e3:+.2f}mm"
                px = "-" if run.median_abs_px is None else f"{run.median_abs_px:.2f}"
                print(f"{robot:<7} {pose:>4} {seed:>4} {_pair(run.start_error):>24} {_pair(run.outline_error):>24} "
                      f"{depth:>8} {run.n_pairs:>6} {px:>5} {run.seconds_fit:>6.1f} {run.seconds_episode:>9.1f}"
                      + (f"  ({run.note})" if run.note else ""), flush=True)
    summary = medians(runs)
    show = {k: (f"{v:.3g}" if isinstance(v, float) else v) for k, v in summary.items()}
    print("medians:", show)
    if args.json:
        args.json.write_text(json.dumps({"args": {k: str(v) for k, v in vars(args).items()},
                                         "runs": [run_record(r) for r in runs], "median": summary}, indent=2))


if __name__ == "__main__":
    main()
