"""Benchmark the solver on synthetic Franka Panda motions: accuracy per stage, timing, coverage.

10 camera poses x 5 seeds (fixed), 0.5 px Gaussian keypoint noise, 10% outlier tracks, random
exploratory motions; the calibrator updates after every motion, as in an episode. Prints a table
and, with --json PATH, writes:
{"stages": {"linear": {"3": {"rot_median_rad", "trans_median_m"}, "5", "10", "25"}, "refined": {...}},
 "update_seconds_median": {"linear", "refined"}, "coverage_95"}
With --all-tracks the same episodes run again at the tracker's load (200 tracks x 30 frames per
motion, every one given to the solver) and the JSON gains
"all_tracks": {"update_seconds_median": {"5", "10", "25"}, "episode_solver_seconds_median",
 "incremental_vs_batch_max_sigma", "relinearizations_median", "coverage_95",
 "stages": {"refined": {"3": {"rot_median_rad", "trans_median_m"}, ...}}}:
the update's wall time (linear + refined) at those motions, the solver's total per episode, and at
every checkpoint the largest difference, in 1-sigma units per pose component, between the
calibrator's (incremental) estimate and a batch bundle adjustment of every motion started from it.
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
from dataclasses import replace  # noqa: E402
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


#: The tracker-sized load of --all-tracks: tracks per motion (and keypoints per link to draw them from), frames.
ALL_TRACKS = (200, 30)


def run_episode(pose: int, seed: int, n_motions: int, all_tracks: bool = False) -> dict:
    """One calibration episode; errors at each checkpoint, update timings, Mahalanobis distances.

    With ``all_tracks`` at the tracker's load (``ALL_TRACKS``), also each update's seconds and, at the
    checkpoints, the incremental estimate's largest difference from a batch adjustment (in 1-sigma units).
    """
    T_true = sample_camera_pose(np.random.default_rng(1000 + pose))
    rng = np.random.default_rng(100 * pose + seed)
    intrinsics = d415_intrinsics()
    config = SyntheticConfig(noise_px=0.5, outlier_fraction=0.1)
    if all_tracks:
        config = replace(config, keypoints_per_link=ALL_TRACKS[0], tracks_per_motion=ALL_TRACKS[0],
                         frames_per_motion=ALL_TRACKS[1])
    scene = SyntheticScene(PANDA, intrinsics, T_true, config, rng)
    calibrator = Calibrator(intrinsics, PANDA.axis_and_point)
    out: dict = {"linear": {}, "refined": {}, "maha2": {}, "seconds": None, "update": {}, "solver": 0.0,
                 "agreement": [], "relinearized": 0}
    for i in range(1, n_motions + 1):
        calibrator.add_motion(scene.random_motion(rng).observation)
        state = calibrator.state
        out["update"][i] = state.seconds["linear"] + state.seconds["refined"]
        out["solver"] += out["update"][i]
        if i not in CHECKPOINTS:
            continue
        if all_tracks and state.stage == "refined":
            batch = calibrator.batch_refinement()
            xi = pose_difference(batch.T_camera_base, state.T_camera_base)
            out["agreement"].append(float(np.max(np.abs(xi) / np.sqrt(np.diag(batch.covariance)))))
        out["linear"][i] = pose_errors(state.T_linear, T_true) if state.T_linear is not None else (np.inf, np.inf)
        if state.stage == "refined":
            out["refined"][i] = pose_errors(state.T_camera_base, T_true)
            xi = pose_difference(state.T_camera_base, T_true)
            out["maha2"][i] = float(xi @ np.linalg.solve(state.covariance, xi))
        else:
            out["refined"][i] = (np.inf, np.inf)
        if i == n_motions:
            out["seconds"] = state.seconds
    out["relinearized"] = calibrator.relinearized
    return out


def stage_medians(runs: list[dict], checkpoints: list[int], stage: str) -> dict:
    """{"3": {"rot_median_rad", "trans_median_m"}, ...} of one stage over the runs."""
    out = {}
    for c in checkpoints:
        errs = np.array([r[stage][c] for r in runs])
        out[str(c)] = {"rot_median_rad": float(np.median(errs[:, 0])), "trans_median_m": float(np.median(errs[:, 1]))}
    return out


def coverage_95(runs: list[dict]) -> tuple[float, int]:
    """Fraction of refined estimates at the checkpoints whose 95% region holds the truth, and their number."""
    maha = [m for r in runs for m in r["maha2"].values()]
    return (float(np.mean(np.array(maha) <= chi2.ppf(0.95, 6))) if maha else float("nan")), len(maha)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses", type=int, default=10, help="camera poses (default 10)")
    parser.add_argument("--seeds", type=int, default=5, help="seeds per pose (default 5)")
    parser.add_argument("--motions", type=int, default=25, help="motions per episode (default 25)")
    parser.add_argument("--json", type=Path, help="write the figures to this file")
    parser.add_argument("--all-tracks", action="store_true",
                        help=f"also run the episodes at the tracker's load ({ALL_TRACKS[0]} tracks x {ALL_TRACKS[1]} "
                             "frames per motion, all to the solver): update times, incremental-vs-batch agreement")
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
    stages = {stage: stage_medians(runs, checkpoints, stage) for stage in ("linear", "refined")}
    secs = [r["seconds"] for r in runs if r["seconds"]]
    update = {k: float(np.median([s[k] for s in secs])) for k in ("linear", "refined")}
    coverage, n_maha = coverage_95(runs)
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
    print(f"coverage of the 95% region ({n_maha} refined estimates at the checkpoints): {coverage:.3f}")
    result: dict = {"stages": stages, "update_seconds_median": update, "coverage_95": coverage}
    if args.all_tracks:
        result["all_tracks"] = run_all_tracks(args.poses, args.seeds, args.motions, checkpoints)
    if args.json:
        tmp = args.json.with_suffix(args.json.suffix + ".tmp")
        tmp.write_text(json.dumps(result, indent=2))
        tmp.replace(args.json)


def run_all_tracks(poses: int, seeds: int, n_motions: int, checkpoints: list[int]) -> dict:
    """The --all-tracks episodes: print their figures and return the JSON's "all_tracks" entry."""
    t0 = time.perf_counter()
    runs = []
    for pose in range(poses):
        for seed in range(seeds):
            runs.append(run_episode(pose, seed, n_motions, all_tracks=True))
            r = runs[-1]
            print(f"  all tracks, pose {pose} seed {seed}: refined@{n_motions} rot "
                  f"{r['refined'][checkpoints[-1]][0]:.2e} rad, trans {r['refined'][checkpoints[-1]][1] * 1e3:.3f} mm; "
                  f"solver {r['solver']:.2f} s, {r['relinearized']} batch updates, incremental vs batch "
                  f"{max(r['agreement'], default=float('nan')):.3f} sigma", flush=True)
    refined = stage_medians(runs, checkpoints, "refined")
    updates = {str(c): float(np.median([r["update"][c] for r in runs])) for c in (5, 10, 25) if c <= n_motions}
    agreement = [a for r in runs for a in r["agreement"]]
    coverage, n_maha = coverage_95(runs)
    out = {"update_seconds_median": updates,
           "episode_solver_seconds_median": float(np.median([r["solver"] for r in runs])),
           "incremental_vs_batch_max_sigma": max(agreement) if agreement else float("nan"),
           "relinearizations_median": float(np.median([r["relinearized"] for r in runs])),
           "coverage_95": coverage, "stages": {"refined": refined}}
    print(f"\nall tracks ({ALL_TRACKS[0]} x {ALL_TRACKS[1]} per motion), {len(runs)} episodes, "
          f"{time.perf_counter() - t0:.0f} s")
    print(f"{'motions':>8} | {'refined rot (rad)':>17} {'refined trans (m)':>17} | {'update (s, median)':>18}")
    for c in checkpoints:
        upd = f"{updates[str(c)]:.3f}" if str(c) in updates else "-"
        print(f"{c:>8} | {refined[str(c)]['rot_median_rad']:>17.2e} {refined[str(c)]['trans_median_m']:>17.2e} | "
              f"{upd:>18}")
    print(f"solver per {n_motions}-motion episode, median: {out['episode_solver_seconds_median']:.2f} s "
          f"({out['relinearizations_median']:.0f} batch updates); incremental vs batch, largest: "
          f"{out['incremental_vs_batch_max_sigma']:.3f} sigma; coverage of the 95% region ({n_maha}): {coverage:.3f}")
    return out


if __name__ == "__main__":
    main()
