"""Can the random planner's first motions fix the pose? The ceiling of "a pose by motion 5" under random selection.

For every benchmark run (robot, camera pose, seed; the episodes of ``scripts/bench_episode.py``) draws the random
planner's first ``--motions`` motions exactly as the episode does before its first estimate, without executing
them (``arc_env.bench.first_motions``), and asks whether their joint axes fix T_camera_base at the true pose. Prints
per run the joints (1-based) and per robot the runs whose first motions fix it: no front end can give a pose by
that motion on the others. With --json PATH, writes {"runs": [{robot, pose, seed, joints (0-based),
observability}], "robots": {robot: {"runs", "fix_pose", "joint_draws"}}}.

Example (about 20 s per run: one scene and the planner's thumbnail renders):
    python scripts/bench_first_motions.py --robots panda,iiwa,xarm6 --poses 10 --seeds 3
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
from collections import Counter  # noqa: E402
from pathlib import Path  # noqa: E402

from arc_env.bench.episodes import EpisodeSpec  # noqa: E402
from arc_env.bench.first_motions import draw_first_motions  # noqa: E402
from arc_env.robot.library import parse_robot_names  # noqa: E402
from arc_env.sim.imaging import REALISMS  # noqa: E402
from solver.errors import InvalidInputError  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", default="panda", help="comma-separated robots of the library")
    parser.add_argument("--poses", type=int, default=10, help="camera poses (default 10)")
    parser.add_argument("--seeds", type=int, default=3, help="seeds per pose (default 3)")
    parser.add_argument("--motions", type=int, default=5, help="first motions to draw (default 5)")
    parser.add_argument("--size", default="1280x720", help="WxH of the renders the planner's image test uses")
    parser.add_argument("--realism", default="realistic", choices=REALISMS)
    parser.add_argument("--json", type=Path, help="write the draws and the counts to this file")
    args = parser.parse_args()
    if args.motions < 1 or args.poses < 1 or args.seeds < 1:
        parser.error("--motions, --poses and --seeds must be >= 1")
    try:
        names = parse_robot_names(args.robots)
        width, height = (int(v) for v in args.size.lower().split("x"))
    except (InvalidInputError, ValueError) as exc:
        parser.error(f"--robots / --size: {exc}")
    runs: list[dict] = []
    robots: dict[str, dict] = {}
    for robot in names:
        draws: Counter[int] = Counter()
        fixed = 0
        n_runs = 0
        for seed in range(args.seeds):
            for pose in range(args.poses):
                spec = EpisodeSpec("random", pose, seed, motions=args.motions, width=width, height=height,
                                   realism=args.realism, robot=robot)
                first = draw_first_motions(spec, args.motions)
                fixes = first.fixes_pose_by(args.motions)
                fixed += fixes
                n_runs += 1
                draws.update(first.joints)
                runs.append({"robot": robot, "pose": pose, "seed": seed, "joints": list(first.joints),
                             "observability": list(first.observability)})
                print(f"{robot:7s} pose {pose} seed {seed}  joints {''.join(str(j + 1) for j in first.joints)}  "
                      f"observability {first.observability[-1]:.1e}  {'fixes the pose' if fixes else 'POSE FREE'}",
                      flush=True)
        robots[robot] = {"runs": n_runs, "fix_pose": fixed,
                         "joint_draws": {str(j + 1): draws[j] for j in sorted(draws)}}
        print(f"{robot}: the first {args.motions} motions fix the pose on {fixed} of {n_runs} runs "
              f"({fixed / n_runs:.0%}); joints drawn (1-based): {robots[robot]['joint_draws']}", flush=True)
    if args.json:
        spec = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()}
        args.json.write_text(json.dumps({"spec": spec, "runs": runs, "robots": robots}, indent=1))


if __name__ == "__main__":
    main()
