"""``arc-calib verify``: a result against a fresh recording, the pose held fixed.

One small simulated recording per module (320x180, 3 motions, PNG frames). The "results" are written
from its ground truth: the true pose (a perfect calibration: consistent), and the true pose moved. At
this size the default thresholds (set for 720p, README "Checking a calibration") catch a 10 cm / 100 mrad
bump (measured on this recording: residual 0.78 px, IoU 0.57 against 0.18 px and 0.96 at the true pose),
not a 5 cm one (0.45 px, IoU 0.72); that one is caught by thresholds from the recording's own baseline,
as the README advises: twice the true pose's residual, its IoU less 0.15.
"""

import contextlib
import io
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from arc_env.cli import main
from arc_env.robot.exports import RESULT_FORMAT
from arc_env.robot.overlay import RobotProjector, mask_iou
from arc_env.robot.recording import read_recording
from arc_env.robot.verify import VerifyCriteria
from arc_env.sim.record import RecordSettings, ground_truth_path, record_episode
from solver.frames import perturb
from tests.support.joints_csv import read_joints_csv, write_joints_csv

#: A bumped camera: rotated about its x axis and shifted along its y axis, (rad, m) each.
BUMPS = {"bumped_10cm": 0.10, "bumped_5cm": 0.05}
#: Baseline thresholds (the README's advice): residual twice the true pose's, IoU the true pose's less this.
BASELINE_RESIDUAL_FACTOR = 2.0
BASELINE_IOU_MARGIN = 0.15
#: ``RobotProjector.mask(fast=True)`` against the exact fill: the outline may move by a pixel.
FAST_MASK_MIN_IOU = 0.97


def _result(T, joint="robot:panda0_joint2", **changes):
    data = {"format": RESULT_FORMAT, "usable": True, "unusable_reason": "", "source": "rec",
            "T_camera_base": np.asarray(T).tolist(), "frames": {"parent": "panda_link0"}, "time_offset_s": 0.0,
            "per_motion": [{"motion": "000", "joint": joint}]}
    data.update(changes)
    return data


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    root = tmp_path_factory.mktemp("verify")
    out = root / "rec"
    record_episode(RecordSettings(out=out, motions=3, seed=1, width=320, height=180))
    T_true = np.asarray(json.loads(ground_truth_path(out).read_text())["T_camera_base"])
    results = {}
    poses = {"true": T_true, **{k: perturb(T_true, np.array([b, 0, 0, 0, b, 0])) for k, b in BUMPS.items()}}
    for name, T in poses.items():
        results[name] = root / f"{name}.json"
        results[name].write_text(json.dumps(_result(T)))
    return out, results, T_true


@pytest.fixture(scope="module")
def true_report(recording):
    """The report of the true pose, with the default thresholds (computed once)."""
    rec, results, _ = recording
    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        assert main(["verify", str(results["true"]), str(rec), "--json", "-q"]) == 0
    return json.loads(buffer.getvalue())


def _verify(capsys, *args):
    code = main(["verify", *map(str, args), "--json", "-q"])
    out, err = capsys.readouterr()
    return code, (json.loads(out) if out.strip() else None), err


def test_a_recording_is_consistent_with_its_true_pose(recording, true_report):
    _, _, T_true = recording
    report = true_report
    assert report["verdict"] == "consistent" and report["reasons"] == []
    assert report["threshold_px"] == VerifyCriteria.max_residual_px
    residual, iou = report["residual_px"], report["mask_iou"]
    assert residual["median"] <= report["threshold_px"] and residual["tracks"] >= VerifyCriteria.min_tracks
    assert residual["rms"] >= residual["median"] * 0.5  # outlier tracks only add to the RMS
    assert [m["motion"] for m in residual["per_motion"]] == ["000", "001", "002"]
    assert sum(m["tracks"] for m in residual["per_motion"]) == residual["tracks"]
    assert iou["median"] >= iou["threshold"] and len(iou["per_motion"]) == 3
    assert np.allclose(report["T_camera_base"], T_true)


def test_a_bumped_camera_is_inconsistent(recording, true_report, capsys):
    rec, results, _ = recording
    true = true_report
    code, moved, _ = _verify(capsys, results["bumped_10cm"], rec)
    assert code == 1 and moved["verdict"] == "inconsistent" and len(moved["reasons"]) >= 1
    assert moved["residual_px"]["judged"] > moved["threshold_px"] > true["residual_px"]["judged"]
    assert moved["mask_iou"]["median"] < true["mask_iou"]["median"]
    assert moved["residual_px"]["tracks"] == true["residual_px"]["tracks"]  # the same tracks, judged at another pose


def test_a_few_centimetres_are_caught_with_thresholds_from_the_baseline(recording, true_report, capsys):
    rec, results, _ = recording
    true = true_report
    max_px = BASELINE_RESIDUAL_FACTOR * true["residual_px"]["judged"]
    min_iou = true["mask_iou"]["median"] - BASELINE_IOU_MARGIN
    limits = ["--max-residual-px", max_px, "--min-mask-iou", min_iou]
    assert _verify(capsys, results["true"], rec, *limits)[0] == 0
    code, moved, _ = _verify(capsys, results["bumped_5cm"], rec, *limits)
    assert code == 1 and moved["threshold_px"] == pytest.approx(max_px)
    assert moved["residual_px"]["judged"] > max_px or moved["mask_iou"]["median"] < min_iou


def test_the_table_says_the_verdict(recording, capsys):
    rec, results, _ = recording
    assert main(["verify", str(results["bumped_10cm"]), str(rec), "-q"]) == 1
    out = capsys.readouterr().out
    assert "verdict: inconsistent" in out and "mask IoU" in out and "Has the camera moved?" in out


def test_bad_inputs_exit_2_with_a_clear_message(recording, capsys, tmp_path):
    rec, results, T_true = recording
    code, _, err = _verify(capsys, tmp_path / "none.json", rec)
    assert code == 2 and "none.json: no such file" in err
    code, _, err = _verify(capsys, results["true"], tmp_path / "no_recording")
    assert code == 2 and "no_recording: no such recording or bag" in err
    iiwa = tmp_path / "iiwa.json"
    iiwa.write_text(json.dumps(_result(T_true, joint="lbr_iiwa_joint_1")))
    code, _, err = _verify(capsys, iiwa, rec)
    assert code == 2 and "'lbr_iiwa_joint_1'" in err and "same robot" in err
    unusable = tmp_path / "unusable.json"
    unusable.write_text(json.dumps(_result(T_true, usable=False, unusable_reason="too few motions")))
    code, _, err = _verify(capsys, unusable, rec)
    assert code == 2 and "not usable" in err
    still = tmp_path / "still"  # the same frames, but joints.csv says no joint moves
    shutil.copytree(rec, still)
    for csv in sorted(still.glob("motions/*/joints.csv")):
        header, rows = read_joints_csv(csv)
        write_joints_csv(csv, header, [[k, *rows[0][1:]] for k in range(len(rows))])
    code, _, err = _verify(capsys, results["true"], still)
    assert code == 2 and "too few usable motions: 0 of 3" in err


def test_the_fast_model_mask_keeps_the_outline(recording):
    rec, _, T_true = recording
    r = read_recording(rec)
    projector = RobotProjector(r.robot, r.intrinsics)
    m = r.motions[0]
    q = m.q_start.copy()
    q[m.joint] += m.delta[-1]
    bodies = set(r.robot.moving_bodies(m.joint))
    exact = projector.mask(q, T_true, bodies)
    assert exact.sum() > 500  # the moving links are in view
    assert mask_iou(projector.mask(q, T_true, bodies, fast=True), exact) >= FAST_MASK_MIN_IOU
    assert not (exact & ~projector.mask(q, T_true)).any()  # the moving links are part of the whole robot


def test_verify_never_loads_the_simulator():
    code = ("import sys, arc_env.cli.verify\n"
            "print([m for m in sys.modules if m.startswith(('arc_env.sim', 'gymnasium'))])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=Path(__file__).resolve().parents[3])
    assert out.stdout.strip() == "[]"
