"""Benchmark the solver on synthetic Franka Panda motions: accuracy per stage, timing, coverage.

10 camera poses x 5 seeds (fixed), 0.5 px Gaussian keypoint noise, 10% outlier tracks, random
exploratory motions; the calibrator updates after every motion, as in an episode. Prints a table
and, with --json PATH, writes:
{"stages": {"linear": {"3": {"rot_median_rad", "trans_median_m"}, "5", "10", "25"}, "refined": {...}},
 "update_seconds_median": {"linear", "refined"}, "coverage_95"}
A run without an estimate at a checkpoint counts as an infinite error in the medians.
Timing is on one core (BLAS threads pinned to 1 before numpy loads).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from scipy.stats import chi2  # noqa: E402

from solver import (  # noqa: E402
    PANDA,
    Calibrator,
    SyntheticConfig,
    SyntheticScene,
    d415_intrinsics,
    pose_difference,
    pose_errors,
    sample_camera_pose,
)

CHECKPOINTS = (3, 5, 10, 25)
PAPER_25 = (0.0042, 0.0065)  # rad, m: the paper's simulation result at 25 motions


def run_episode(pose: int, seed: int, n_motions: int) -> dict:
    """One calibration episode; errors at each checkpoint, update timings, Mahalanobis distances."""
    T_true = sample_camera_pose(np.random.default_rng(1000 + pose))
    rng = np.random.default_rng(100 * pose + seed)
    intrinsics = d415_intrinsics()
    scene = SyntheticScene(PANDA, intrinsics, T_true, SyntheticConfig(noise_px=0.5, outlier_fraction=0.1), rng)
    calibrator = Calibrator(intrinsics, PANDA.axis_and_point)
    out: dict = {"linear": {}, "refined": {}, "maha2": {}, "seconds": None}
    for i in range(1, n_motions + 1):
        calibrator.add_motion(scene.random_motion(rng).observation)
        state = calibrator.state
        if i not in CHECKPOINTS:
            continue
        out["linear"][i] = pose_errors(state.T_linear, T_true) if state.T_linear is not None else (np.inf, np.inf)
        if state.stage == "refined":
            out["refined"][i] = pose_errors(state.T_camera_base, T_true)
            xi = pose_difference(state.T_camera_base, T_true)
            out["maha2"][i] = float(xi @ np.linalg.solve(state.covariance, xi))
        else:
            out["refined"][i] = (np.inf, np.inf)
        if i == n_motions:
            out["seconds"] = state.seconds
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses", type=int, default=10, help="camera poses (default 10)")
    parser.add_argument("--seeds", type=int, default=5, help="seeds per pose (default 5)")
    parser.add_argument("--motions", type=int, default=25, help="motions per episode (default 25)")
    parser.add_argument("--json", type=Path, help="write the figures to this file")
    args = parser.parse_args()
    checkpoints = [c for c in CHECKPOINTS if c <= args.motions]
    runs = []
    t0 = time.perf_counter()
    for pose in range(args.poses):
        for seed in range(args.seeds):
            runs.append(run_episode(pose, seed, args.motions))
            print(f"  pose {pose} seed {seed}: refined@{args.motions} rot "
                  f"{runs[-1]['refined'][checkpoints[-1]][0]:.2e} rad, trans "
                  f"{runs[-1]['refined'][checkpoints[-1]][1] * 1e3:.3f} mm", flush=True)
    stages: dict = {}
    for stage in ("linear", "refined"):
        stages[stage] = {}
        for c in checkpoints:
            errs = np.array([r[stage][c] for r in runs])
            stages[stage][str(c)] = {"rot_median_rad": float(np.median(errs[:, 0])),
                                     "trans_median_m": float(np.median(errs[:, 1]))}
    secs = [r["seconds"] for r in runs if r["seconds"]]
    update = {k: float(np.median([s[k] for s in secs])) for k in ("linear", "refined")}
    maha = [m for r in runs for m in r["maha2"].values()]
    coverage = float(np.mean(np.array(maha) <= chi2.ppf(0.95, 6))) if maha else float("nan")
    print(f"\n{len(runs)} episodes ({args.poses} poses x {args.seeds} seeds), 0.5 px noise, 10% outlier "
          f"tracks, {time.perf_counter() - t0:.0f} s")
    print(f"{'motions':>8} | {'linear rot (rad)':>16} {'linear trans (m)':>16} | "
          f"{'refined rot (rad)':>17} {'refined trans (m)':>17}")
    for c in checkpoints:
        lin, ref = stages["linear"][str(c)], stages["refined"][str(c)]
        print(f"{c:>8} | {lin['rot_median_rad']:>16.2e} {lin['trans_median_m']:>16.2e} | "
              f"{ref['rot_median_rad']:>17.2e} {ref['trans_median_m']:>17.2e}")
    print(f"paper at 25 motions: {PAPER_25[0]} rad, {PAPER_25[1]} m")
    print(f"update at {args.motions} motions, median s: linear {update['linear']:.3f}, "
          f"refined {update['refined']:.3f}, total {update['linear'] + update['refined']:.3f}")
    print(f"coverage of the 95% region ({len(maha)} refined estimates at the checkpoints): {coverage:.3f}")
    if args.json:
        result = {"stages": stages, "update_seconds_median": update, "coverage_95": coverage}
        tmp = args.json.with_suffix(args.json.suffix + ".tmp")
        tmp.write_text(json.dumps(result, indent=2))
        tmp.replace(args.json)


if __name__ == "__main__":
    main()
