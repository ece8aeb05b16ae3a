"""Pose error against joint-log latency, with the time offset estimated by the bundle adjustment and without.

For each seed and latency L (ms): ``arc-calib record --format mcap --joint-latency-ms L`` (the simulator's
episode as a ROS 2 MCAP bag whose joint states are stamped L late) into a temporary directory, then the
bag calibrated as ``arc-calib calibrate`` does (``read_bag`` + ``calibrate_reading_offset``: the joints read
again at the estimated offset while its correction is large; no ``--time-offset``) twice: with the time
offset estimated (the default: a bag's motions carry joint velocities) and with the estimate off
(``RefinementConfig.estimate_time_offset=False``: the joint values taken as stamped).

    python scripts/bench_latency.py [--latencies 0 10 20 40] [--motions 10] [--size 960x540] [--seeds 0]
        [--json out.json]

Prints one row per latency and mode (means over the seeds). ``--json FILE`` writes the same figures::

    {"settings": {"motions", "size", "seeds", "latencies_ms"},
     "latency_ms": {"20": {"estimated": ROW, "fixed": ROW}, ...}}

where ROW holds the means over the seeds that gave a pose -- ``rot_rad`` (geodesic rotation error, rad),
``trans_m`` (translation error, m), ``offset_s`` (the estimated time offset d = t_joint - t_camera, s, over all passes;
null when fixed), ``offset_std_s`` (its 1-sigma, s; null when fixed), ``std_rot_deg`` / ``std_trans_mm``
(the largest 1-sigma of the pose), ``rms_px`` -- plus ``n_pose`` (seeds with a pose), ``n_usable``
(seeds whose result ``calibrate`` would write) and ``per_seed`` (the same keys per seed, with ``seed``,
``usable`` and ``seconds``; null figures where there was no pose).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from arc_env.robot.bag import read_bag
from arc_env.robot.session import UsableCriteria, calibrate_reading_offset, unusable_reason
from arc_env.sim.record import RecordSettings, record_episode
from solver.frames import pose_errors
from solver.pipeline import CalibratorConfig
from solver.refinement import RefinementConfig

#: The two ways to calibrate: the time offset estimated (calibrate's default for a bag), or not.
MODES = {"estimated": CalibratorConfig(),
         "fixed": CalibratorConfig(refinement=RefinementConfig(estimate_time_offset=False))}
FIGURES = ("rot_rad", "trans_m", "offset_s", "offset_std_s", "std_rot_deg", "std_trans_mm", "rms_px")


def calibrate_bag(bag: Path, truth: dict, config: CalibratorConfig) -> dict:
    """One calibration of a recorded bag: its errors against the ground truth and its estimate of the offset."""
    t0 = time.perf_counter()
    run = calibrate_reading_offset(lambda offset: read_bag(bag, truth["robot_model"], truth["base_body"],
                                                           time_offset_s=offset), config=config)
    s = run.calibrator.state
    row: dict = {k: None for k in FIGURES}
    row.update(usable=not unusable_reason(run, UsableCriteria()), seconds=round(time.perf_counter() - t0, 1))
    if s.T_camera_base is not None:
        rot, trans = pose_errors(s.T_camera_base, np.asarray(truth["T_camera_base"]))
        total = None if s.time_offset_s is None else run.given_time_offset_s + s.time_offset_s
        row.update(rot_rad=rot, trans_m=trans, offset_s=total, offset_std_s=s.time_offset_std_s,
                   rms_px=s.rms_px)
    if s.std is not None:
        row.update(std_rot_deg=float(np.degrees(s.std[:3]).max()), std_trans_mm=float(s.std[3:].max() * 1e3))
    return row


def summarize(rows: list[dict]) -> dict:
    """The means over the seeds that gave a pose (None when none did), the counts and the rows."""
    posed = [r for r in rows if r["rot_rad"] is not None]
    out: dict = {}
    for key in FIGURES:
        values = [r[key] for r in posed if r[key] is not None]
        out[key] = float(np.mean(values)) if values else None
    out.update(n_pose=len(posed), n_usable=sum(r["usable"] for r in rows), per_seed=rows)
    return out


def _fmt(value: float | None, scale: float, spec: str) -> str:
    return "-" if value is None else format(value * scale, spec)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--latencies", type=float, nargs="+", default=[0.0, 10.0, 20.0, 40.0], metavar="MS",
                        help="joint-log latencies to record, ms (default 0 10 20 40)")
    parser.add_argument("--motions", type=int, default=10, help="motions per episode (default 10)")
    parser.add_argument("--size", default="960x540", help="image size WxH (default 960x540)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0], help="episode seeds (default 0)")
    parser.add_argument("--json", metavar="FILE", help="write the figures here")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.lower().split("x"))
    rows: dict[float, dict[str, list[dict]]] = {lat: {m: [] for m in MODES} for lat in args.latencies}
    with tempfile.TemporaryDirectory() as tmp:
        for seed in args.seeds:
            for latency in args.latencies:
                bag = Path(tmp) / f"bag_{seed}_{latency:g}ms"
                t0 = time.perf_counter()
                truth = record_episode(RecordSettings(out=bag, motions=args.motions, seed=seed, width=width,
                                                      height=height, format="mcap", joint_latency_s=latency * 1e-3))
                print(f"seed {seed}, latency {latency:g} ms: recorded in {time.perf_counter() - t0:.0f} s", flush=True)
                for mode, config in MODES.items():
                    row = calibrate_bag(bag, truth, config)
                    rows[latency][mode].append({"seed": seed, **row})
                    print(f"  {mode}: {row['seconds']:.0f} s", flush=True)
    table = {f"{lat:g}": {mode: summarize(r) for mode, r in by_mode.items()} for lat, by_mode in rows.items()}
    print(f"\n{args.motions} motions, {args.size}, seeds {args.seeds}; means over the seeds with a pose")
    print(f"{'latency':>8} {'offset':>9} {'rot err':>9} {'trans err':>9} {'offset':>9} {'1-sigma':>8} "
          f"{'1-sigma':>8} {'1-sigma':>8} {'RMS':>6} {'pose':>5} {'usable':>6}")
    print(f"{'ms':>8} {'':>9} {'mrad':>9} {'mm':>9} {'ms':>9} {'ms':>8} {'deg':>8} {'mm':>8} {'px':>6}")
    for lat, by_mode in table.items():
        for mode, r in by_mode.items():
            print(f"{lat:>8} {mode:>9} {_fmt(r['rot_rad'], 1e3, '.3f'):>9} {_fmt(r['trans_m'], 1e3, '.3f'):>9} "
                  f"{_fmt(r['offset_s'], 1e3, '+.2f'):>9} {_fmt(r['offset_std_s'], 1e3, '.2f'):>8} "
                  f"{_fmt(r['std_rot_deg'], 1, '.3f'):>8} {_fmt(r['std_trans_mm'], 1, '.2f'):>8} "
                  f"{_fmt(r['rms_px'], 1, '.3f'):>6} {r['n_pose']:>5} {r['n_usable']:>6}")
    if args.json:
        settings = {"motions": args.motions, "size": args.size, "seeds": args.seeds, "latencies_ms": args.latencies}
        Path(args.json).write_text(json.dumps({"settings": settings, "latency_ms": table}, indent=2) + "\n")
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
