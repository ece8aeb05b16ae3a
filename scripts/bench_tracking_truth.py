"""Tracker error against the simulator's truth on rendered episodes: lag, end error, tracks kept.

Runs a random-planner episode (``arc_env.bench.episodes``' scenes and camera poses) once with the default
tracker, then tracks its rendered sweeps with every setting and scores each motion's tracks against the true
projections of the surface points they started on (``arc_env.bench.tracking_truth``): all settings see the
same frames (an episode per setting would not: the random planner's image test reads the estimate, which the
tracks change). Prints per tracker setting the medians over motions and, with --json PATH, writes
{setting: summary} (``tracking_truth.summary``'s keys). With --calibrate each setting's tracks also go to a fresh
calibrator as the episode's (its outline images too): the pose's error after each motion (``"calibration"``: rotation
rad, translation m, or None before a pose), printed at 10 motions and at the last.

Example (about 2 min): python scripts/bench_tracking_truth.py --realism clean --size 1280x720 --motions 8
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

from arc_env.bench.dense_flow import DenseFlowConfig, dense_flow_tracks  # noqa: E402
from arc_env.bench.episodes import EpisodeSpec, make_env  # noqa: E402
from arc_env.bench.tracking_truth import MotionTruth, motion_truth, rendered_motions, summary  # noqa: E402
from arc_env.robot.library import ROBOT_NAMES  # noqa: E402
from arc_env.robot.session import SeenMotion  # noqa: E402
from arc_env.robot.tracking import TrackerConfig, track_keypoints  # noqa: E402
from arc_env.sim.imaging import APPEARANCES, REALISMS  # noqa: E402
from solver.frames import pose_errors  # noqa: E402

#: "default": the tracker as shipped (the affine patch fit on a window weighted by a 4 px Gaussian,
#: ``TrackerConfig.window_sigma_px``, with the whole window's check); "affine": on a uniform window;
#: "gaussian-weighted-check": the Gaussian window judged by the weighted dissimilarity alone
#: (``max_window_dissimilarity`` off); "quadratic": the quadratic warp on a uniform window; "cold-lk": LK searching
#: every pyramid level from rest at each step instead of from the track's last step
#: (``TrackerConfig.predicted_max_level`` off); "still-window": tracks whose detection window stays still while
#: they move are dropped (``TrackerConfig.max_static_fraction`` 0.6); "no-shading-ramp": the patch fit allows only
#: the brightness offset and gain to change, not a linear ramp across the patch (``TrackerConfig.shading_ramp`` off);
#: "dense-flow": no corners, DIS flow from every 8 px grid point of the moving region
#: (``arc_env.bench.dense_flow``); "dense-flow-textured": only grid points whose smaller structure-tensor eigenvalue
#: is at least 1e-4, 4 px apart, a 0.3 px forward-backward check.
SETTINGS: dict[str, TrackerConfig | DenseFlowConfig] = {
            "default": TrackerConfig(), "affine": TrackerConfig(window_sigma_px=0.0),
            "cold-lk": TrackerConfig(predicted_max_level=None),
            "gaussian-weighted-check": TrackerConfig(max_window_dissimilarity=1e9),
            "quadratic": TrackerConfig(quadratic_warp=True, window_sigma_px=0.0),
            "still-window": TrackerConfig(max_static_fraction=0.6),
            "no-shading-ramp": TrackerConfig(shading_ramp=False),
            "dense-flow": DenseFlowConfig(),
            "dense-flow-textured": DenseFlowConfig(grid_px=4, fb_max_px=0.3, min_eigenvalue=1e-4)}


def retracked(seen: list[SeenMotion], tracker: TrackerConfig | DenseFlowConfig) -> list[SeenMotion]:
    """The seen motions that have frames, their tracks replaced by ``tracker``'s of those frames."""
    def tracks(m: SeenMotion) -> list[Any]:
        if isinstance(tracker, DenseFlowConfig):
            return dense_flow_tracks(m.frames, np.asarray(m.deltas), tracker)
        return track_keypoints(m.frames, np.asarray(m.deltas), tracker).tracks

    return [replace(m, tracks=tracks(m)) for m in seen if m.frames is not None]


def score(scene: Any, motions: list[SeenMotion]) -> list[MotionTruth]:  # noqa: ANN401
    """Every motion's tracks scored against the truth."""
    return [motion_truth(scene, m) for m in motions]


def calibrated(session: Any, T_true: np.ndarray, motions: list[SeenMotion],  # noqa: ANN401 (a CalibrationSession)
               outlines: list[list[Any]]) -> list[list[float] | None]:
    """Per motion, the pose's (rotation rad, translation m) error against T_true (4, 4), or None.

    The motions' tracks and their ``outlines`` (per motion, ``session.outline_images``) go into a fresh calibrator
    (``session.reset``: the episode's settings).
    """
    session.reset()
    errors: list[list[float] | None] = []
    for m, images in zip(motions, outlines, strict=True):
        session.observe(m.q_start, m.joint, m.tracks, outlines=images)
        T = session.calibrator.state.T_camera_base
        errors.append(None if T is None else list(pose_errors(T, T_true)))
    return errors


def _show(value: float | None, fmt: str) -> str:
    return "-" if value is None else format(value, fmt)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", default="panda", choices=ROBOT_NAMES)
    parser.add_argument("--realism", default="realistic", choices=REALISMS)
    parser.add_argument("--appearance", default=None, choices=APPEARANCES)
    parser.add_argument("--size", default="1280x720", help="WxH (default 1280x720)")
    parser.add_argument("--pose", type=int, default=0, help="benchmark camera pose (default 0)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--motions", type=int, default=8, help="motions per episode (default 8)")
    parser.add_argument("--settings", default="affine,default", help=f"comma list of {sorted(SETTINGS)}")
    parser.add_argument("--calibrate", action="store_true",
                        help="also calibrate from each setting's tracks (and the outlines): error at 10 and at the end")
    parser.add_argument("--json", type=Path, help="write the summaries to this file")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.lower().split("x"))
    spec = EpisodeSpec("random", args.pose, args.seed, motions=args.motions, width=width, height=height,
                       realism=args.realism, appearance=args.appearance, robot=args.robot)
    names = args.settings.split(",")
    unknown = [n for n in names if n not in SETTINGS]
    if unknown:
        parser.error(f"unknown settings {unknown}; valid: {sorted(SETTINGS)}")
    results = {}
    env, obs = make_env(spec)
    try:
        seen = rendered_motions(env, obs, spec)
        motions = {name: retracked(seen, SETTINGS[name]) for name in names}
        scored = {name: score(env.scene, motions[name]) for name in names}
        poses = {}
        if args.calibrate:  # the outline images depend on the frames alone: found once for every setting
            outlines = [env.session.outline_images(m.q_start, m.joint, np.asarray(m.deltas), m.frames)
                        for m in seen if m.frames is not None]
            poses = {name: calibrated(env.session, env.T_camera_base_true, motions[name], outlines) for name in names}
    finally:
        env.close()
    print(f"{'setting':<16} {'motions':>7} {'tracks':>7} {'on links':>8} {'end px':>7} {'<=1px':>6} {'chord':>12}")
    for name in names:
        results[name] = summary(scored[name])
        r = results[name]
        chord = None if r["chord_scale_median"] is None else r["chord_scale_median"] * 1e3
        print(f"{name:<16} {r['motions']:>7} {_show(r['tracks_median'], '.0f'):>7} "
              f"{_show(r['on_links_median'], '.0f'):>8} {_show(r['end_error_px_median'], '.2f'):>7} "
              f"{_show(r['within_1px_median'], '.2f'):>6} {_show(chord, '+.2f'):>9} o/oo")
        if name in poses:
            r["calibration"] = poses[name]
            for k in sorted({min(10, len(poses[name])), len(poses[name])}):
                e = poses[name][k - 1] if k else None
                print(f"{'':<16} after motion {k}: " + ("no pose" if e is None else
                                                       f"{e[0]:.2e} rad, {e[1] * 1e3:.2f} mm"))
    if args.json:
        args.json.write_text(json.dumps({"spec": vars(args) | {"json": str(args.json)}, "results": results},
                                        indent=2, default=str))


if __name__ == "__main__":
    main()
