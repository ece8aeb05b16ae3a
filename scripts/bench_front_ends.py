"""Each front end's axis error against pixel noise: the paper's conics and the rigid front end, per motion.

Random synthetic Panda motions (``solver.SyntheticScene``: a camera from ``sample_camera_pose``, 1920x1080
D415 intrinsics, 40 tracks of 30 frames, a share of the tracks replaced by tracker failures) at several
pixel noise levels, in two track regimes:

* ``full``: every track spans the whole sweep (the painted robot's case);
* ``short``: every track keeps one random window of 30-60 % of the sweep's frames, and 40 % of the
  tracks fail (drift or jump): what the tracker delivers on realistic images (measured on rendered 1080p
  recordings: median track length 0.4-0.8 of the sweep, about half the tracks sliding).

For each motion, stage one's conics (``estimate_motion_geometry``) and the rigid front end on its own
(``rigid_axis_of_motion`` with no start from the conics) each give an axis or fail with a reason. The
error is the angle between the estimated and the true camera-frame axis lines (unsigned: the conics
cannot tell the turn's sign before the pose). Prints one row per regime, noise level and front end:
motions with an axis, median and 90th-percentile error, and how many are within 3 degrees; ``--json``
writes ``{"<regime>": {"<noise>px": {"conics"|"rigid": {"motions": n, "with_axis": k,
"median_err_rad": x|null, "p90_err_rad": x|null, "within_3deg": m}}}}``.

    .venv/bin/python scripts/bench_front_ends.py --motions 60 --json front_ends.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from solver import PANDA, SyntheticConfig, SyntheticScene, d415_intrinsics, estimate_motion_geometry, sample_camera_pose
from solver.errors import ArcCalibError
from solver.observations import KeypointTrack, MotionObservation
from solver.rigid_axis import rigid_axis_of_motion

NOISE_PX = (0.25, 0.5, 1.0, 2.0)
REGIMES = {"full": 0.1, "short": 0.4}  # regime -> fraction of failed tracks
SHORT_SPAN = (0.3, 0.6)  # a short track keeps this fraction of the sweep's frames


def _shorten(obs: MotionObservation, rng: np.random.Generator) -> MotionObservation:
    """Every track cut to one random window of ``SHORT_SPAN`` of its frames."""
    tracks = []
    for t in obs.tracks:
        n = len(t.delta)
        keep = max(6, int(round(rng.uniform(*SHORT_SPAN) * n)))
        start = int(rng.integers(0, n - keep + 1))
        tracks.append(KeypointTrack(t.pixels[start:start + keep], t.delta[start:start + keep]))
    return MotionObservation(obs.q_start, obs.joint, tuple(tracks))


def _line_angle(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.arccos(np.clip(abs(a @ b) / np.linalg.norm(a) / np.linalg.norm(b), 0.0, 1.0)))


def measure(regime: str, noise_px: float, n_motions: int, seed: int) -> dict[str, dict]:
    """Both front ends on ``n_motions`` random motions of one regime and noise level."""
    rng = np.random.default_rng(seed)
    K = d415_intrinsics()
    config = SyntheticConfig(noise_px=noise_px, outlier_fraction=REGIMES[regime])
    errors: dict[str, list[float]] = {"conics": [], "rigid": []}
    for _ in range(n_motions):
        T = sample_camera_pose(rng)
        motion = SyntheticScene(PANDA, K, T, config, rng).random_motion(rng)
        obs = motion.observation if regime == "full" else _shorten(motion.observation, rng)
        axis_base, _ = PANDA.axis_and_point(obs.q_start, obs.joint)
        truth = T[:3, :3] @ axis_base
        for name, front_end in (("conics", lambda o: estimate_motion_geometry(o, K).axis_cam),
                                ("rigid", lambda o: rigid_axis_of_motion(o, K).axis_cam)):
            try:
                errors[name].append(_line_angle(front_end(obs), truth))
            except ArcCalibError:
                errors[name].append(np.nan)
    out = {}
    for name, e in errors.items():
        got = np.array([x for x in e if np.isfinite(x)])
        out[name] = {"motions": n_motions, "with_axis": int(got.size),
                     "median_err_rad": float(np.median(got)) if got.size else None,
                     "p90_err_rad": float(np.percentile(got, 90)) if got.size else None,
                     "within_3deg": int(np.sum(got < np.radians(3.0)))}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--motions", type=int, default=60, help="random motions per regime and noise (default 60)")
    parser.add_argument("--noise", default=",".join(map(str, NOISE_PX)),
                        help=f"comma-separated pixel noise levels (default {','.join(map(str, NOISE_PX))})")
    parser.add_argument("--regimes", default=",".join(REGIMES), help="full, short or both (default both)")
    parser.add_argument("--seed", type=int, default=11)
    parser.add_argument("--json", type=Path, help="write the figures here")
    args = parser.parse_args()
    noise = [float(x) for x in args.noise.split(",")]
    regimes = [r for r in args.regimes.split(",") if r]
    unknown = [r for r in regimes if r not in REGIMES]
    if unknown or not regimes or args.motions < 1 or any(not x >= 0 for x in noise):
        parser.error(f"regimes must be among {list(REGIMES)}, motions >= 1, noise >= 0")
    result: dict[str, dict] = {}
    print(f"{'regime':>6} {'noise':>6} {'front end':>9} {'with axis':>10} {'median':>9} {'p90':>9} {'< 3 deg':>8}")
    for regime in regimes:
        for n in noise:
            row = measure(regime, n, args.motions, args.seed)
            result.setdefault(regime, {})[f"{n}px"] = row
            for name, r in row.items():
                med = "-" if r["median_err_rad"] is None else f"{np.degrees(r['median_err_rad']):.2f}deg"
                p90 = "-" if r["p90_err_rad"] is None else f"{np.degrees(r['p90_err_rad']):.2f}deg"
                print(f"{regime:>6} {n:>5}px {name:>9} {r['with_axis']:>4}/{r['motions']:<5} {med:>9} {p90:>9} "
                      f"{r['within_3deg']:>8}", flush=True)
    if args.json:
        args.json.write_text(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
