"""Random (the paper) against informed (ours) motion selection, on rendered pixels with real tracking.

The same 10 camera poses x 5 seeds for both planners (fixed; ``--poses N --seeds M`` run a subset),
25 motions each, 1920x1080 by default. Prints a table per run and a summary; writes a PNG of the
median rotation and translation error against the number of motions (``--plot``, like the paper's
Fig. 7) and, with ``--json PATH``:
{"random": {"errors": {"1": {"rot_median_rad", "trans_median_m"}, ..., "25": ...},
            "motions_to_paper_accuracy_median": ...},
 "informed": {...same...},
 "informed_fewer_motions_fraction": ...,
 "planning_seconds_median": {"random": ..., "informed": ...}}
plus "planning_seconds_max" and, per planner, "executed_in_collision" (executed sweeps and transits
that a 2 mm re-check finds colliding) and "refused" (actions the env refused). "Paper accuracy" is
rotation <= 0.0042 rad and translation <= 6.5 mm; a run reaches it at the first motion whose estimate
is within both. A run that never does counts as infinitely many motions (null in the JSON when that
is the median); a motion count without an estimate counts as an infinite error. Planning seconds are per call, on
one core (``OMP_NUM_THREADS``/BLAS threads are not restricted: set them to 1 for a strict figure).
``--store DIR`` keeps every finished episode (``arc_env.bench.episodes``) and reuses it, so a long run can be
interrupted and resumed; ``--workers N`` runs N episodes at once (one renderer thread each).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
from reproduce_paper import error_plot  # scripts/ is on sys.path when run as a script

from arc_env.bench.episodes import (
    EpisodeSpec,
    add_study_outline_argument,
    commits_used,
    padded_curve,
    write_figures,
)
from arc_env.bench.runner import add_runner_arguments, check_runner_arguments, run_from_arguments
from arc_env.sim.env import PAPER_ROTATION_RAD, PAPER_TRANSLATION_M

PLANNERS = ("random", "informed")


def motions_to_paper_accuracy(errors: list[tuple[float, float]]) -> float:
    """First motion count (1-based) whose estimate is within the paper's accuracy; inf if none."""
    for i, (rot, trans) in enumerate(errors, start=1):
        if rot <= PAPER_ROTATION_RAD and trans <= PAPER_TRANSLATION_M:
            return float(i)
    return float("inf")


def _median(values: list[float]) -> float:
    return float(np.median(values)) if values else float("nan")


def summarize(runs: list[dict], n_motions: int) -> dict:
    """Median errors per motion count, motions to paper accuracy, planning time, collisions."""
    errors = {}
    for k in range(1, n_motions + 1):
        at_k = [padded_curve(r, n_motions)[k - 1] for r in runs]
        errors[str(k)] = {"rot_median_rad": _median([e[0] for e in at_k]),
                          "trans_median_m": _median([e[1] for e in at_k])}
    return {"errors": errors,
            "motions_to_paper_accuracy_median": _median([motions_to_paper_accuracy(padded_curve(r, n_motions))
                                                         for r in runs]),
            "executed_in_collision": int(sum(r["in_collision"] for r in runs)),
            "refused": int(sum(r["refused"] for r in runs))}


def plot(summary: dict, n_motions: int, path: Path) -> None:
    """Median rotation and translation error against motions, both planners (the paper's Fig. 7)."""
    curves = {name: {"rot": [summary[name]["errors"][str(k)]["rot_median_rad"] for k in range(1, n_motions + 1)],
                     "trans": [summary[name]["errors"][str(k)]["trans_median_m"] for k in range(1, n_motions + 1)]}
              for name in summary if name in PLANNERS}
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), error_plot(curves)):
        raise OSError(f"OpenCV could not write {path}")


def main(argv: list[str] | None = None) -> int:
    """Run the comparison; returns the exit code."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses", type=int, default=10, help="camera poses (default 10)")
    parser.add_argument("--seeds", type=int, default=5, help="seeds per pose (default 5)")
    parser.add_argument("--motions", type=int, default=25, help="motions per episode (default 25)")
    parser.add_argument("--width", type=int, default=1920)
    parser.add_argument("--height", type=int, default=1080)
    parser.add_argument("--plot", type=Path, default=Path("bench_out/compare_planners.png"),
                        help="PNG of median error vs motions (default bench_out/compare_planners.png)")
    parser.add_argument("--json", type=Path, help="write the figures to this file")
    add_study_outline_argument(parser, 0)  # 0: the tracks alone, as the stored comparison
    add_runner_arguments(parser)
    args = parser.parse_args(argv)
    check_runner_arguments(parser, args)
    specs = {(name, pose, seed): EpisodeSpec(name, pose, seed, args.motions, args.width, args.height,
                                             realism=args.realism, appearance=args.appearance,
                                             background=args.background, outline_frames=args.outline_frames)
             for pose in range(args.poses) for seed in range(args.seeds) for name in PLANNERS}
    print(f"{args.poses} poses x {args.seeds} seeds, {args.motions} motions, {args.width}x{args.height}")
    print(f"{'planner':>8} {'pose':>4} {'seed':>4} {'@3':>17} {'@6':>17} {'@10':>17} {'final':>17} "
          f"{'to paper':>8} {'plan med s':>10} {'refused':>7} {'collide':>7} {'sec':>6}  commit")

    def show(r: dict, from_store: bool) -> None:
        curve = padded_curve(r, args.motions)
        cells = []
        for k in (3, 6, 10, args.motions):
            rot, trans = curve[k - 1] if k <= args.motions else (np.inf, np.inf)
            cells.append(f"{rot:>8.1e} {trans * 1e3:>6.1f}mm" if np.isfinite(rot) else f"{'-':>17}")
        spec = r["spec"]
        print(f"{spec['method']:>8} {spec['pose']:>4} {spec['seed']:>4} {' '.join(cells)} "
              f"{motions_to_paper_accuracy(curve):>8.0f} {_median(r['planning']):>10.3f} {r['refused']:>7} "
              f"{r['in_collision']:>7} {r['seconds']['total']:>6.0f}  {r['commit']}{' (stored)' * from_store}"
              f"{'  ' + r['note'] if r['note'] else ''}", flush=True)

    records = run_from_arguments(specs.values(), args, show)
    runs = {name: [records[specs[name, p, s]] for p in range(args.poses) for s in range(args.seeds)]
            for name in PLANNERS}
    reached = {name: [motions_to_paper_accuracy(padded_curve(r, args.motions)) for r in rs]
               for name, rs in runs.items()}
    fewer = [i < r for i, r in zip(reached["informed"], reached["random"], strict=True)]
    summary: dict = {name: summarize(rs, args.motions) for name, rs in runs.items()}
    summary["informed_fewer_motions_fraction"] = float(np.mean(fewer))
    summary["planning_seconds_median"] = {name: _median([t for r in rs for t in r["planning"]])
                                          for name, rs in runs.items()}
    summary["planning_seconds_max"] = {name: max((t for r in rs for t in r["planning"]), default=float("nan"))
                                       for name, rs in runs.items()}
    print()
    print(f"code: {commits_used(records.values())}")
    for name in PLANNERS:
        s = summary[name]
        marks = [k for k in (1, 3, 6, 10, 25) if k <= args.motions]
        cells = ", ".join(f"@{k} {s['errors'][str(k)]['rot_median_rad']:.2e} rad "
                          f"{s['errors'][str(k)]['trans_median_m'] * 1e3:.2f} mm" for k in marks)
        print(f"{name:>8}: {cells}")
        print(f"{'':>8}  motions to paper accuracy (median) {s['motions_to_paper_accuracy_median']}, "
              f"planning {summary['planning_seconds_median'][name]:.3f} s per call (median), "
              f"{summary['planning_seconds_max'][name]:.2f} s (max), "
              f"refused {s['refused']}, executed in collision {s['executed_in_collision']}")
    print(f"informed reaches paper accuracy in fewer motions than random on "
          f"{summary['informed_fewer_motions_fraction']:.0%} of {len(fewer)} runs "
          f"(targets: informed median <= 6 motions, fewer on >= 80% of runs, planning <= 1 s, 0 collisions)")
    plot(summary, args.motions, args.plot)
    print(f"plot: {args.plot}")
    if args.json:
        write_figures(args.json, summary)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
