"""``record --format mcap|bag`` writes a real ROS 2 bag that ``calibrate`` reads back: the script's turns are
the motions found, the transits are skipped, a given joint latency is undone by ``--time-offset``.

A tiny episode (3 motions, 320x180 at 10 Hz: no tracking happens at this size, so this tests the
bag's contents and the segmentation, not the pose; the README gives the full-size round trip).
"""

import json

import numpy as np
import pytest

from arc_env.cli import main
from arc_env.robot.bag import read_bag
from arc_env.sim.record import BAG_EPOCH_S, robot_dir_path

LATENCY_S = 0.02
#: rad: a segment's net turn is read at two rests of the exact joint stream.
DELTA_TOL = 1e-6
#: s: a segment starts (stops) at most half the 0.1 s window plus a 200 Hz sample before (after) the turn.
EDGE_TOL = 0.05 + 0.005


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    out = tmp_path_factory.mktemp("bag") / "episode"
    assert main(["record", "--out", str(out), "--format", "mcap", "--motions", "3", "--width", "320", "--height",
                 "180", "--fps", "10", "--seed", "3", "--joint-latency-ms", str(LATENCY_S * 1e3)]) == 0
    return out, json.loads(out.with_name(out.name + ".ground_truth.json").read_text())


def test_the_bag_holds_the_script_and_nothing_of_the_truth(bag):
    out, truth = bag
    assert sorted(p.suffix for p in out.iterdir()) == [".mcap", ".yaml"]
    assert robot_dir_path(out).is_dir() and truth["time_offset_s"] == LATENCY_S
    assert b"T_camera_base" not in next(out.glob("*.mcap")).read_bytes()
    rec = read_bag(out, truth["robot_model"], truth["base_body"], time_offset_s=LATENCY_S)
    assert len(rec.motions) == len(truth["script"]) == 3
    assert all("joints move" in s.reason for s in rec.skipped) and len(rec.skipped) >= 3  # the transits
    for m, seg, step in zip(rec.motions, rec.segments, truth["script"], strict=True):
        assert rec.joint_names[m.joint] == step["joint"] and not m.pruned
        assert seg.delta == pytest.approx(step["delta"], abs=DELTA_TOL)
        # segment times are on the joint clock: the true time + epoch + latency
        start, stop = (BAG_EPOCH_S + step[k] + LATENCY_S for k in ("t_start", "t_stop"))
        assert start - EDGE_TOL <= seg.t_start <= start and stop <= seg.t_stop <= stop + EDGE_TOL
        # with the offset, every frame's delta is the true turn at its exposure (1 rad/s from t_start)
        t = m.times - BAG_EPOCH_S
        turned = np.clip((t - step["t_start"]) / (step["t_stop"] - step["t_start"]), 0, 1) * step["delta"]
        np.testing.assert_allclose(m.delta, turned - turned[0], atol=1e-6)


def test_calibrate_prints_the_segments_and_the_skipped_transits(bag, tmp_path, capsys):
    out, truth = bag
    code = main(["calibrate", str(out), "--robot", truth["robot_model"], "--base-body", truth["base_body"],
                 "--time-offset", str(LATENCY_S), "--output", str(tmp_path / "r.json"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 1 and "Traceback" not in err  # no tracks at 320x180: nothing usable, nothing written
    assert "3 exploratory motion(s) found in /joint_states" in err
    for k, step in enumerate(truth["script"]):
        assert f"motion {k:03d}: {step['joint']} delta {step['delta']:+.3f} rad" in err
    assert "a transit or a multi-joint motion" in err and "time offset +20 ms" in err
    assert not (tmp_path / "r.json").exists()
