"""Benchmark whole episodes of ArcCalib-v0: rendered pixels and real tracking, and the oracle floor.

10 camera poses x 5 seeds (fixed; ``--poses N --seeds M`` run a subset), random collision-free
motions, 1920x1080. Every run is done twice: tracked (rendering + optical flow) and with
``oracle_keypoints`` (projected mesh points, 0.5 px noise), the floor that separates tracking
error from geometry error. Prints a line per run, a summary per robot, size and look, and a markdown
table of them side by side; with ``--json PATH`` it writes the figures (keys below). A run without an
estimate at a checkpoint counts as an infinite error in the medians (printed as inf, written as null).
``--quick``: 2 poses x 1 seed at 960x540, 10 motions, for a CI smoke run (at 640x360 the
speckle falls below a pixel and too few corners survive to calibrate in 10 motions).
``--realism realistic`` renders with a real camera's noise, motion blur, gain drift and H.264 video and a
realistic robot surface; ``--appearance`` picks the surface (``arc_env.sim.imaging``).
``--store DIR`` keeps every finished episode (``arc_env.bench.episodes``) and reuses it, so a long run can be
interrupted and resumed; ``--workers N`` runs N episodes at once (one renderer thread each).
``--keep-captures`` also keeps each tracked episode's calibrator inputs in the store (``arc_env.bench.capture``:
its tracks and outline frames), and ``--replay-from DIR --store NEW`` then rescores such a store with the solver
of this checkout, in seconds per episode instead of minutes (same frames and motions; records marked
``replayed_from``); with ``--stored-only`` too it replays what DIR captured and renders nothing.
``--robots panda,iiwa,xarm6`` runs the benchmark on each named robot of ``arc_env.robot.library`` in turn
(the camera poses scaled to each arm, ``arc_env.bench.poses.benchmark_view``); ``--sizes
1920x1080,1280x720`` at each image size (default: ``--width`` x ``--height``); ``--beside-clean`` runs the
same poses and seeds again with ``--realism clean`` and the painted robot (today's setting; tracked runs
only) and prints the two looks side by side. Tracked runs use the outline stage as ``calibrate`` does
(``--outline-frames``, default 3); ``--outline-frames 0`` runs the tracks alone, the setting of every record
stored before the stage was on by default (their keys have no ``_o3``).

The realism issue's (issue 19) measurement, 10 poses x 3 seeds at 1080p and 720p::

    MUJOCO_GL=egl python scripts/bench_episode.py --realism realistic --robots panda,iiwa,xarm6 \
        --seeds 3 --sizes 1920x1080,1280x720 --no-oracle --beside-clean --store DIR --json out.json

For realistic runs the summary checks that issue's targets (PASS / FAIL / n/a): a usable result on every
run at the end (25 motions); the median error at 25 motions <= 1e-3 rad and 1.5 mm from 1080 px high
images, <= 2e-3 rad and 3 mm from 720 px (n/a below 720 px or with fewer motions); an estimate after
motion 5 on >= 90 % of runs; no run that declared convergence while its true error was over 3 times its
reported 1-sigma (``arc_env.bench.episodes.falsely_converged``).

``--json`` figures of one robot, size and look (medians over the tracked runs unless named otherwise):
{"tracked": {"3": {"rot_median_rad", "trans_median_m"}, "10": ..., "25": ...}, "oracle": {...} (when run),
 "motions_to_converge_median", "seconds_per_episode_median", "seconds_split": {"render", "tracking",
 "solver", "report"}, "tracking_plus_solver_ms_per_frame", "planning_seconds_per_call_median",
 "tracks_per_motion_median", "full_tracks_per_motion_median", "axes_per_run_median", "usable_runs",
 "runs_with_track_counts", "usable_fraction",
 "axes_conics_per_run_median", "axes_rigid_per_run_median", "runs_with_front_ends",
 "pose_by_5_fraction", "false_convergence_runs", "runs_with_convergence_check",
 "coverage_95_at_end", "runs_with_coverage_at_end", "coverage_95_updates", "updates_with_coverage",
 "chi2_updates_median", "runs_with_chi2",
 "realism", "appearance", "targets" (realistic runs only): {"usable_every_run", "median_at_25",
 "median_target_25": [rad, m] or null, "pose_by_5", "no_false_convergence"} (true, false, or null: n/a)}.
``seconds_split``: median seconds per tracked episode of each part; "report" is the solver's time on the paper's
conic front end where only this benchmark's front-end count needs it (``CalibratorConfig.conics_always``; the
estimate is the same without it), left out of "solver" and of ``tracking_plus_solver_ms_per_frame``, which are then
what the default settings spend (records stored before this split have 0 and their solver time includes it).
``usable_runs`` counts the runs
whose final estimate is usable among ``runs_with_track_counts``; ``usable_fraction`` is their ratio.
``pose_by_5_fraction``: runs with an estimate after motion 5 (null with fewer motions).
``false_convergence_runs``: runs with at least one falsely converged motion. ``coverage_95_at_end``: the share of
runs whose reported 95 % region held the truth after their last motion, ``coverage_95_updates`` after every update,
``chi2_updates_median`` the median chi-square of the truth over those updates (5.35 when the covariance is
calibrated; lower: wider than the errors) (``coverage_figures``; null without a covariance).
``end_error_mean_camera``: the runs' mean final error in the camera frame, estimate - truth, and its spread
(``bias_figures``: ``runs``, ``rot_mean_rad``, ``rot_sd_rad``, ``trans_mean_m``, ``trans_sd_m``; null without an
estimate at the end); printed with its standard error, so that a bias the runs share shows. Records stored before a
figure existed are left out of it; ``runs_with_track_counts``, ``runs_with_front_ends`` and
``runs_with_convergence_check`` count the runs that have it. Without ``--robots``, ``--sizes`` and
``--beside-clean`` the document is these figures (the Panda, one size, one look); with any of them it is
nested {"robots": {"panda": {"1920x1080": {"realistic": {...figures...}, "clean": {...}}, ...}, ...}}:
per robot, per size ("WxH"), per look (the ``--realism`` name, and "clean" with ``--beside-clean``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy.stats import chi2

from arc_env.bench.capture import stored_capture
from arc_env.bench.episodes import (
    EpisodeSpec,
    EpisodeStore,
    add_study_outline_argument,
    commits_used,
    padded_curve,
    write_figures,
)
from arc_env.bench.runner import add_runner_arguments, check_runner_arguments, run_from_arguments
from arc_env.robot.library import DEFAULT_ROBOT, ROBOT_NAMES, parse_robot_names
from arc_env.robot.session import OUTLINE_FRAMES
from arc_env.sim.env import PAPER_ROTATION_RAD, PAPER_TRANSLATION_M
from solver.errors import InvalidInputError

CHECKPOINTS = (3, 10, 25)
TARGET_25 = (0.001, 0.0015)  # rad, m: issue 3's target for tracked runs at 25 motions
PAPER_25 = (PAPER_ROTATION_RAD, PAPER_TRANSLATION_M)  # rad, m: the paper's simulation result
#: Issue 19's median error targets at 25 motions for realistic runs, by the smallest image height (px)
#: they apply from: (rad, m). Smaller images have none.
REALISTIC_TARGETS_25 = ((1080, (1e-3, 1.5e-3)), (720, (2e-3, 3e-3)))
#: Issue 19: a pose (linear or refined) after this many motions on at least this fraction of runs.
POSE_BY = 5
POSE_BY_FRACTION = 0.9
#: The look --beside-clean adds: today's clean camera and painted robot.
CLEAN = ("clean", None)


def _median(values: list[float]) -> float:
    return float(np.median(values)) if values else float("nan")


def _finite_or_none(x: float) -> float | None:
    return x if np.isfinite(x) else None


def parse_sizes(text: str) -> list[tuple[int, int]]:
    """``"1920x1080,1280x720"`` -> [(1920, 1080), (1280, 720)] (width, height px; repeats dropped)."""
    sizes = []
    for part in text.split(","):
        w, sep, h = part.strip().lower().partition("x")
        if not sep or not w.isdigit() or not h.isdigit() or int(w) < 1 or int(h) < 1:
            raise InvalidInputError(f"sizes are WxH[,WxH...] such as 1920x1080,1280x720; got {part.strip()!r}")
        sizes.append((int(w), int(h)))
    return list(dict.fromkeys(sizes))


def summarize(runs: list[dict], checkpoints: list[int], n_motions: int) -> dict:
    """Median rotation and translation error per checkpoint over runs."""
    curves = [padded_curve(r, n_motions) for r in runs]
    return {str(k): {"rot_median_rad": _median([c[k - 1][0] for c in curves]),
                     "trans_median_m": _median([c[k - 1][1] for c in curves])}
            for k in checkpoints}


def tracking_figures(runs: list[dict]) -> dict:
    """Medians of tracks per motion and of tracks spanning the sweep, axes per run, usable runs.

    Records stored before these fields existed are left out (``runs_with_track_counts`` counts the rest).
    """
    counted = [r for r in runs if "tracks" in r and "usable" in r]
    usable = sum(bool(r["usable"]) for r in counted)
    return {"tracks_per_motion_median": _median([n for r in counted for n in r["tracks"]]),
            "full_tracks_per_motion_median": _median([n for r in counted for n in r["full_tracks"]]),
            "axes_per_run_median": _median([r["axes"] for r in counted]),
            "usable_runs": usable, "runs_with_track_counts": len(counted),
            "usable_fraction": usable / len(counted) if counted else None}


def front_end_figures(runs: list[dict]) -> dict:
    """Medians over runs of the motions with an axis from the conics and from the rigid front end.

    Records stored before ``axes_conics`` existed are left out (``runs_with_front_ends`` counts the rest).
    """
    counted = [r for r in runs if "axes_conics" in r and "axes_rigid" in r]
    return {"axes_conics_per_run_median": _median([r["axes_conics"] for r in counted]),
            "axes_rigid_per_run_median": _median([r["axes_rigid"] for r in counted]),
            "runs_with_front_ends": len(counted)}


def pose_by_fraction(runs: list[dict], k: int, n_motions: int) -> float | None:
    """Fraction of runs with an estimate after motion k (a run that stopped earlier keeps its last state).

    None without runs or when the episodes have fewer than k motions.
    """
    if not runs or k > n_motions:
        return None
    return sum(bool(np.isfinite(padded_curve(r, k)[k - 1][0])) for r in runs) / len(runs)


def convergence_figures(runs: list[dict]) -> dict:
    """Runs that declared convergence at least once while their true error was over 3x their 1-sigma.

    Records stored before ``false_convergence`` existed are left out (``runs_with_convergence_check``).
    """
    counted = [r for r in runs if "false_convergence" in r]
    return {"false_convergence_runs": sum(r["false_convergence"] > 0 for r in counted),
            "runs_with_convergence_check": len(counted)}


#: The 95 % quantile of chi-square with 6 degrees of freedom: an honest covariance's region holds the truth below it.
CHI2_6_95 = float(chi2.ppf(0.95, 6))
#: Its median: a calibrated covariance's updates have half their chi-squares below it; far fewer is a region wider than
#: the errors (conservative), far more a narrower one.
CHI2_6_MEDIAN = float(chi2.ppf(0.5, 6))


def coverage_figures(runs: list[dict]) -> dict:
    """How often the reported 95 % region held the truth (``arc_env.bench.episodes.truth_chi2``).

    ``coverage_95_at_end``: the fraction of runs whose last update's chi-square is below ``CHI2_6_95`` (of those
    with a covariance then); ``coverage_95_updates``: the same over every update with a covariance, pooled;
    ``chi2_updates_median``: the median of those updates' chi-squares (``CHI2_6_MEDIAN`` when calibrated);
    None when there is none. Records stored before ``chi2_curve`` existed are left out (``runs_with_chi2``).
    """
    counted = [r for r in runs if "chi2_curve" in r]
    ends = [r["chi2_curve"][-1] for r in counted if r["chi2_curve"] and r["chi2_curve"][-1] is not None]
    updates = [c for r in counted for c in r["chi2_curve"] if c is not None]
    return {"coverage_95_at_end": float(np.mean(np.array(ends) <= CHI2_6_95)) if ends else None,
            "runs_with_coverage_at_end": len(ends),
            "coverage_95_updates": float(np.mean(np.array(updates) <= CHI2_6_95)) if updates else None,
            "updates_with_coverage": len(updates),
            "chi2_updates_median": float(np.median(updates)) if updates else None, "runs_with_chi2": len(counted)}


def bias_figures(runs: list[dict]) -> dict:
    """The runs' mean final error in the camera frame (estimate - truth) and its spread: a bias the runs share.

    From each run's last ``error_curve`` entry (``solver.frames.pose_difference(estimate, truth)``, negated):
    ``end_error_mean_camera`` holds ``runs`` (those with an estimate at the end), ``rot_mean_rad`` / ``rot_sd_rad``
    (3,) and ``trans_mean_m`` / ``trans_sd_m`` (3,) about the optical frame's x right, y down, z forward (the
    translation is where the estimate puts the base's origin); None without such runs. The mean is a bias when it
    stands several of its standard errors (sd / sqrt(runs)) from zero. Records without ``error_curve`` are left out.
    """
    ends = [r["error_curve"][-1] for r in runs if r.get("error_curve") and r["error_curve"][-1] is not None]
    if not ends:
        return {"end_error_mean_camera": None}
    e = -np.asarray(ends, dtype=np.float64)
    sd = e.std(axis=0, ddof=1) if len(e) > 1 else np.full(6, np.nan)
    return {"end_error_mean_camera": {"runs": len(e), "rot_mean_rad": e[:, :3].mean(axis=0).tolist(),
                                      "rot_sd_rad": [_finite_or_none(x) for x in sd[:3]],
                                      "trans_mean_m": e[:, 3:].mean(axis=0).tolist(),
                                      "trans_sd_m": [_finite_or_none(x) for x in sd[3:]]}}


def median_target(height: int) -> tuple[float, float] | None:
    """Issue 19's median error target at 25 motions (rad, m) for realistic images ``height`` px high."""
    for min_height, target in REALISTIC_TARGETS_25:
        if height >= min_height:
            return target
    return None


def realistic_targets(figures: dict, height: int) -> dict:
    """Issue 19's targets for one robot, size and realistic look: True (met), False, or None (n/a)."""
    target = median_target(height)
    at_25 = figures["tracked"].get("25")
    median_met = None
    if target is not None and at_25 is not None:
        median_met = bool(at_25["rot_median_rad"] <= target[0] and at_25["trans_median_m"] <= target[1])
    n_usable, n_checked = figures["runs_with_track_counts"], figures["runs_with_convergence_check"]
    pose = figures["pose_by_5_fraction"]
    return {"usable_every_run": figures["usable_runs"] == n_usable if n_usable else None,
            "median_at_25": median_met, "median_target_25": None if target is None else list(target),
            "pose_by_5": None if pose is None else pose >= POSE_BY_FRACTION,
            "no_false_convergence": figures["false_convergence_runs"] == 0 if n_checked else None}


def _size_label(size: tuple[int, int]) -> str:
    return f"{size[0]}x{size[1]}"


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; returns the exit code."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses", type=int, default=10, help="camera poses (default 10)")
    parser.add_argument("--seeds", type=int, default=5, help="seeds per pose (default 5)")
    parser.add_argument("--motions", type=int, default=25, help="motions per episode (default 25)")
    parser.add_argument("--width", type=int, default=1920)
    parser.add_argument("--height", type=int, default=1080)
    parser.add_argument("--sizes", help="comma-separated image sizes WxH run in turn, e.g. 1920x1080,1280x720 "
                        "(default: --width x --height)")
    parser.add_argument("--no-oracle", action="store_true", help="skip the oracle runs")
    parser.add_argument("--quick", action="store_true", help="2 poses x 1 seed, 960x540, 10 motions (CI smoke)")
    parser.add_argument("--robots", help=f"comma-separated robots of the library, run in turn "
                        f"({', '.join(ROBOT_NAMES)}; default: the Panda alone)")
    parser.add_argument("--beside-clean", action="store_true",
                        help="also run the same poses and seeds clean with the painted robot (tracked only) and "
                        "print both side by side")
    add_study_outline_argument(parser, OUTLINE_FRAMES)
    parser.add_argument("--stored-only", action="store_true",
                        help="run nothing: the figures of the episodes already in --store (a partial table while "
                             "a run goes on; a cell without stored runs is left out); with --replay-from, the "
                             "episodes captured there and not yet in --store are replayed first (no rendering)")
    parser.add_argument("--json", type=Path, help="write the figures to this file")
    add_runner_arguments(parser)
    args = parser.parse_args(argv)
    check_runner_arguments(parser, args)
    if args.quick:
        args.poses, args.seeds, args.motions, args.width, args.height = 2, 1, 10, 960, 540
    try:
        robots = parse_robot_names(args.robots) if args.robots is not None else (DEFAULT_ROBOT,)
        sizes = parse_sizes(args.sizes) if args.sizes is not None else [(args.width, args.height)]
    except InvalidInputError as exc:
        parser.error(str(exc))
    if args.stored_only and args.store is None:
        parser.error("--stored-only reads the episodes of --store DIR")
    if args.beside_clean and args.realism == "clean":
        parser.error("--beside-clean adds clean painted runs beside --realism realistic; --realism is already clean")
    nested = args.robots is not None or args.sizes is not None or args.beside_clean
    checkpoints = [k for k in CHECKPOINTS if k <= args.motions]
    looks = [(args.realism, args.appearance)] + ([CLEAN] if args.beside_clean else [])
    modes = {look: ["tracked"] + ([] if args.no_oracle or i > 0 else ["oracle"]) for i, look in enumerate(looks)}
    specs = {(robot, size, look, mode, pose, seed): EpisodeSpec(
                 "random", pose, seed, args.motions, size[0], size[1], realism=look[0], appearance=look[1],
                 oracle=mode == "oracle", robot=robot, outline_frames=args.outline_frames if mode == "tracked" else 0,
                 background=args.background if look == looks[0] else "floor")  # the clean look beside: today's
             for robot in robots for size in sizes for look in looks
             for pose in range(args.poses) for seed in range(args.seeds) for mode in modes[look]}
    print(f"{args.poses} poses x {args.seeds} seeds, {args.motions} motions, "
          f"{', '.join(_size_label(z) for z in sizes)}, {' and '.join(look[0] for look in looks)}"
          + (f", robots {', '.join(robots)}" if args.robots is not None else ""))
    print(("robot    size      look      " if nested else "")
          + f"{'mode':>8} {'pose':>4} {'seed':>4} " + " ".join(f"{'@' + str(k):>19}" for k in checkpoints)
          + f" {'conv':>5} {'sec':>6} {'render':>7} {'track':>6} {'solve':>6}  commit")

    def show(r: dict, from_store: bool) -> None:
        curve = padded_curve(r, args.motions)
        errs = " ".join(f"{curve[k - 1][0]:>9.2e} {curve[k - 1][1] * 1e3:>6.2f}mm" for k in checkpoints)
        spec, sec = r["spec"], r["seconds"]
        where = (f"{spec.get('robot', DEFAULT_ROBOT):<8} {_size_label((spec['width'], spec['height'])):<9} "
                 f"{spec.get('realism', 'clean'):<9} " if nested else "")
        print(f"{where}{'oracle' if spec['oracle'] else 'tracked':>8} {spec['pose']:>4} {spec['seed']:>4} {errs} "
              f"{str(r['converged_at'] or '-'):>5} {sec['total']:>6.1f} {sec['render']:>7.1f} {sec['tracking']:>6.1f} "
              f"{sec['solver']:>6.1f}  {r['commit']}{' (stored)' * from_store}{'  ' + r['note'] if r['note'] else ''}",
              flush=True)

    if args.stored_only:
        store = EpisodeStore(args.store)
        replayed = set()
        if args.replay_from is not None:  # render nothing: replay what the source captured and --store lacks
            source = EpisodeStore(args.replay_from)
            todo = [spec for spec in specs.values()
                    if store.get(spec) is None and stored_capture(source, spec) is not None]
            replayed = set(run_from_arguments(todo, args, show)) if todo else set()
        records = {spec: record for spec in specs.values() if (record := store.get(spec)) is not None}
        for spec, record in records.items():
            if spec not in replayed:
                show(record, True)
        now = f" ({len(replayed)} replayed now)" if replayed else ""
        print(f"{len(records)} of {len(specs)} episodes stored{now}")
    else:
        records = run_from_arguments(specs.values(), args, show)
    print()
    print(f"code: {commits_used(records.values())}")
    figures: dict[str, dict[str, dict[str, dict]]] = {}
    for robot in robots:
        for size in sizes:
            cell = {look: {mode: [records[key] for p in range(args.poses) for s in range(args.seeds)
                                  if (key := specs[robot, size, look, mode, p, s]) in records]
                           for mode in modes[look]} for look in looks}
            if not all(results["tracked"] for results in cell.values()):  # --stored-only: a cell not run yet
                print(f"-- {robot} {_size_label(size)}: not every look has stored runs; left out")
                continue
            for look, by_mode in cell.items():
                results = {mode: runs for mode, runs in by_mode.items() if runs}  # --stored-only: no oracle runs yet
                if nested:
                    print(f"-- {robot} {_size_label(size)} {look[0]}")
                group = robot_figures(results, checkpoints, args.motions, look, size)
                figures.setdefault(robot, {}).setdefault(_size_label(size), {})[look[0]] = group
    print()
    print(side_by_side_table(figures, [look[0] for look in looks]))
    if args.json:
        if nested:
            write_figures(args.json, {"robots": figures})
        else:
            write_figures(args.json, figures[DEFAULT_ROBOT][_size_label(sizes[0])][args.realism])
    return 0


def robot_figures(results: dict[str, list[dict]], checkpoints: list[int], n_motions: int,
                  look: tuple[str, str | None], size: tuple[int, int]) -> dict:
    """One robot's figures at one size and look (the --json document's keys) from its runs per mode; prints them."""
    tracked = results["tracked"]
    conv = [r["converged_at"] if r["converged_at"] is not None else np.inf for r in tracked]
    frames = sum(r["frames"] for r in tracked)
    realism, appearance = look[0], look[1] or ("realistic" if look[0] == "realistic" else "painted")
    out = {mode: summarize(runs, checkpoints, n_motions) for mode, runs in results.items()}
    out["motions_to_converge_median"] = _finite_or_none(_median(conv))
    out["seconds_per_episode_median"] = _median([r["seconds"]["total"] for r in tracked])
    out["seconds_split"] = {k: _median([r["seconds"].get(k, 0.0) for r in tracked])
                            for k in ("render", "tracking", "solver", "report")}
    out["tracking_plus_solver_ms_per_frame"] = 1e3 * sum(
        r["seconds"]["tracking"] + r["seconds"]["solver"] for r in tracked) / max(frames, 1)
    out["planning_seconds_per_call_median"] = _median([t for r in tracked for t in r["planning"]])
    out.update(tracking_figures(tracked))
    out.update(front_end_figures(tracked))
    out["pose_by_5_fraction"] = pose_by_fraction(tracked, POSE_BY, n_motions)
    out.update(convergence_figures(tracked))
    out.update(coverage_figures(tracked))
    out.update(bias_figures(tracked))
    with_outlines = [r for r in tracked if r["spec"].get("outline_frames")]
    out["outline_runs"] = len(with_outlines)
    out["outline_used_at_end"] = sum(bool(r.get("outline_curve") and r["outline_curve"][-1]) for r in with_outlines)
    out["realism"], out["appearance"] = realism, appearance
    if realism == "realistic":
        out["targets"] = realistic_targets(out, size[1])
    for mode in results:
        for k in checkpoints:
            e = out[mode][str(k)]
            print(f"{mode:>8} @{k:<3} median rotation {e['rot_median_rad']:.2e} rad, "
                  f"translation {e['trans_median_m'] * 1e3:.2f} mm")
    print(f"targets @25 tracked: <= {TARGET_25[0]} rad, <= {TARGET_25[1] * 1e3} mm (paper: {PAPER_25[0]} rad, "
          f"{PAPER_25[1] * 1e3} mm)")
    print(f"motions to converge (median): {out['motions_to_converge_median']}")
    print(f"seconds per episode (median): {out['seconds_per_episode_median']:.1f} "
          f"(render {out['seconds_split']['render']:.1f}, tracking {out['seconds_split']['tracking']:.1f}, "
          f"solver {out['seconds_split']['solver']:.1f}, report {out['seconds_split']['report']:.1f}); "
          f"tracking + solver "
          f"{out['tracking_plus_solver_ms_per_frame']:.1f} ms per rendered frame")
    if out["runs_with_track_counts"]:
        print(f"tracks per motion (median): {out['tracks_per_motion_median']:.0f}, spanning the sweep "
              f"{out['full_tracks_per_motion_median']:.0f}; motions with an axis from stage one per run (median): "
              f"{out['axes_per_run_median']:.1f}; usable result at the end: {out['usable_runs']} of "
              f"{out['runs_with_track_counts']} runs ({realism} camera, {appearance} robot)")
    _print_missing(out, len(tracked))
    if out["runs_with_front_ends"]:
        print(f"motions with an axis per run (median): conics {out['axes_conics_per_run_median']:.1f}, "
              f"rigid {out['axes_rigid_per_run_median']:.1f}")
    if out["pose_by_5_fraction"] is not None:
        print(f"runs with a pose after motion {POSE_BY}: {out['pose_by_5_fraction']:.0%}")
    if out["runs_with_convergence_check"]:
        print(f"runs that declared convergence with a true error over 3x their 1-sigma: "
              f"{out['false_convergence_runs']} of {out['runs_with_convergence_check']}")
    if out["runs_with_coverage_at_end"]:
        print(f"the 95 % region held the truth at the end in {out['coverage_95_at_end']:.0%} of "
              f"{out['runs_with_coverage_at_end']} runs, after {out['coverage_95_updates']:.0%} of "
              f"{out['updates_with_coverage']} updates (median chi-square {out['chi2_updates_median']:.2f}; "
              f"{CHI2_6_MEDIAN:.2f} if calibrated, lower: a region wider than the errors)")
    bias = out["end_error_mean_camera"]
    if bias is not None and bias["runs"] > 1:
        root_n = np.sqrt(bias["runs"])  # the standard error is sd / root_n
        t = "  ".join(f"{a} {m * 1e3:+.2f} +- {s * 1e3 / root_n:.2f}"
                      for a, m, s in zip("xyz", bias["trans_mean_m"], bias["trans_sd_m"], strict=True))
        w = "  ".join(f"{a} {m * 1e6:+.0f} +- {s * 1e6 / root_n:.0f}"
                      for a, m, s in zip("xyz", bias["rot_mean_rad"], bias["rot_sd_rad"], strict=True))
        print(f"mean final error over {bias['runs']} runs, camera frame (estimate - truth; x right, y down, "
              f"z forward; +- its standard error): translation mm {t}; rotation urad {w}")
    if out["outline_runs"]:
        notes = sorted({r["outline_note"] for r in with_outlines if r.get("outline_note")})
        print(f"the outlines joined the estimate at the end of {out['outline_used_at_end']} of {out['outline_runs']} "
              "runs" + (f"; not: {'; '.join(n[:100] for n in notes)}" if notes else ""))
    if "targets" in out:
        print(targets_line(out, n_motions))
    return out


def _print_missing(out: dict, n_runs: int) -> None:
    """Say how many stored records predate a figure (they are left out of it)."""
    for key, what in (("runs_with_track_counts", "track counts and usability"),
                      ("runs_with_front_ends", "axes per front end"),
                      ("runs_with_convergence_check", "the convergence check")):
        if out[key] < n_runs:
            print(f"{n_runs - out[key]} of {n_runs} stored runs predate {what}: left out of it")


def _verdict(met: bool | None) -> str:
    return "n/a" if met is None else ("PASS" if met else "FAIL")


def targets_line(out: dict, n_motions: int) -> str:
    """The issue 19 targets of one realistic group, each with PASS / FAIL / n/a and the measured figure."""
    t = out["targets"]
    at_25 = out["tracked"].get("25")
    median = ("" if at_25 is None else
              f" ({at_25['rot_median_rad']:.2e} rad, {at_25['trans_median_m'] * 1e3:.2f} mm)")
    target = ("median @25 (no target at this size)" if t["median_target_25"] is None else
              f"median @25 <= {t['median_target_25'][0]:.0e} rad / {t['median_target_25'][1] * 1e3:g} mm")
    pose = out["pose_by_5_fraction"]
    return (f"targets: usable on every run by {n_motions} motions {_verdict(t['usable_every_run'])} "
            f"({out['usable_runs']} of {out['runs_with_track_counts']}); "
            f"{target} {_verdict(t['median_at_25'])}{median}; "
            f"pose by {POSE_BY} motions on >= {POSE_BY_FRACTION:.0%} of runs {_verdict(t['pose_by_5'])}"
            f"{'' if pose is None else f' ({pose:.0%})'}; "
            f"no false convergence {_verdict(t['no_false_convergence'])} "
            f"({out['false_convergence_runs']} of {out['runs_with_convergence_check']} runs)")


def _cell(value: float | None, fmt: str) -> str:
    return "-" if value is None or np.isnan(value) else ("inf" if np.isinf(value) else format(value, fmt))


def side_by_side_table(figures: dict[str, dict[str, dict[str, dict]]], looks: list[str]) -> str:
    """A markdown table: a row per robot and size, each cell the figure of every look ("realistic / clean").

    Args:
        figures: {robot: {"WxH": {look: figures of ``robot_figures``}}}.
        looks: the looks in the order the cells give them.
    """
    def error(group: dict, k: int, part: str, scale: float) -> str:
        e = group["tracked"].get(str(k))
        return "-" if e is None else _cell(e[part] * scale, ".2f")

    def fraction(n: int, of: int) -> str:
        return f"{n}/{of}" if of else "-"

    columns = {
        "tracks per motion": lambda g: _cell(g["tracks_per_motion_median"], ".0f"),
        "spanning the sweep": lambda g: _cell(g["full_tracks_per_motion_median"], ".0f"),
        "axes: conics": lambda g: _cell(g["axes_conics_per_run_median"], ".1f"),
        "axes: rigid": lambda g: _cell(g["axes_rigid_per_run_median"], ".1f"),
        "@10 mrad": lambda g: error(g, 10, "rot_median_rad", 1e3),
        "@10 mm": lambda g: error(g, 10, "trans_median_m", 1e3),
        "@25 mrad": lambda g: error(g, 25, "rot_median_rad", 1e3),
        "@25 mm": lambda g: error(g, 25, "trans_median_m", 1e3),
        "usable": lambda g: fraction(g["usable_runs"], g["runs_with_track_counts"]),
        f"pose by {POSE_BY}": lambda g: "-" if g["pose_by_5_fraction"] is None else f"{g['pose_by_5_fraction']:.0%}",
        "false conv.": lambda g: fraction(g["false_convergence_runs"], g["runs_with_convergence_check"]),
    }
    lines = [f"Cells: {' / '.join(looks)} (medians over runs; errors of the tracked runs)", "",
             "| robot | size | " + " | ".join(columns) + " |", "|---|---|" + "---|" * len(columns)]
    for robot, by_size in figures.items():
        for size, by_look in by_size.items():
            cells = [" / ".join(fmt(by_look[look]) for look in looks) for fmt in columns.values()]
            lines.append(f"| {robot} | {size} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
