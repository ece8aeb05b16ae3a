"""Reproduce the paper's simulation study (§VI-A, Fig. 7) and its IoU study, with the marker baseline beside us.

For each camera pose (the benchmarks' fixed poses, as in ``bench_episode.py``: 10 by default) and
seed (5 by default), at 1920x1080:

* ``random``: ARC-Calib in ``ArcCalib-v0`` with ``RandomPlanner`` (the paper's selection), ``--motions``
  exploratory motions, rendered pixels and optical-flow tracking; the true error after every motion.
* ``informed``: the same with ``planners.informed.InformedPlanner`` (ours).
* ``marker``: ``arc_env.bench.marker_baseline``: a ChArUco board on the flange, ``--motions`` board poses,
  OpenCV detection + PnP, eye-to-hand by Shah's method; "n motions" = the first n board poses.

Every method sees the same camera pose. A run without an estimate at some n counts as an infinite
error in the medians (printed "inf", written as null). IoU study (the paper's real-world metric, here
in simulation): at ``--iou-configs`` random collision-free configurations with the robot in view
(the same for every method of an episode, in the scene without the board), the robot mask rendered
with the method's final estimate against the true mask; IoU 0 without an estimate; the mean over
configurations and episodes.

Writes ``OUT/errors.png`` (median error vs number of motions, log scale, with the paper's points),
``OUT/iou.png``, ``OUT/results.md`` (the table, also printed) and, with ``--json PATH``,
``{"methods": {name: {"errors": {"3": {"rot_median_rad", "trans_median_m"}, "10": ..., "25": ...},
"iou_mean"}}}``; a checkpoint beyond ``--motions`` is written as nulls. Plots are drawn with OpenCV
(matplotlib is not a dependency).

``--quick``: 2 poses x 1 seed at 960x540, 10 motions, 5 IoU configurations (a few minutes).
``--store DIR`` keeps every finished episode (``arc_env.bench.episodes``) and reuses it, so a long run can be
interrupted and resumed (and shares runs with ``bench_episode.py`` and ``compare_planners.py``);
``--workers N`` runs N episodes at once (one renderer thread each). The IoU study is recomputed.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from arc_env.bench.episodes import (
    METHODS,
    EpisodeSpec,
    add_study_outline_argument,
    commits_used,
    padded_curve,
    write_figures,
)
from arc_env.bench.poses import benchmark_camera_pose
from arc_env.bench.runner import add_runner_arguments, check_runner_arguments, run_from_arguments
from arc_env.robot.overlay import mask_iou
from arc_env.sim.env import ArcCalibEnv, EnvConfig
from arc_env.sim.scene import SceneConfig

CHECKPOINTS = (3, 10, 25)
#: The paper's simulation figures (§VI-A, mean over 10 poses x 5 runs, random selection): n -> (rad, m).
PAPER_SIM = {3: (0.0225, 0.0786), 25: (0.0042, 0.0065)}
#: The paper's real-world IoU (§VI-B): ARC-Calib and AprilTag hand-eye (ROS hand_eye_calibration).
PAPER_IOU = {"ARC-Calib": 0.94, "AprilTag hand-eye": 0.84}
COLOURS = {"random": (200, 110, 30), "informed": (40, 160, 40), "marker": (40, 40, 210), "paper": (0, 0, 0)}



def iou_study(pose: int, seed: int, estimates: dict[str, np.ndarray | None], args: argparse.Namespace) -> dict:
    """Mean IoU of each estimate's robot mask against the true one over random configurations."""
    env = ArcCalibEnv(EnvConfig(scene=SceneConfig(width=args.width, height=args.height)))
    try:
        env.reset(seed=1000 * pose + seed,
                  options={"camera_pose": benchmark_camera_pose(pose, env.config.camera_target)})
        s, robot = env.scene, env.scene.robot
        rng = np.random.default_rng(5000 + 1000 * pose + seed)
        ious: dict[str, list[float]] = {m: [] for m in estimates}
        min_pixels = 0.002 * s.intrinsics.width * s.intrinsics.height
        for _ in range(200 * args.iou_configs):
            if all(len(v) >= args.iou_configs for v in ious.values()):
                break
            q = rng.uniform(robot.lower, robot.upper)
            if env.session.checker.in_collision(q)[0]:
                continue
            robot.set_q(q)
            true = s.robot_mask()
            if true.sum() < min_pixels:
                continue
            for m, T_camera_base in estimates.items():
                ious[m].append(0.0 if T_camera_base is None else mask_iou(s.robot_mask(T_camera_base), true))
    finally:
        env.close()
    return {m: float(np.mean(v)) if v else float("nan") for m, v in ious.items()}


def _median(values: list[float]) -> float:
    return float(np.median(values)) if values else float("nan")


def summarize(runs: list[dict], n_motions: int) -> dict:
    """Median (rot, trans) per number of motions 1..n_motions."""
    curves = [padded_curve(r, n_motions) for r in runs]
    return {"rot": [_median([c[n][0] for c in curves]) for n in range(n_motions)],
            "trans": [_median([c[n][1] for c in curves]) for n in range(n_motions)]}


# -- plots (OpenCV) ----------------------------------------------------------------------------
def _log_plot(curves: dict[str, list[float]], refs: list[tuple[float, float]], title: str, unit: str,
              size: tuple[int, int] = (760, 420)) -> np.ndarray:
    w, h = size
    left, right, top, bottom = 80, 20, 40, 50
    img = np.full((h, w, 3), 255, np.uint8)
    values = [v for c in curves.values() for v in c if np.isfinite(v) and v > 0] + [y for _, y in refs]
    if not values:
        cv2.putText(img, f"{title}: no estimates", (left, h // 2), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1)
        return img
    lo, hi = np.floor(np.log10(min(values))), np.ceil(np.log10(max(values)))
    hi = max(hi, lo + 1)
    n = max(len(c) for c in curves.values()) if curves else 25
    n = max(n, max((int(x) for x, _ in refs), default=1))

    def px(x: float, y: float) -> tuple[int, int]:
        u = left + (x - 1) / max(n - 1, 1) * (w - left - right)
        v = top + (hi - np.log10(y)) / (hi - lo) * (h - top - bottom)
        return int(round(u)), int(round(v))

    for e in range(int(lo), int(hi) + 1):  # decades
        _, v = px(1, 10.0 ** e)
        cv2.line(img, (left, v), (w - right, v), (225, 225, 225), 1)
        cv2.putText(img, f"1e{e}", (8, v + 5), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (60, 60, 60), 1, cv2.LINE_AA)
    for x in range(1, n + 1):
        if x in (1, n) or x % 5 == 0:
            u, _ = px(x, 10.0 ** lo)
            cv2.putText(img, str(x), (u - 6, h - bottom + 18), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (60, 60, 60), 1)
    cv2.rectangle(img, (left, top), (w - right, h - bottom), (0, 0, 0), 1)
    cv2.putText(img, title, (left, 26), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, f"number of robot motions / board poses    (median {unit}, log scale)",
                (left, h - 12), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    for k, (name, c) in enumerate(curves.items()):
        colour = COLOURS.get(name, (120, 120, 120))
        pts = [px(i + 1, y) for i, y in enumerate(c) if np.isfinite(y) and y > 0]
        for a, b in zip(pts, pts[1:], strict=False):
            cv2.line(img, a, b, colour, 2, cv2.LINE_AA)
        for p in pts:
            cv2.circle(img, p, 3, colour, -1, cv2.LINE_AA)
        cv2.putText(img, name, (w - right - 150, top + 20 + 18 * k), cv2.FONT_HERSHEY_SIMPLEX, 0.5, colour, 1,
                    cv2.LINE_AA)
    for x, y in refs:
        u, v = px(x, y)
        cv2.drawMarker(img, (u, v), COLOURS["paper"], cv2.MARKER_TILTED_CROSS, 12, 2)
    if refs:
        k = len(curves)
        cv2.putText(img, "x paper (sim, random)", (w - right - 150, top + 20 + 18 * k), cv2.FONT_HERSHEY_SIMPLEX,
                    0.5, COLOURS["paper"], 1, cv2.LINE_AA)
    return img


def error_plot(summary: dict[str, dict]) -> np.ndarray:
    """Rotation (top) and translation (bottom) median error vs motions, one line per method."""
    rot = _log_plot({m: s["rot"] for m, s in summary.items()}, [(n, r) for n, (r, _) in PAPER_SIM.items()],
                    "Rotation error", "rad")
    trans = _log_plot({m: s["trans"] for m, s in summary.items()}, [(n, t) for n, (_, t) in PAPER_SIM.items()],
                      "Translation error", "m")
    return np.vstack([rot, trans])


def iou_plot(iou: dict[str, float]) -> np.ndarray:
    """Bars: our mean IoU per method (simulation) and the paper's (real world)."""
    bars = [(f"{m} (ours, sim)", v, COLOURS.get(m, (120, 120, 120))) for m, v in iou.items()]
    bars += [(f"{k} (paper, real)", v, (150, 150, 150)) for k, v in PAPER_IOU.items()]
    w, h, left = 760, 60 + 34 * len(bars), 250
    img = np.full((h, w, 3), 255, np.uint8)
    cv2.putText(img, "Mean IoU of the robot mask rendered with the estimate", (10, 26), cv2.FONT_HERSHEY_SIMPLEX,
                0.6, (0, 0, 0), 1, cv2.LINE_AA)
    for k, (label, v, colour) in enumerate(bars):
        y = 50 + 34 * k
        cv2.putText(img, label, (10, y + 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
        if np.isfinite(v):
            cv2.rectangle(img, (left, y), (left + int((w - left - 80) * v), y + 24), colour, -1)
            cv2.putText(img, f"{v:.3f}", (left + int((w - left - 80) * v) + 6, y + 18), cv2.FONT_HERSHEY_SIMPLEX,
                        0.5, (0, 0, 0), 1, cv2.LINE_AA)
    return img


# -- table and JSON ----------------------------------------------------------------------------
def _fmt(x: float | None, scale: float = 1.0, digits: str = ".2e") -> str:
    if x is None:
        return "-"
    return "inf" if not np.isfinite(x) else format(x * scale, digits)


def _finite_mean(values: list[float]) -> float:
    """The mean of the finite values (per-run IoU means; NaN where a run had none), NaN if none is."""
    finite = [v for v in values if np.isfinite(v)]
    return float(np.mean(finite)) if finite else float("nan")


def markdown_table(summary: dict[str, dict], iou: dict[str, float], n_motions: int, header: str) -> str:
    """The results as a markdown table (ours and the paper's)."""
    cols = [k for k in CHECKPOINTS]
    head = "| method | " + " | ".join(f"rot @{k} (rad) | trans @{k} (mm)" for k in cols) + " | mean IoU |"
    sep = "|---" * (2 * len(cols) + 2) + "|"
    rows = [header, "", head, sep]
    for m, s in summary.items():
        cells = []
        for k in cols:
            if k <= n_motions:
                cells += [_fmt(s["rot"][k - 1]), _fmt(s["trans"][k - 1], 1e3, ".2f")]
            else:
                cells += ["-", "-"]
        mean_iou = iou.get(m)  # NaN: no IoU study ran (--iou-configs 0), not an error
        shown = mean_iou if mean_iou is not None and np.isfinite(mean_iou) else None
        rows.append(f"| {m} (ours, sim) | " + " | ".join(cells) + f" | {_fmt(shown, digits='.3f')} |")
    paper = []
    for k in cols:
        r, t = PAPER_SIM.get(k, (None, None))
        paper += [_fmt(r), _fmt(t, 1e3, ".1f")]
    rows.append("| ARC-Calib random (paper, sim; mean) | " + " | ".join(paper) + " | 0.94 (real) |")
    rows.append("| AprilTag hand-eye (paper, real) | " + " | ".join(["-"] * 2 * len(cols)) + " | 0.84 (real) |")
    return "\n".join(rows)


def json_figures(summary: dict[str, dict], iou: dict[str, float], n_motions: int) -> dict:
    """The ``--json`` document (nulls for infinite errors and checkpoints beyond the budget)."""
    def clean(x: float) -> float | None:
        return float(x) if np.isfinite(x) else None

    out = {}
    for m, s in summary.items():
        errors = {}
        for k in CHECKPOINTS:
            inside = k <= n_motions
            errors[str(k)] = {"rot_median_rad": clean(s["rot"][k - 1]) if inside else None,
                              "trans_median_m": clean(s["trans"][k - 1]) if inside else None}
        out[m] = {"errors": errors, "iou_mean": clean(iou[m])}
    return {"methods": out}


def main(argv: list[str] | None = None) -> int:
    """Run the study; returns the exit code."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses", type=int, default=10, help="camera poses (default 10)")
    parser.add_argument("--seeds", type=int, default=5, help="runs per pose (default 5)")
    parser.add_argument("--motions", type=int, default=25, help="motions / board poses per run (default 25)")
    parser.add_argument("--methods", default=",".join(METHODS), help=f"comma-separated, of {', '.join(METHODS)}")
    parser.add_argument("--width", type=int, default=1920)
    parser.add_argument("--height", type=int, default=1080)
    parser.add_argument("--iou-configs", type=int, default=10, help="configurations per IoU study (default 10)")
    parser.add_argument("--out", type=Path, default=Path("bench_out/reproduce"), help="directory for PNGs and table")
    parser.add_argument("--quick", action="store_true", help="2 poses x 1 seed, 960x540, 10 motions, 5 IoU configs")
    parser.add_argument("--json", type=Path, help="write the figures to this file")
    add_study_outline_argument(parser, 0)  # 0: the tracks alone, as the stored study
    add_runner_arguments(parser)
    args = parser.parse_args(argv)
    check_runner_arguments(parser, args)
    if args.quick:
        args.poses, args.seeds, args.motions, args.width, args.height, args.iou_configs = 2, 1, 10, 960, 540, 5
    methods = list(dict.fromkeys(m.strip() for m in args.methods.split(",") if m.strip()))
    unknown = [m for m in methods if m not in METHODS]
    if unknown or not methods:
        parser.error(f"unknown method(s) {unknown}; valid: {', '.join(METHODS)}")
    print(f"{args.poses} poses x {args.seeds} seeds, {args.motions} motions, {args.width}x{args.height}, "
          f"methods {', '.join(methods)}, IoU at {args.iou_configs} configurations", flush=True)
    checkpoints = [k for k in CHECKPOINTS if k <= args.motions]
    specs = {(m, pose, seed): EpisodeSpec(m, pose, seed, args.motions, args.width, args.height,
                                          realism=args.realism, appearance=args.appearance,
                                          background=args.background,
                                          outline_frames=0 if m == "marker" else args.outline_frames)
             for pose in range(args.poses) for seed in range(args.seeds) for m in methods}

    def show(r: dict, from_store: bool) -> None:
        spec = r["spec"]
        print(f"  {spec['method']} pose {spec['pose']} seed {spec['seed']}: {r['seconds']['total']:.0f} s, "
              f"{r['commit']}{' (stored)' * from_store}", flush=True)

    records = run_from_arguments(specs.values(), args, show)
    print(f"{'method':>8} {'pose':>4} {'seed':>4} " + " ".join(f"{'@' + str(k):>19}" for k in checkpoints)
          + f" {'IoU':>6} {'sec':>6}  note", flush=True)
    runs: dict[str, list[dict]] = {m: [] for m in methods}
    ious: dict[str, list[float]] = {m: [] for m in methods}
    for pose in range(args.poses):
        for seed in range(args.seeds):
            results = {m: records[specs[m, pose, seed]] for m in methods}
            iou = iou_study(pose, seed, {m: None if r["T_camera_base"] is None else np.asarray(r["T_camera_base"])
                                         for m, r in results.items()}, args)
            for m, r in results.items():
                runs[m].append(r)
                ious[m].append(iou[m])
                curve = padded_curve(r, args.motions)
                errs = " ".join(f"{curve[k - 1][0]:>9.2e} {curve[k - 1][1] * 1e3:>6.2f}mm" for k in checkpoints)
                print(f"{m:>8} {pose:>4} {seed:>4} {errs} {iou[m]:>6.3f} {r['seconds']['total']:>6.1f}  {r['note']}",
                      flush=True)
    summary = {m: summarize(rs, args.motions) for m, rs in runs.items()}
    iou_mean = {m: _finite_mean(v) for m, v in ious.items()}
    header = (f"{args.poses} camera poses x {args.seeds} runs, {args.width}x{args.height}, {args.motions} motions; "
              f"median errors, mean IoU over {args.iou_configs} configurations per run")
    table = markdown_table(summary, iou_mean, args.motions, header)
    print()
    print(table)
    print()
    print(f"code: {commits_used(records.values())}")
    for m, rs in runs.items():
        print(f"{m}: median {np.median([r['seconds']['total'] for r in rs]):.1f} s per run")
    args.out.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out / "errors.png"), error_plot(summary))
    cv2.imwrite(str(args.out / "iou.png"), iou_plot(iou_mean))
    (args.out / "results.md").write_text(table + "\n")
    print(f"wrote {args.out / 'errors.png'}, {args.out / 'iou.png'}, {args.out / 'results.md'}")
    if args.json:
        write_figures(args.json, json_figures(summary, iou_mean, args.motions))
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
