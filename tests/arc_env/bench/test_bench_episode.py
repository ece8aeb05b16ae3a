"""scripts/bench_episode.py: the realism issue's figures from fake records, and the --json layout."""

import json
from dataclasses import asdict

import numpy as np
import pytest

from arc_env.bench.episodes import (
    FALSE_CONVERGENCE_SIGMAS,
    EpisodeSpec,
    EpisodeStore,
    falsely_converged,
    front_end_axes,
    std_maxima,
    truth_chi2,
)
from solver.frames import perturb
from solver.pipeline import CalibrationState, MotionReport
from tests.support.scripts import load_script


@pytest.fixture(scope="module")
def script():
    return load_script("bench_episode")


def _state(converged: bool, std: list[float] | None) -> CalibrationState:
    return CalibrationState(np.eye(4), "refined", None, None, None if std is None else np.asarray(std), None,
                            converged, 5, 0, 0.2, "")


def test_false_convergence_is_an_error_over_three_sigma_norms():
    std = [1e-3, 1e-3, 1e-3, 2e-3, 0.0, 0.0]  # norms: 1.732e-3 rad, 2e-3 m
    rot_limit, trans_limit = FALSE_CONVERGENCE_SIGMAS * np.sqrt(3) * 1e-3, FALSE_CONVERGENCE_SIGMAS * 2e-3
    assert not falsely_converged(_state(True, std), 0.99 * rot_limit, 0.99 * trans_limit)
    assert falsely_converged(_state(True, std), 1.01 * rot_limit, 0.0)
    assert falsely_converged(_state(True, std), 0.0, 1.01 * trans_limit)
    assert not falsely_converged(_state(False, std), 1.0, 1.0)  # it did not claim convergence
    assert not falsely_converged(_state(True, None), 1.0, 1.0)  # no 1-sigma to check against
    assert not falsely_converged(_state(True, std), None, None)  # no estimate
    assert std_maxima(np.asarray(std)) == [1e-3, 2e-3] and std_maxima(None) is None


def test_front_end_axes_count_each_front_end_and_not_still_motions():
    reports = [
        MotionReport(0, 1, 3, reason="nothing moved: 1 of 3 tracks moved"),  # neither front end ran
        MotionReport(1, 2, 40, front_end="conics"),  # conics only (rigid off or failed)
        MotionReport(2, 3, 40, front_end="rigid", conics="lines, not ellipses"),  # rigid only
        MotionReport(3, 4, 40, front_end="rigid"),  # both gave one; the rigid one is used
        MotionReport(4, 5, 40, conics="ambiguous", rigid="too few tracks"),  # neither
    ]
    assert front_end_axes(reports) == (2, 2)


def _record(curve, *, usable=True, new_keys=True, conics=3, rigid=1, false=0, pose=0, seed=0, robot="panda",
            width=480, height=270, realism="realistic"):
    record = {"spec": {"method": "random", "pose": pose, "seed": seed, "motions": len(curve), "width": width,
                       "height": height, "oracle": False, "realism": realism, "appearance": None, "robot": robot},
              "commit": "abc1234", "curve": curve, "planning": [0.1], "frames": 10, "converged_at": None,
              "note": "", "seconds": {"total": 1.0, "render": 0.5, "tracking": 0.2, "solver": 0.3},
              "tracks": [20] * len(curve), "full_tracks": [5] * len(curve), "axes": conics, "usable": usable}
    if new_keys:
        record.update(axes_conics=conics, axes_rigid=rigid, false_convergence=false,
                      std_curve=[None] * len(curve))
    return record


def test_truth_chi2_is_the_error_in_units_of_the_covariance():
    """Independent construction: an estimate off by xi along each axis of a diagonal covariance."""
    rng = np.random.default_rng(3)
    T_true = perturb(np.eye(4), np.array([0.3, -0.2, 0.1, 0.5, 0.1, 1.2]))
    sigma = np.array([1e-3, 2e-3, 5e-4, 1e-3, 3e-3, 2e-3])
    xi = rng.normal(size=6) * sigma * 2.0
    T_est = perturb(T_true, -xi)  # pose_difference(T_est, T_true) = xi to first order
    state = CalibrationState(T_est, "refined", None, np.diag(sigma**2), sigma, None, False, 5, 0, 0.2, "")
    assert truth_chi2(state, T_true) == pytest.approx(float(np.sum((xi / sigma) ** 2)), rel=1e-3)
    rotated = np.diag(sigma**2)
    Q = np.linalg.qr(rng.normal(size=(6, 6)))[0]
    rotated = Q @ rotated @ Q.T  # the same in another basis: chi-square of Q^T xi per axis
    state = CalibrationState(T_est, "refined", None, rotated, None, None, False, 5, 0, 0.2, "")
    assert truth_chi2(state, T_true) == pytest.approx(float(np.sum((Q.T @ xi / sigma) ** 2)), rel=1e-3)
    assert truth_chi2(_state(True, None), T_true) is None  # no covariance
    singular = CalibrationState(T_est, "refined", None, np.zeros((6, 6)), None, None, False, 5, 0, 0.2, "")
    assert truth_chi2(singular, T_true) is None


def test_coverage_counts_the_runs_whose_region_holds_the_truth(script):
    runs = [_record([[0.001, 0.001]] * 3) for _ in range(4)]
    runs[0]["chi2_curve"] = [None, 30.0, 5.0]  # held at the end
    runs[1]["chi2_curve"] = [2.0, 3.0, 13.0]  # not at the end (12.59)
    runs[2]["chi2_curve"] = [None, None, None]  # never a covariance
    assert "chi2_curve" not in runs[3]  # stored before the figure
    figures = script.coverage_figures(runs)
    assert figures == {"coverage_95_at_end": 0.5, "runs_with_coverage_at_end": 2,
                       "coverage_95_updates": pytest.approx(3 / 5), "updates_with_coverage": 5,
                       "chi2_updates_median": pytest.approx(5.0), "runs_with_chi2": 3}  # of 30, 5, 2, 3, 13
    assert script.coverage_figures(runs[2:])["coverage_95_at_end"] is None
    assert script.coverage_figures(runs[2:])["chi2_updates_median"] is None
    assert script.CHI2_6_95 == pytest.approx(12.592, abs=1e-3)
    assert script.CHI2_6_MEDIAN == pytest.approx(5.348, abs=1e-3)


def test_bias_is_the_mean_of_estimate_minus_truth_in_the_camera_frame(script):
    """Estimates shifted by known camera-frame offsets and turned by known small rotations (left of the truth), written
    as the benchmark writes them (``pose_difference(estimate, truth)``): the figure is their mean and spread."""
    from scipy.spatial.transform import Rotation

    from solver.frames import pose_difference
    rng = np.random.default_rng(3)
    T_true = perturb(np.eye(4), np.array([0.3, -0.2, 0.1, 0.05, -0.1, 1.5]))
    shifts, turns, runs = rng.normal(0, 1e-3, (5, 3)), rng.normal(0, 1e-4, (5, 3)), []
    for d, w in zip(shifts, turns, strict=True):
        T_est = T_true.copy()
        T_est[:3, :3] = Rotation.from_rotvec(w).as_matrix() @ T_true[:3, :3]
        T_est[:3, 3] += d
        runs.append({"error_curve": [None, pose_difference(T_est, T_true).tolist()]})
    runs.append({"error_curve": [None]})  # no estimate at the end
    runs.append({})  # stored before the figure
    bias = script.bias_figures(runs)["end_error_mean_camera"]
    assert bias["runs"] == 5
    np.testing.assert_allclose(bias["trans_mean_m"], shifts.mean(axis=0), atol=1e-12)
    np.testing.assert_allclose(bias["trans_sd_m"], shifts.std(axis=0, ddof=1), atol=1e-12)
    np.testing.assert_allclose(bias["rot_mean_rad"], turns.mean(axis=0), rtol=1e-6)
    np.testing.assert_allclose(bias["rot_sd_rad"], turns.std(axis=0, ddof=1), rtol=1e-5)
    assert script.bias_figures(runs[5:]) == {"end_error_mean_camera": None}
    assert script.bias_figures(runs[:1])["end_error_mean_camera"]["trans_sd_m"] == [None, None, None]


def test_figures_leave_out_old_records(script):
    good = [0.001, 0.001]
    runs = [_record([None] * 4 + [good], conics=4, rigid=2, false=2),
            _record([None] * 5, usable=False, conics=2, rigid=0),
            _record([None, good, good, None, None], new_keys=False, conics=9)]  # stored before the new keys
    front = script.front_end_figures(runs)
    assert front == {"axes_conics_per_run_median": 3.0, "axes_rigid_per_run_median": 1.0, "runs_with_front_ends": 2}
    assert script.convergence_figures(runs) == {"false_convergence_runs": 1, "runs_with_convergence_check": 2}
    assert script.tracking_figures(runs)["usable_fraction"] == pytest.approx(2 / 3)
    # pose after motion 5 comes from the curve, which every record has: only the first run has one
    assert script.pose_by_fraction(runs, 5, 5) == pytest.approx(1 / 3)
    assert script.pose_by_fraction(runs, 5, 4) is None  # the episodes are shorter than 5 motions
    assert script.pose_by_fraction([_record([good, good, good])], 5, 5) == 1.0  # stopped early, kept its pose


def test_targets_pass_fail_and_not_applicable(script):
    runs = [_record([None] * 4 + [[0.0009, 0.0014]] * 21) for _ in range(9)] + [_record([None] * 25)]
    figures = {"tracked": script.summarize(runs, [3, 10, 25], 25), **script.tracking_figures(runs),
               "pose_by_5_fraction": script.pose_by_fraction(runs, 5, 25), **script.convergence_figures(runs)}
    at_1080 = script.realistic_targets(figures, 1080)
    assert at_1080 == {"usable_every_run": True, "median_at_25": True, "median_target_25": [1e-3, 1.5e-3],
                       "pose_by_5": True, "no_false_convergence": True}  # 9 of 10 have a pose: exactly 90 %
    assert script.realistic_targets(figures, 720)["median_target_25"] == [2e-3, 3e-3]
    assert script.realistic_targets(figures, 540)["median_at_25"] is None  # no target below 720 px
    runs[0]["false_convergence"], runs[1]["usable"] = 1, False
    runs[2]["curve"] = [None] * 25  # 8 of 10 runs with a pose by 5; the median at 25 is still 0.9 mrad
    figures.update(script.tracking_figures(runs), pose_by_5_fraction=script.pose_by_fraction(runs, 5, 25),
                   **script.convergence_figures(runs))
    assert script.realistic_targets(figures, 1080) == {
        "usable_every_run": False, "median_at_25": True, "median_target_25": [1e-3, 1.5e-3],
        "pose_by_5": False, "no_false_convergence": False}


def _fake_runner(specs, args, on_record=None):
    """run_from_arguments without rendering: a record per spec whose error depends on its look."""
    records = {}
    for spec in specs:
        error = [0.002, 0.003] if spec.realism == "realistic" else [0.0005, 0.0007]
        record = _record([None] + [error] * (spec.motions - 1), pose=spec.pose, seed=spec.seed, robot=spec.robot,
                         width=spec.width, height=spec.height, realism=spec.realism)
        record["spec"].update(oracle=spec.oracle, appearance=spec.appearance)
        records[spec] = record
        if on_record:
            on_record(record, False)
    return records


def test_json_layout_flat_without_the_new_options_nested_with_them(script, monkeypatch, tmp_path, capsys):
    monkeypatch.setattr(script, "run_from_arguments", _fake_runner)
    flat = tmp_path / "flat.json"
    assert script.main(["--poses", "2", "--seeds", "1", "--motions", "10", "--json", str(flat)]) == 0
    document = json.loads(flat.read_text())
    assert {"tracked", "oracle", "usable_runs", "tracks_per_motion_median"} <= set(document)
    assert document["tracked"]["10"] == {"rot_median_rad": 0.0005, "trans_median_m": 0.0007}
    capsys.readouterr()

    nested = tmp_path / "nested.json"
    assert script.main(["--robots", "panda,iiwa", "--sizes", "1920x1080,1280x720", "--poses", "2", "--seeds", "1",
                        "--motions", "25", "--realism", "realistic", "--beside-clean", "--no-oracle",
                        "--json", str(nested)]) == 0
    document = json.loads(nested.read_text())
    assert list(document) == ["robots"] and list(document["robots"]) == ["panda", "iiwa"]
    for by_size in document["robots"].values():
        assert list(by_size) == ["1920x1080", "1280x720"]
        for size, by_look in by_size.items():
            assert list(by_look) == ["realistic", "clean"]
            realistic, clean = by_look["realistic"], by_look["clean"]
            assert realistic["tracked"]["25"] == {"rot_median_rad": 0.002, "trans_median_m": 0.003}
            assert clean["tracked"]["25"] == {"rot_median_rad": 0.0005, "trans_median_m": 0.0007}
            assert "targets" in realistic and "targets" not in clean and "oracle" not in clean
            # 2 mrad / 3 mm: over the 1080p target, exactly at the 720p one
            assert realistic["targets"]["median_at_25"] is (size == "1280x720")
            assert realistic["pose_by_5_fraction"] == 1.0 and realistic["usable_fraction"] == 1.0
    printed = capsys.readouterr().out
    assert "| iiwa | 1280x720 | 20 / 20 | 5 / 5 |" in printed  # the side-by-side markdown table
    assert "median @25 <= 1e-03 rad / 1.5 mm FAIL" in printed and "median @25 <= 2e-03 rad / 3 mm PASS" in printed


def test_stored_only_reports_the_stored_episodes_and_runs_none(script, monkeypatch, tmp_path, capsys):
    """A partial store: the Panda's seed-0 runs alone. Nothing runs; the iiwa's cell, with none, is left out."""
    def never(*args, **kwargs):
        raise AssertionError("--stored-only ran an episode")

    monkeypatch.setattr(script, "run_from_arguments", never)
    store = EpisodeStore(tmp_path / "store")
    argv = ["--robots", "panda,iiwa", "--poses", "2", "--seeds", "2", "--motions", "10", "--realism", "realistic",
            "--no-oracle", "--store", str(tmp_path / "store")]
    specs = [EpisodeSpec("random", pose, 0, 10, 1920, 1080, realism="realistic", robot="panda", outline_frames=3)
             for pose in range(2)]
    for spec, record in _fake_runner(specs, None).items():
        store.put({**record, "spec": asdict(spec)})
    out = tmp_path / "partial.json"
    assert script.main([*argv, "--stored-only", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "2 of 8 episodes stored" in printed and "iiwa 1920x1080: not every look has stored runs" in printed
    document = json.loads(out.read_text())["robots"]
    assert list(document) == ["panda"]
    assert document["panda"]["1920x1080"]["realistic"]["runs_with_track_counts"] == 2
    with pytest.raises(SystemExit):
        script.main(["--stored-only"])  # no --store


def test_stored_only_with_replay_from_replays_the_captured_episodes_alone(script, monkeypatch, tmp_path, capsys):
    """--stored-only --replay-from SRC: the episodes SRC has a record and a capture of, and --store lacks, are replayed
    (no other is run); then every stored one is reported."""
    specs = [EpisodeSpec("random", pose, seed, 10, 1920, 1080, realism="realistic", robot="panda", outline_frames=3)
             for pose in range(2) for seed in range(2)]
    records = _fake_runner(specs, None)
    source, dest = EpisodeStore(tmp_path / "src"), EpisodeStore(tmp_path / "dst")
    for spec in specs[:3]:  # (0, 0), (0, 1), (1, 0) recorded there
        source.put({**records[spec], "spec": asdict(spec)})
    for spec in (specs[0], specs[2], specs[3]):  # captured: (0, 0), (1, 0) and (1, 1), which has no record
        source.capture_path(spec).parent.mkdir(parents=True, exist_ok=True)
        source.capture_path(spec).write_bytes(b"capture")
    dest.put({**records[specs[0]], "spec": asdict(specs[0])})  # (0, 0) replayed before
    asked = []

    def replaying(todo, args, on_record=None):
        asked.extend(todo)
        assert args.replay_from == tmp_path / "src"
        out = {}
        for spec in todo:
            dest.put({**records[spec], "spec": asdict(spec)})
            out[spec] = records[spec]
            on_record(records[spec], False)
        return out

    monkeypatch.setattr(script, "run_from_arguments", replaying)
    argv = ["--poses", "2", "--seeds", "2", "--motions", "10", "--realism", "realistic", "--no-oracle",
            "--store", str(tmp_path / "dst"), "--stored-only", "--replay-from", str(tmp_path / "src")]
    assert script.main(argv) == 0
    assert asked == [specs[2]]
    assert "2 of 4 episodes stored (1 replayed now)" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        script.main([*argv[:-1], str(tmp_path / "missing")])


def test_bad_sizes_and_beside_clean_without_realism_are_refused(script):
    with pytest.raises(SystemExit):
        script.main(["--sizes", "1920by1080"])
    with pytest.raises(SystemExit):
        script.main(["--beside-clean"])  # --realism is clean already
    assert script.parse_sizes("1920x1080, 1280X720,1920x1080") == [(1920, 1080), (1280, 720)]
