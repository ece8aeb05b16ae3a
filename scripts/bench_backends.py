"""Benchmark the bundle adjustment's backends on one batch refine: scipy's TRF, ours (Schur LM), Ceres.

``refine`` with ``RefinementConfig.backend`` "scipy" and "schur" (``solver.schur``), and ``refine_ceres``.

Synthetic Franka Panda episodes built as in scripts/bench_solver.py (camera pose i from seed 1000 + i,
episode rng 100 i + seed, d415 intrinsics, 0.5 px noise, random exploratory motions), with up to
``--tracks`` (default 200) tracks x 30 frames per motion and a fraction of outlier tracks (drift or
jump, ``SyntheticScene``; default 10% and 30%). At each checkpoint (5, 10, 25 motions) every backend
runs one batch refine of all motions so far from the same start: the linear pose of the paper's
method (``Calibrator`` without refinement) on the same motions. Two loads: "capped" (the
library's 60 tracks per motion, chosen at random once per motion, x 30 frames) and "all" (every
track). Per load, outlier fraction and backend: median seconds of the refine, median rotation and
translation errors, coverage of the 95% region (Mahalanobis distance of the truth under the
reported covariance against chi2(6)), and failures (no estimate: infinite error in the medians);
and how far apart the backends' estimates are, in the scipy estimate's sigmas.
Timing is on one core (BLAS threads pinned to 1 before numpy loads; Ceres num_threads = 1).
With --json PATH writes {"settings", "tracks_per_motion_mean", "observations_median": {fraction: {load: {count}}},
"results": {load: {fraction: {backend: {"seconds_median", "rot_median_rad", "trans_median_m": {count},
"coverage_95", "failures"}}}}, "agreement_sigma_median": {load: {fraction: {count}}}}.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from scipy.stats import chi2  # noqa: E402

from solver import (  # noqa: E402
    PANDA,
    ArcCalibError,
    Calibrator,
    CalibratorConfig,
    RefinementResult,
    SyntheticConfig,
    SyntheticScene,
    d415_intrinsics,
    pose_difference,
    pose_errors,
    sample_camera_pose,
)
from solver.camera import normalized_from_pixels  # noqa: E402
from solver.refinement import RefinementConfig, TrackSet, build_track_set, refine  # noqa: E402
from solver.refinement_ceres import refine_ceres  # noqa: E402

CHECKPOINTS = (5, 10, 25)
CAP_TRACKS = 60  # CalibratorConfig.max_tracks_per_motion
LOADS = ("capped", "all")
BACKENDS: dict[str, Callable[..., RefinementResult]] = {
    "scipy": lambda tracks, start: refine(tracks, start, RefinementConfig(backend="scipy")),
    "schur": lambda tracks, start: refine(tracks, start, RefinementConfig(backend="schur")),
    "ceres": refine_ceres,
}
CHI2_95 = float(chi2.ppf(0.95, 6))


def _motion_tuple(motion, intrinsics, pick) -> tuple:
    axis, point = PANDA.axis_and_point(motion.observation.q_start, motion.observation.joint)
    tracks = motion.observation.tracks
    return axis, point, [(normalized_from_pixels(tracks[k].pixels, intrinsics), tracks[k].delta) for k in pick]


def run_episode(pose: int, seed: int, outlier_fraction: float, n_motions: int, n_tracks: int,
                backends: tuple[str, ...]) -> dict:
    """One episode: at each checkpoint, every backend's batch refine on both loads from the linear pose."""
    T_true = sample_camera_pose(np.random.default_rng(1000 + pose))
    rng = np.random.default_rng(100 * pose + seed)
    intrinsics = d415_intrinsics()
    config = SyntheticConfig(noise_px=0.5, outlier_fraction=outlier_fraction, tracks_per_motion=n_tracks,
                             frames_per_motion=30)
    scene = SyntheticScene(PANDA, intrinsics, T_true, config, rng)
    calibrator = Calibrator(intrinsics, PANDA.axis_and_point, CalibratorConfig(refine=False))
    cap_rng = np.random.default_rng([pose, seed])
    motions: dict[str, list] = {load: [] for load in LOADS}
    out: dict = {"n_tracks": [], "by_count": {}}
    for i in range(1, n_motions + 1):
        motion = scene.random_motion(rng)
        calibrator.add_motion(motion.observation, update=i in CHECKPOINTS)
        n = len(motion.observation.tracks)
        out["n_tracks"].append(n)
        capped = np.sort(cap_rng.choice(n, CAP_TRACKS, replace=False)) if n > CAP_TRACKS else np.arange(n)
        motions["capped"].append(_motion_tuple(motion, intrinsics, capped))
        motions["all"].append(_motion_tuple(motion, intrinsics, np.arange(n)))
        if i not in CHECKPOINTS:
            continue
        start = calibrator.state.T_linear
        row: dict = {}
        for load in LOADS:
            tracks: TrackSet = build_track_set(motions[load], intrinsics.focal)
            row[load] = {"observations": int(tracks.uv.shape[0])}
            for name in backends:
                row[load][name] = _run_backend(BACKENDS[name], tracks, start, T_true)
        out["by_count"][i] = row
    return out


def _run_backend(fn: Callable[..., RefinementResult], tracks: TrackSet, start, T_true) -> dict:
    if start is None:
        return {"seconds": None, "errors": (np.inf, np.inf), "maha2": None, "T": None, "cov": None}
    t0 = time.perf_counter()
    try:
        res = fn(tracks, start)
    except (ArcCalibError, np.linalg.LinAlgError):
        return {"seconds": time.perf_counter() - t0, "errors": (np.inf, np.inf), "maha2": None, "T": None,
                "cov": None}
    seconds = time.perf_counter() - t0
    xi = pose_difference(res.T_camera_base, T_true)
    return {"seconds": seconds, "errors": pose_errors(res.T_camera_base, T_true),
            "maha2": float(xi @ np.linalg.solve(res.covariance, xi)), "T": res.T_camera_base, "cov": res.covariance}


def summarize(runs: list[dict], backends: tuple[str, ...], checkpoints: list[int]) -> tuple[dict, dict, dict]:
    """Per load and backend: medians per count, coverage, failures; and the backends' agreement."""
    results: dict = {}
    agreement: dict = {}
    observations: dict = {}
    for load in LOADS:
        results[load] = {}
        observations[load] = {str(c): float(np.median([r["by_count"][c][load]["observations"] for r in runs]))
                              for c in checkpoints}
        for name in backends:
            cells = {c: [r["by_count"][c][load][name] for r in runs] for c in checkpoints}
            maha = [x["maha2"] for c in checkpoints for x in cells[c] if x["maha2"] is not None]
            results[load][name] = {
                "seconds_median": {str(c): float(np.median([x["seconds"] for x in cells[c] if x["seconds"] is not None]
                                                           or [np.nan])) for c in checkpoints},
                "rot_median_rad": {str(c): float(np.median([x["errors"][0] for x in cells[c]])) for c in checkpoints},
                "trans_median_m": {str(c): float(np.median([x["errors"][1] for x in cells[c]])) for c in checkpoints},
                "coverage_95": float(np.mean(np.array(maha) <= CHI2_95)) if maha else float("nan"),
                "failures": int(sum(x["maha2"] is None for c in checkpoints for x in cells[c])),
            }
        if {"scipy", "ceres"} <= set(backends):
            agreement[load] = {}
            for c in checkpoints:
                d = []
                for r in runs:
                    a, b = r["by_count"][c][load]["scipy"], r["by_count"][c][load]["ceres"]
                    if a["T"] is not None and b["T"] is not None:
                        xi = pose_difference(b["T"], a["T"])
                        d.append(float(np.sqrt(xi @ np.linalg.solve(a["cov"], xi))))
                agreement[load][str(c)] = float(np.median(d)) if d else float("nan")
    return results, agreement, observations


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses", type=int, default=10, help="camera poses (default 10)")
    parser.add_argument("--seeds", type=int, default=5, help="seeds per pose (default 5)")
    parser.add_argument("--motions", type=int, default=25, help="motions per episode (default 25)")
    parser.add_argument("--tracks", type=int, default=200, help="tracks per motion at most (default 200)")
    parser.add_argument("--outliers", type=str, default="0.1,0.3", help="outlier-track fractions (default 0.1,0.3)")
    parser.add_argument("--backends", type=str, default="scipy,schur,ceres",
                        help="of scipy, schur (solver.schur, the default), ceres (default all three)")
    parser.add_argument("--json", type=Path, help="write the figures to this file")
    args = parser.parse_args()
    backends = tuple(b.strip() for b in args.backends.split(","))
    unknown = [b for b in backends if b not in BACKENDS]
    if unknown:
        parser.error(f"unknown backend(s) {unknown}: choose from {sorted(BACKENDS)}")
    fractions = [float(f) for f in args.outliers.split(",")]
    checkpoints = [c for c in CHECKPOINTS if c <= args.motions]
    t0 = time.perf_counter()
    all_results: dict = {load: {} for load in LOADS}
    all_agreement: dict = {load: {} for load in LOADS}
    observations: dict = {}
    n_tracks: list[int] = []
    for fraction in fractions:
        runs = []
        for pose in range(args.poses):
            for seed in range(args.seeds):
                runs.append(run_episode(pose, seed, fraction, args.motions, args.tracks, backends))
                n_tracks += runs[-1]["n_tracks"]
                last = runs[-1]["by_count"][checkpoints[-1]]["all"]
                print(f"  outliers {fraction:.0%} pose {pose} seed {seed}: all tracks @{checkpoints[-1]}: "
                      + ", ".join(f"{b} {last[b]['seconds'] or float('nan'):.2f} s {last[b]['errors'][0]:.1e} rad "
                                  f"{last[b]['errors'][1] * 1e3:.2f} mm" for b in backends), flush=True)
        results, agreement, obs = summarize(runs, backends, checkpoints)
        observations[str(fraction)] = obs
        for load in LOADS:
            all_results[load][str(fraction)] = results[load]
            all_agreement[load][str(fraction)] = agreement.get(load, {})
    print(f"\n{args.poses} poses x {args.seeds} seeds, 0.5 px noise, outlier fractions {fractions}, "
          f"{np.mean(n_tracks):.0f} tracks per motion on average (at most {args.tracks}), "
          f"{time.perf_counter() - t0:.0f} s")
    for load in LOADS:
        obs = observations[str(fractions[0])][load]
        print(f"\n{load} ({'at most 60 tracks' if load == 'capped' else 'every track'} x 30 frames per motion; "
              f"median observations at {fractions[0]:.0%} outliers "
              + ", ".join(f"{obs[str(c)]:.0f} @{c}" for c in checkpoints) + ")")
        head = " ".join(f"{'s@' + str(c):>7}" for c in checkpoints)
        rot = " ".join(f"{'rot@' + str(c):>8}" for c in checkpoints)
        tr = " ".join(f"{'mm@' + str(c):>7}" for c in checkpoints)
        print(f"{'outliers':>8} {'backend':>7} | {head} | {rot} (mrad) | {tr} | {'cov95':>5} {'fail':>4}")
        for fraction in fractions:
            for name in backends:
                r = all_results[load][str(fraction)][name]
                print(f"{fraction:>8.0%} {name:>7} | "
                      + " ".join(f"{r['seconds_median'][str(c)]:>7.3f}" for c in checkpoints) + " | "
                      + " ".join(f"{r['rot_median_rad'][str(c)] * 1e3:>8.3f}" for c in checkpoints) + "        | "
                      + " ".join(f"{r['trans_median_m'][str(c)] * 1e3:>7.3f}" for c in checkpoints)
                      + f" | {r['coverage_95']:>5.3f} {r['failures']:>4}")
            ag = all_agreement[load][str(fraction)]
            if ag:
                print(f"{fraction:>8.0%} {'|c-s|':>7} | median distance of ceres from scipy in scipy's sigmas: "
                      + ", ".join(f"{ag[str(c)]:.3f} @{c}" for c in checkpoints))
    if args.json:
        result = {"settings": {"poses": args.poses, "seeds": args.seeds, "motions": args.motions,
                               "tracks": args.tracks, "outlier_fractions": fractions, "backends": list(backends)},
                  "tracks_per_motion_mean": float(np.mean(n_tracks)), "observations_median": observations,
                  "results": all_results, "agreement_sigma_median": all_agreement}
        tmp = args.json.with_suffix(args.json.suffix + ".tmp")
        tmp.write_text(json.dumps(result, indent=2))
        tmp.replace(args.json)


if __name__ == "__main__":
    main()
