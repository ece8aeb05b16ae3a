"""End-to-end tests of the Calibrator and the per-motion estimation on synthetic Panda scenes."""

import re
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from solver import (
    PANDA,
    CalibrationState,
    Calibrator,
    CalibratorConfig,
    CameraIntrinsics,
    ConvergenceConfig,
    ConvergenceMonitor,
    DegenerateMotionError,
    InvalidInputError,
    KeypointTrack,
    MotionConfig,
    MotionObservation,
    SyntheticConfig,
    SyntheticScene,
    d415_intrinsics,
    estimate_motion_geometry,
    pipeline,
    pose_difference,
    pose_errors,
    sample_camera_pose,
)
from solver.calibration import AxisCorrespondence, family_offsets, pose_family
from solver.camera import pixels_from_camera_points
from solver.errors import (
    InsufficientMotionsError,
    OutlineDisagreementError,
    OutlineMismatchError,
    OutlineReachError,
)
from solver.frames import perturb
from solver.one_axis import OneAxisSearch
from solver.outline_fusion import OutlineAdjustment, OutlineFusionConfig, OutlineImage
from solver.outlines import ImageEdges
from solver.pipeline import CONICS_NOT_RIGID, CONICS_NOT_RUN, FOCAL_SCALE_TOLERANCE
from solver.rigid_axis import RigidAxisConfig
from tests.solver.spheres import sphere_contour

#: Noise-free recovery at the end of an episode (the issue's bound).
EXACT_ROT, EXACT_TRANS = 1e-6, 1e-6
#: With 0.5 px noise and 10% bad tracks, 12 motions give ~0.5 mrad / ~0.5 mm (bench_solver);
#: these bounds are 4-6x that, and far below the paper's 25-motion 0.0042 rad / 6.5 mm.
NOISY_ROT, NOISY_TRANS = 3e-3, 3e-3
#: chi^2_6 quantile 0.999: an honest covariance puts a single run inside it almost always.
CHI2_6_999 = 22.46

K = d415_intrinsics()


def _episode(seed, n, config):
    rng = np.random.default_rng(seed)
    T = sample_camera_pose(rng)
    scene = SyntheticScene(PANDA, K, T, config, rng)
    cal = Calibrator(K, PANDA.axis_and_point)
    for _ in range(n):
        cal.add_motion(scene.random_motion(rng).observation)
    return cal, T


@pytest.fixture(scope="module")
def exact_episode():
    return _episode(1, 8, SyntheticConfig(noise_px=0.0, outlier_fraction=0.0, tracks_per_motion=20))


def test_noise_free_episode_recovers_pose_exactly(exact_episode):
    cal, T = exact_episode
    assert cal.state.stage == "refined"
    rot, trans = pose_errors(cal.state.T_camera_base, T)
    assert rot < EXACT_ROT and trans < EXACT_TRANS
    lin_rot, lin_trans = pose_errors(cal.state.T_linear, T)
    assert lin_rot < EXACT_ROT and lin_trans < EXACT_TRANS


def test_noisy_episode_is_accurate_and_its_covariance_honest():
    cal, T = _episode(2, 12, SyntheticConfig(noise_px=0.5, outlier_fraction=0.1, tracks_per_motion=30))
    s = cal.state
    assert s.stage == "refined"
    rot, trans = pose_errors(s.T_camera_base, T)
    assert rot < NOISY_ROT and trans < NOISY_TRANS
    xi = pose_difference(s.T_camera_base, T)
    assert xi @ np.linalg.solve(s.covariance, xi) < CHI2_6_999
    assert s.std.shape == (6,) and np.all(s.std > 0)
    assert 0.3 < s.rms_px < 1.0  # ~ sqrt(2) * 0.5 px / sqrt(2) per coordinate, plus kept outliers


def test_the_rigid_front_end_gives_axes_and_drops_outlier_tracks():
    rng = np.random.default_rng(4)
    T = sample_camera_pose(rng)
    scene = SyntheticScene(PANDA, K, T, SyntheticConfig(noise_px=0.3, outlier_fraction=0.1, tracks_per_motion=25),
                           rng)
    cal = Calibrator(K, PANDA.axis_and_point, CalibratorConfig(rigid_axis=RigidAxisConfig(), rigid_always=True))
    for _ in range(6):
        cal.add_motion(scene.random_motion(rng).observation)
    fronts = [r.front_end for r in cal.reports]
    assert fronts.count("rigid") >= 4, [(r.front_end, r.rigid, r.conics) for r in cal.reports]
    assert all(r.rigid == "" for r in cal.reports if r.front_end == "rigid")
    assert sum(r.n_inconsistent_tracks for r in cal.reports) >= 1  # the scene's outlier tracks
    rot, trans = pose_errors(cal.state.T_camera_base, T)
    assert cal.state.stage == "refined" and rot < NOISY_ROT and trans < NOISY_TRANS


def _eight_noisy_motions():
    """(T_camera_base, 8 observations): a Panda episode with 0.3 px noise and 10 % bad tracks, 25 tracks a motion."""
    rng = np.random.default_rng(4)
    T = sample_camera_pose(rng)
    scene = SyntheticScene(PANDA, K, T, SyntheticConfig(noise_px=0.3, outlier_fraction=0.1, tracks_per_motion=25),
                           rng)
    return T, [scene.random_motion(rng).observation for _ in range(8)]


def _conics_alone(obs, index):
    """What the conic front end says of motion ``index`` run on its own ("" or why it gave no axis)."""
    try:
        estimate_motion_geometry(obs, K, MotionConfig(), np.random.default_rng([0, index]))
    except DegenerateMotionError as exc:
        return str(exc)
    return ""


def test_the_refined_pose_predicts_the_rigid_front_ends_start():
    """Once there is a refined pose, the rigid front end starts from the axis it predicts and skips its searches;
    off, no motion does; both end at an accurate pose, and the motions before the first pose never do."""
    T, observations = _eight_noisy_motions()
    runs = {}
    for on in (True, False):
        cal = Calibrator(K, PANDA.axis_and_point, CalibratorConfig(predicted_start=on))
        first_pose = None
        for k, obs in enumerate(observations):
            cal.add_motion(obs)
            first_pose = k if first_pose is None and cal.state.stage == "refined" else first_pose
        runs[on] = cal
        assert first_pose is not None and first_pose < 7
        assert not any(r.rigid_predicted for r in cal.reports[:first_pose + 1])
        rot, trans = pose_errors(cal.state.T_camera_base, T)
        assert rot < NOISY_ROT and trans < NOISY_TRANS
    predicted = [r.rigid_predicted for r in runs[True].reports]
    assert sum(predicted) >= 3, [(r.front_end, r.rigid_predicted) for r in runs[True].reports]
    assert not any(r.rigid_predicted for r in runs[False].reports)
    assert [r.front_end for r in runs[True].reports] == [r.front_end for r in runs[False].reports]
    # the conics run only where the rigid fit needs them (no taken prediction), and give what they give alone
    assert [r.conics == CONICS_NOT_RUN for r in runs[True].reports] == [
        r.rigid_predicted and r.front_end == "rigid" for r in runs[True].reports]
    assert not any(r.conics == CONICS_NOT_RUN for r in runs[False].reports)
    for k, (obs, r) in enumerate(zip(observations, runs[True].reports, strict=True)):
        if r.conics != CONICS_NOT_RUN:
            assert r.conics == _conics_alone(obs, k) == runs[False].reports[k].conics


def test_conics_always_reports_the_paper_front_end_on_every_motion_and_changes_nothing_else():
    _, observations = _eight_noisy_motions()
    runs = {}
    for always in (False, True):
        runs[always] = Calibrator(K, PANDA.axis_and_point, CalibratorConfig(conics_always=always))
        for obs in observations:
            runs[always].add_motion(obs)
    lazy, full = runs[False], runs[True]
    assert any(r.conics == CONICS_NOT_RUN for r in lazy.reports)
    # the report's own time is counted apart (benchmarks leave it out of the solver's)
    assert lazy.report_seconds == 0.0 and full.report_seconds > 0.0
    np.testing.assert_array_equal(full.state.T_camera_base, lazy.state.T_camera_base)
    assert [r.front_end for r in full.reports] == [r.front_end for r in lazy.reports]
    for k, (obs, r) in enumerate(zip(observations, full.reports, strict=True)):
        assert r.conics == _conics_alone(obs, k)


def test_same_input_gives_identical_estimates():
    a, _ = _episode(3, 5, SyntheticConfig(tracks_per_motion=15))
    b, _ = _episode(3, 5, SyntheticConfig(tracks_per_motion=15))
    np.testing.assert_array_equal(a.state.T_camera_base, b.state.T_camera_base)


@pytest.mark.parametrize("blas_threads", [1, None])
def test_the_calibrator_limits_blas_threads_while_it_works_and_restores_them(monkeypatch, blas_threads):
    """In add_motion, and in the adjustments of focal_check and batch_refinement."""
    from threadpoolctl import threadpool_info, threadpool_limits

    seen: list[int] = []

    def threads() -> list[int]:
        return [info["num_threads"] for info in threadpool_info() if info["user_api"] == "blas"]

    def kinematics(q, joint):  # called inside add_motion: records the BLAS threads there
        seen.extend(threads())
        return PANDA.axis_and_point(q, joint)

    rng = np.random.default_rng(3)
    scene = SyntheticScene(PANDA, K, sample_camera_pose(rng), SyntheticConfig(tracks_per_motion=15), rng)
    cal = Calibrator(K, kinematics, CalibratorConfig(blas_threads=blas_threads))
    with threadpool_limits(limits=2, user_api="blas"):
        for _ in range(4):
            cal.add_motion(scene.random_motion(rng).observation)
        after = threads()
        adjusted: list[int] = []
        real = pipeline.refine

        def spy(*args, **kwargs):
            adjusted.extend(threads())
            return real(*args, **kwargs)

        monkeypatch.setattr(pipeline, "refine", spy)
        assert cal.state.stage == "refined"
        assert cal.focal_check() is not None and cal.batch_refinement() is not None
        assert threads() == after
    want = {1} if blas_threads == 1 else {2}
    assert seen and set(seen) == want and adjusted and set(adjusted) == want
    assert set(after) == {2}  # restored


def test_blas_threads_must_be_at_least_one():
    for bad in (0, -1, True):
        with pytest.raises(InvalidInputError, match="blas_threads"):
            CalibratorConfig(blas_threads=bad)


def test_too_few_motions_give_no_pose():
    cal, _ = _episode(4, 2, SyntheticConfig(tracks_per_motion=15))
    assert cal.state.T_camera_base is None and cal.state.stage == "none"
    assert "needs 3" in cal.state.message and not cal.state.converged


def test_a_linear_pose_the_refinement_rejects_is_withheld():
    rng = np.random.default_rng(2)  # the noisy episode's scene and motions
    T = sample_camera_pose(rng)
    scene = SyntheticScene(PANDA, K, T, SyntheticConfig(noise_px=0.5, outlier_fraction=0.1,
                                                        tracks_per_motion=30), rng)
    # no pose can meet a 1-nanometre bound, so the refinement rejects every one (the family start, which
    # the same check rejects, is off: it would add a bundle adjustment per motion to this test)
    strict = Calibrator(K, PANDA.axis_and_point, CalibratorConfig(max_std_translation=1e-9, family_start=False))
    linear_only = Calibrator(K, PANDA.axis_and_point, CalibratorConfig(refine=False))
    for _ in range(12):
        obs = scene.random_motion(rng).observation
        strict.add_motion(obs)
        linear_only.add_motion(obs)
    assert strict.state.T_linear is not None
    assert strict.state.T_camera_base is None and strict.state.stage == "none" and not strict.state.converged
    assert "not confirmed by the bundle adjustment" in strict.state.message
    assert "do not fix the pose" in strict.state.message
    assert linear_only.state.stage == "linear"
    np.testing.assert_array_equal(linear_only.state.T_camera_base, linear_only.state.T_linear)


def test_shoulder_joints_alone_never_give_a_pose():
    """Joints 1-3 of the Panda meet at the shoulder: depth is free, so no pose may be reported."""
    rng = np.random.default_rng(5)
    T = sample_camera_pose(rng)
    scene = SyntheticScene(PANDA, K, T, SyntheticConfig(noise_px=0.0, outlier_fraction=0.0,
                                                        tracks_per_motion=20), rng)
    cal = Calibrator(K, PANDA.axis_and_point, CalibratorConfig(family_start=True))  # the start must not invent depth
    for _ in range(8):
        cal.add_motion(scene.random_motion(rng, joints=(0, 1, 2)).observation)
    assert cal.state.T_camera_base is None
    assert re.search(r"not fixed|cannot fix|do not fix", cal.state.message)
    assert "gave no axis" not in cal.state.message
    assert not cal.state.converged
    # a distal motion whose trajectories are straight lines gives no axis: the message points to it
    deltas = np.linspace(0, 0.5, 20)
    lines = tuple(KeypointTrack(np.array([400.0 + 30 * k, 300.0 + 11 * k]) + np.outer(deltas, [200.0, 80.0]), deltas)
                  for k in range(10))
    report = cal.add_motion(MotionObservation(np.zeros(7), 5, lines))
    assert "lines, not ellipses" in report.stage_one
    assert cal.state.T_camera_base is None
    assert "1 of 9 motions gave no axis" in cal.state.message


def _stage_one_for(monkeypatch, n_axes):
    """Let the conics give an axis to the first ``n_axes`` motions where they find one, and none after.

    With the rigid front end off (``CalibratorConfig(rigid_axis=None)``) that is all of stage one.
    """
    real = pipeline.estimate_motion_geometry
    found = []

    def limited(obs, *args, **kwargs):
        if len(found) >= n_axes:
            raise DegenerateMotionError("stage one switched off by the test")
        geometry = real(obs, *args, **kwargs)
        found.append(geometry)
        return geometry

    monkeypatch.setattr(pipeline, "estimate_motion_geometry", limited)


def test_two_axes_start_the_bundle_adjustment_from_the_pose_family(monkeypatch):
    """Only two motions give an axis; the others carry tracks. The pose comes from the family member
    that explains every motion's tracks, though the family spans members metres off."""
    _stage_one_for(monkeypatch, 2)
    rng = np.random.default_rng(1)
    T = sample_camera_pose(rng)
    scene = SyntheticScene(PANDA, K, T, SyntheticConfig(noise_px=0.5, outlier_fraction=0.1, tracks_per_motion=20),
                           rng)
    cal = Calibrator(K, PANDA.axis_and_point, CalibratorConfig(rigid_axis=None, family_start=True))
    first = None
    observations = [scene.random_motion(rng).observation for _ in range(7)]
    for obs in observations:
        cal.add_motion(obs)
        if first is None and cal.state.T_camera_base is not None:
            first = cal.state
    with_axis = [k for k in range(7) if cal.motion_geometry(k) is not None]
    assert len(with_axis) == 2
    assert first is not None and first.stage == "refined" and first.start == "family"
    assert first.T_linear is None
    rot, trans = pose_errors(first.T_camera_base, T)
    assert rot < NOISY_ROT and trans < NOISY_TRANS
    xi = pose_difference(first.T_camera_base, T)
    assert xi @ np.linalg.solve(first.covariance, xi) < CHI2_6_999
    assert not first.converged
    # the choice was not trivial: the family holds members far from the true pose
    cors = []
    for k in with_axis:
        axis_base, point_base = PANDA.axis_and_point(observations[k].q_start, observations[k].joint)
        g = cal.motion_geometry(k)
        cors.append(AxisCorrespondence(axis_base, point_base, g.axis_cam, g.plane_normal))
    R, t0, u = pose_family(cors)
    joints = np.array([PANDA.axis_and_point(obs.q_start, obs.joint)[1] for obs in observations])
    s = family_offsets(R, t0, u, joints, np.geomspace(*cal.config.family_distances, cal.config.family_samples))
    assert np.ptp(np.linalg.norm(t0 + np.outer(s, u) - T[:3, 3], axis=1)) > 1.0
    # later motions warm-start from it and stay accurate
    s_end = cal.state
    assert s_end.stage == "refined" and s_end.start == "previous"
    rot, trans = pose_errors(s_end.T_camera_base, T)
    assert rot < NOISY_ROT and trans < NOISY_TRANS


def test_a_family_chain_is_checked_against_the_linear_start_once_there_is_one(monkeypatch):
    """A chain begun from the pose family meets a linear pose: both starts are adjusted on every motion and
    the better fit goes on. The chain is turned half a turn first (the tracks behind its camera): the linear
    start must take over, and the chain's comparisons end."""
    _stage_one_for(monkeypatch, 2)
    rng = np.random.default_rng(2)
    T = sample_camera_pose(rng)
    scene = SyntheticScene(PANDA, K, T, SyntheticConfig(noise_px=0.5, outlier_fraction=0.1, tracks_per_motion=20),
                           rng)
    cal = Calibrator(K, PANDA.axis_and_point, CalibratorConfig(rigid_axis=None, family_start=True))
    observations = [scene.random_motion(rng).observation for _ in range(11)]
    for obs in observations[:6]:
        cal.add_motion(obs)
    assert cal.state.stage == "refined" and cal.state.T_linear is None and cal._from_family
    # a chain stuck elsewhere: its pose (the next update's start) turned about the camera's y axis
    wrong = cal._refined.T_camera_base.copy()
    wrong[:3] = np.hstack([Rotation.from_rotvec([0.0, np.pi, 0.0]).as_matrix(), [[0.0], [0.0], [0.0]]]) @ wrong
    cal._refined = replace(cal._refined, T_camera_base=wrong)
    monkeypatch.undo()  # stage one gives axes again: the next motions bring a linear pose
    for obs in observations[6:]:
        cal.add_motion(obs)
        if cal.state.T_linear is not None:
            break
    s = cal.state
    assert s.T_linear is not None and s.stage == "refined" and s.start == "linear" and not cal._from_family
    rot, trans = pose_errors(s.T_camera_base, T)
    assert rot < NOISY_ROT and trans < 3 * NOISY_TRANS  # 7 motions, 20 tracks each, 10 % outliers
    xi = pose_difference(s.T_camera_base, T)
    assert xi @ np.linalg.solve(s.covariance, xi) < CHI2_6_999


def test_one_axis_gives_no_pose_and_says_why(monkeypatch):
    _stage_one_for(monkeypatch, 1)
    rng = np.random.default_rng(1)
    T = sample_camera_pose(rng)
    scene = SyntheticScene(PANDA, K, T, SyntheticConfig(noise_px=0.5, outlier_fraction=0.1, tracks_per_motion=15),
                           rng)
    cal = Calibrator(K, PANDA.axis_and_point, CalibratorConfig(rigid_axis=None, family_start=True))
    for _ in range(4):
        cal.add_motion(scene.random_motion(rng).observation)
    s = cal.state
    assert s.T_camera_base is None and s.stage == "none" and s.start == "" and not s.converged
    assert "1 motion(s) with an axis; the linear calibration needs 3" in s.message
    assert "no start from the two-axis pose family: it needs 2 motions with non-parallel axes" in s.message


def test_parallel_axes_give_no_family_start():
    rng = np.random.default_rng(8)
    T = sample_camera_pose(rng)
    scene = SyntheticScene(PANDA, K, T, SyntheticConfig(noise_px=0.0, outlier_fraction=0.0, tracks_per_motion=12),
                           rng)
    cal = Calibrator(K, PANDA.axis_and_point, CalibratorConfig(family_start=True))
    for _ in range(2):  # the base joint's axis is the base z axis at every configuration
        cal.add_motion(scene.random_motion(rng, joints=(0,)).observation)
    assert cal.motion_geometry(0) is not None and cal.motion_geometry(1) is not None
    assert cal.state.T_camera_base is None
    assert re.search(r"no start from the two-axis pose family: .*parallel", cal.state.message)


def test_tracks_that_do_not_turn_rigidly_give_no_axis_from_the_conics_either():
    """The same pixels as an elbow motion, but each track told its own angle scale (0.4-1.6): the paths are the
    same circles, the turn is not one rigid turn by the known angles. The rigid front end, started from the
    conics' axis among others, finds 2 of 30 tracks rigid; the conics alone would give an axis 29 degrees off.
    It is not used, and the report says why. (With seed 5 of this construction the conics' axis would be 0.5
    degrees off and is dropped all the same: no axis is taken from tracks that do not turn rigidly.)"""
    rng = np.random.default_rng(3)
    T = sample_camera_pose(rng)
    scene = SyntheticScene(PANDA, K, T, SyntheticConfig(noise_px=0.3, outlier_fraction=0.0, tracks_per_motion=30), rng)
    obs = scene.random_motion(rng, joints=(3,)).observation
    scales = rng.uniform(0.4, 1.6, len(obs.tracks))
    tracks = tuple(KeypointTrack(t.pixels, t.delta * s) for t, s in zip(obs.tracks, scales, strict=True))
    skewed = MotionObservation(obs.q_start, obs.joint, tracks)
    conics_only = Calibrator(K, PANDA.axis_and_point, CalibratorConfig(rigid_axis=None))
    conics_only.add_motion(skewed, update=False)
    axis_true = T[:3, :3] @ PANDA.axis_and_point(obs.q_start, obs.joint)[0]
    assert np.degrees(np.arccos(abs(conics_only.motion_geometry(0).axis_cam @ axis_true))) > 20.0
    cal = Calibrator(K, PANDA.axis_and_point, CalibratorConfig())
    report = cal.add_motion(skewed, update=False)
    assert cal.motion_geometry(0) is None and report.front_end == ""
    assert report.conics == CONICS_NOT_RIGID
    assert report.rigid.startswith("rigid front end: only 2 of 30 tracks move rigidly together")
    # told the true angles, the same pixels give the rigid front end's axis
    fair = Calibrator(K, PANDA.axis_and_point, CalibratorConfig())
    assert fair.add_motion(obs, update=False).front_end == "rigid"


def test_motion_where_nothing_moved_is_rejected_with_reason(exact_episode):
    cal, _ = exact_episode
    still = MotionObservation(np.zeros(7), 3, tuple(
        KeypointTrack(np.full((20, 2), 500.0) + k, np.linspace(0, 0.5, 20)) for k in range(10)))
    report = cal.add_motion(still)
    assert not report.accepted and "nothing moved" in report.reason
    assert cal.state.n_rejected >= 1


def test_nan_track_is_refused_at_the_boundary():
    with pytest.raises(InvalidInputError, match="NaN"):
        KeypointTrack(np.array([[1.0, np.nan]] * 6), np.zeros(6))


def test_bad_kinematics_output_is_refused():
    cal = Calibrator(K, lambda q, j: (np.array([np.nan, 0, 1.0]), np.zeros(3)))
    obs = MotionObservation(np.zeros(7), 0, ())
    with pytest.raises(InvalidInputError, match="invalid axis"):
        cal.add_motion(obs)
    assert cal.reports == []  # nothing stored: reports and motions stay in step


def _circle_tracks(axis_point, axis_dir, points, deltas, intrinsics: CameraIntrinsics):
    """Tracks of camera-frame points turned about a camera-frame axis, projected with a pinhole."""
    tracks = []
    for p in points:
        rot = Rotation.from_rotvec(np.outer(deltas, axis_dir)).as_matrix()
        pc = np.einsum("kij,j->ki", rot, p - axis_point) + axis_point
        uv = pc[:, :2] / pc[:, 2:] * intrinsics.focal + intrinsics.K[:2, 2]
        tracks.append(KeypointTrack(uv, deltas))
    return tuple(tracks)


def test_single_trajectory_motion_is_degenerate():
    deltas = np.linspace(0, 1.0, 30)
    tracks = _circle_tracks(np.array([0, 0, 1.5]), np.array([0.3, 0.5, 0.8]) / np.linalg.norm([0.3, 0.5, 0.8]),
                            [np.array([0.2, 0.1, 1.4])], deltas, K)
    with pytest.raises(DegenerateMotionError, match="only 1 of 1 trajectories moved"):
        estimate_motion_geometry(MotionObservation(np.zeros(7), 0, tracks), K)


def test_camera_in_the_plane_of_rotation_gives_lines():
    """Axis along camera y through (0, 0, 2): every circle lies in a plane y = c; with c = 0 the
    camera centre is in the plane and every trajectory is a straight line."""
    rng = np.random.default_rng(6)
    pts = [np.array([x, 0.0, 2.0 + z]) for x, z in rng.uniform(-0.3, 0.3, (12, 2))]
    tracks = _circle_tracks(np.array([0, 0, 2.0]), np.array([0, 1.0, 0]), pts, np.linspace(0, 1.0, 30), K)
    with pytest.raises(DegenerateMotionError, match="lines, not ellipses"):
        estimate_motion_geometry(MotionObservation(np.zeros(7), 0, tracks), K)


def test_axis_through_the_camera_centre_has_no_reference_plane():
    rng = np.random.default_rng(7)
    axis = np.array([0.1, -0.05, 1.0]) / np.linalg.norm([0.1, -0.05, 1.0])
    pts = [axis * d + rng.normal(0, 0.15, 3) for d in rng.uniform(1.5, 2.0, 12)]
    tracks = _circle_tracks(np.zeros(3), axis, pts, np.linspace(0, 1.2, 30), K)
    with pytest.raises(DegenerateMotionError, match="camera centre"):
        estimate_motion_geometry(MotionObservation(np.zeros(7), 0, tracks), K)


def test_convergence_monitor_window_and_range():
    mon = ConvergenceMonitor(ConvergenceConfig(window=3, max_rotation_range=1e-3, max_translation_range=1e-3))
    T = np.eye(4)
    mon.push(T)
    mon.push(T)
    assert mon.gamma is None and not mon.converged
    mon.push(T)
    assert mon.converged and np.all(mon.gamma == 0)
    jumped = T.copy()
    jumped[0, 3] = 2e-3
    mon.push(jumped)
    assert not mon.converged and mon.gamma[3] == pytest.approx(2e-3)


def _window_run(observations, extra, min_leverage):
    """The monitor's range (window 2) after ``observations``, and after ``extra`` too, with its report."""
    cal = Calibrator(K, PANDA.axis_and_point,
                     CalibratorConfig(convergence=ConvergenceConfig(window=2, min_leverage=min_leverage)))
    for obs in observations:
        cal.add_motion(obs)
    before = cal.state.gamma
    report = cal.add_motion(extra)
    return before, cal.state.gamma, report


def test_the_convergence_window_takes_only_estimates_after_motions_that_inform_them():
    """An estimate after a pruned or rejected motion repeats the one before: in the window it would make the range
    small without testing anything (a realistic xArm 6 episode converged that way, 4.6 mm off its truth)."""
    _, observations = _eight_noisy_motions()
    first, nxt = observations[:6], observations[6]
    still = MotionObservation(nxt.q_start, nxt.joint, tuple(
        KeypointTrack(np.full((20, 2), 500.0) + k, np.linspace(0, 0.5, 20)) for k in range(10)))
    before, after, report = _window_run(first, still, 0.0)
    assert before is not None and np.any(before > 0)
    assert "nothing moved" in report.reason and np.array_equal(after, before)
    before, after, report = _window_run(first, replace(nxt, tracks=nxt.tracks[:4]), 0.0)
    assert not report.accepted and np.array_equal(after, before)  # kept in the adjustment, but not informing
    before, after, report = _window_run(first, nxt, 0.0)
    assert report.accepted and 0 < report.leverage <= 1 and not np.array_equal(after, before)
    # the motion's share of the pose information decides: just over it, it enters; just under, it does not
    # (with the threshold that high, earlier motions may stay out too: each run is compared with itself)
    before_low, after_low, _ = _window_run(first, nxt, report.leverage - 1e-6)
    before_high, after_high, high = _window_run(first, nxt, report.leverage + 1e-6)
    assert before_high is not None and np.array_equal(after_high, before_high)
    assert not np.array_equal(after_low, before_low)
    assert high.accepted and high.leverage == pytest.approx(report.leverage)


@pytest.mark.parametrize("summaries", [True, False])
def test_a_motion_with_too_few_agreeing_tracks_does_not_inform_the_estimate(summaries, monkeypatch):
    """Its report says it does not inform the estimate, and it does not: the pose and covariance are those of the
    motions before it (a captured realistic xArm 6 wrist motion with 2 of 8 tracks kept had put the truth at
    chi-square 107); also with a backend that gives no motion summaries (the Ceres one), stood in for here."""
    if not summaries:
        import solver.pipeline as pipeline

        refine = pipeline.refine
        monkeypatch.setattr(pipeline, "refine", lambda *a, **k: replace(refine(*a, **k), summaries=()))
    _, observations = _eight_noisy_motions()
    first, nxt = observations[:6], observations[6]
    cal = Calibrator(K, PANDA.axis_and_point)
    for obs in first:
        cal.add_motion(obs)
    before = cal.state
    report = cal.add_motion(replace(nxt, tracks=nxt.tracks[:4]))
    assert not report.accepted and 0 < report.n_inlier_tracks < 4, (report.n_inlier_tracks, report.reason)
    assert "agree with the refined pose" in report.reason
    after = cal.state
    d = pose_difference(after.T_camera_base, before.T_camera_base)
    assert after.stage == "refined" and d @ np.linalg.solve(before.covariance, d) < 0.1**2  # batch vs incremental
    L = np.linalg.cholesky(before.covariance)
    ratio = np.linalg.eigvalsh(np.linalg.solve(L, np.linalg.solve(L, after.covariance).T))  # whitened by before
    assert np.all((ratio > 0.8) & (ratio < 1.25)), ratio
    cal.add_motion(nxt)  # a motion whose tracks agree informs it again
    assert cal.reports[-1].accepted and cal.state.n_accepted == 7


def test_convergence_config_is_validated():
    with pytest.raises(InvalidInputError, match="window"):
        ConvergenceConfig(window=1)
    for bad in (-0.1, 1.0, float("nan")):
        with pytest.raises(InvalidInputError, match="min_leverage"):
            ConvergenceConfig(min_leverage=bad)


def test_state_type(exact_episode):
    assert isinstance(exact_episode[0].state, CalibrationState)


def test_a_singular_adjustment_says_so_in_words(monkeypatch):
    """numpy's "leading minor not positive definite" never reaches the user."""
    import solver.pipeline as pipeline

    def singular(*args, **kwargs):
        raise np.linalg.LinAlgError("8-th leading minor of the array is not positive definite")

    monkeypatch.setattr(pipeline, "refine", singular)
    cal, _ = _episode(1, 6, SyntheticConfig(noise_px=0.0, outlier_fraction=0.0, tracks_per_motion=20))
    assert cal.state.T_linear is not None and cal.state.T_camera_base is None and not cal.state.converged
    assert "equations are singular" in cal.state.message and "minor" not in cal.state.message


# -- a fisheye camera ---------------------------------------------------------------------------------------
#: A 1280x800 fisheye (OpenCV's model; corners 77 degrees off the axis), the camera 0.6-1.6 m from the arm so
#: the tracks spread out to ~550 px from the centre, where r = f theta_d is 10-50 % inside a pinhole's f tan(theta).
FISHEYE = CameraIntrinsics(K=np.array([[520.0, 0.0, 641.3], [0.0, 522.0, 398.2], [0.0, 0.0, 1.0]]),
                           dist=np.array([0.08, -0.03, 0.008, -0.001]), width=1280, height=800, model="fisheye")
#: The same K and D read as OpenCV's pinhole model: what a solver ignoring the lens model would use.
FISHEYE_AS_PINHOLE = CameraIntrinsics(K=FISHEYE.K, dist=np.zeros(0), width=1280, height=800)
#: The pinhole model on fisheye tracks: measured 26 mrad / 113 mm off (seed 1, noise-free; 12-motion noisy
#: runs 15-30 mrad / 34-152 mm); the bound is far above EXACT and far below those.
MISMODELLED_ROT, MISMODELLED_TRANS = 5e-3, 1e-2


@pytest.fixture(scope="module")
def fisheye_episode():
    rng = np.random.default_rng(1)
    T = sample_camera_pose(rng, distance=(0.6, 1.6))
    scene = SyntheticScene(PANDA, FISHEYE, T, SyntheticConfig(noise_px=0.0, outlier_fraction=0.0,
                                                              tracks_per_motion=20), rng)
    return T, [scene.random_motion(rng).observation for _ in range(8)]


def _calibrate(intrinsics, motions):
    cal = Calibrator(intrinsics, PANDA.axis_and_point)
    for m in motions:
        cal.add_motion(m, update=False)
    cal.update()
    return cal


def test_a_fisheye_camera_is_calibrated_through_its_model(fisheye_episode):
    T, motions = fisheye_episode
    pixels = np.concatenate([t.pixels for m in motions for t in m.tracks])
    assert np.max(np.hypot(*(pixels - FISHEYE.K[:2, 2]).T)) > 300  # the lens model matters out there
    cal = _calibrate(FISHEYE, motions)
    assert cal.state.stage == "refined"
    rot, trans = pose_errors(cal.state.T_camera_base, T)
    assert rot < EXACT_ROT and trans < EXACT_TRANS  # as the noise-free pinhole episode
    check = cal.focal_check()
    assert check is not None and check.fits and abs(check.best_scale - 1.0) < FOCAL_SCALE_TOLERANCE
    wrong = _calibrate(FISHEYE_AS_PINHOLE, motions)
    assert wrong.state.T_camera_base is not None
    rot, trans = pose_errors(wrong.state.T_camera_base, T)
    assert rot > MISMODELLED_ROT or trans > MISMODELLED_TRANS


def test_a_fisheye_focal_length_3_percent_high_is_flagged(fisheye_episode):
    T, motions = fisheye_episode
    K = FISHEYE.K.copy()
    K[[0, 1], [0, 1]] *= 1.03
    check = _calibrate(replace(FISHEYE, K=K), motions).focal_check()
    # measured: best at 0.969 (1 / 1.03 = 0.971), RMS 0.052 px at 0.98 against 0.097 px at the given K
    assert check is not None and not check.fits and 0.95 < check.best_scale < 0.98


def test_the_motions_fix_the_pose_is_judged_before_the_motion_jackknife():
    """Each sweep's tracks all shifted by one ~2 px offset: the motions disagree beyond the pixel noise, so the
    reported covariance takes the leave-one-motion-out jackknife; whether a pose is given is judged without it."""
    rng = np.random.default_rng(41)
    scene = SyntheticScene(PANDA, K, sample_camera_pose(rng),
                           SyntheticConfig(noise_px=0.3, outlier_fraction=0.0, tracks_per_motion=20), rng)
    observations = []
    for _ in range(8):
        obs = scene.random_motion(rng).observation
        shift = rng.normal(0.0, 2.0, 2)
        observations.append(replace(obs, tracks=tuple(replace(t, pixels=t.pixels + shift) for t in obs.tracks)))

    def run(config):
        cal = Calibrator(K, PANDA.axis_and_point, config)
        for obs in observations:
            cal.add_motion(obs)
        return cal

    free = run(CalibratorConfig(family_start=False))
    assert free.state.stage == "refined"
    reported = float(np.max(free.state.std[3:]))
    geometric = float(np.max(np.sqrt(np.diag(free._refined.sandwich_covariance))[3:]))
    assert reported > 1.5 * geometric  # the jackknife was taken and widens the 1-sigma (seen: 5.5 mm, 2.0 mm)
    bound = 0.5 * (reported + geometric)  # between the two: the geometry fixes the pose to it, the report does not
    bounded = run(CalibratorConfig(family_start=False, max_std_translation=bound))
    assert bounded.state.stage == "refined"
    assert np.max(bounded.state.std[3:]) > bound  # the reported 1-sigma keeps the jackknife


@pytest.mark.parametrize(("offset_sigma", "rival_wins"), [(1e-6, False), (3.0, True)])
def test_a_linear_rival_at_the_same_pose_keeps_the_family_chain(monkeypatch, offset_sigma, rival_wins):
    """The family chain against the linear start's adjustment: at the same pose (below RIVAL_SAME_SIGMA) the chain's
    result stays whichever fits better by round-off, and the comparison ends; a distinct, better rival replaces it."""
    from solver.refinement import RefinementResult, TrackSet

    T = sample_camera_pose(np.random.default_rng(8))
    cov = np.diag([1e-6] * 3 + [1e-6] * 3)  # 1 mrad, 1 mm
    tracks = TrackSet(np.zeros((4, 2)), np.zeros(4, dtype=np.int64), np.tile(np.eye(3), (4, 1, 1)),
                      np.zeros((1, 3)), np.zeros(1, dtype=np.int64), np.array([600.0, 600.0]))

    def result(T_pose, rms):
        return RefinementResult(T_pose, cov, np.zeros((1, 3)), np.ones(1, dtype=bool), rms, rms)

    moved = T.copy()
    moved[:3, 3] += offset_sigma * 1e-3 * np.array([1.0, 0.0, 0.0])
    chain, rival = result(T, 0.50), result(moved, 0.40)  # the rival fits better
    cal = Calibrator(K, PANDA.axis_and_point)
    cal._refined, cal._from_family = chain, True
    starts = iter([chain, rival])
    monkeypatch.setattr(cal, "_refine_checked", lambda *args: (next(starts), "", True))
    monkeypatch.setattr(cal, "_warm_points", lambda live: None)
    monkeypatch.setattr(cal, "_store_batch", lambda live, tracks, refined: None)
    kept, why, ran = cal._rival_linear(tracks, [0], moved)
    assert kept is (rival if rival_wins else chain) and why == "" and ran
    assert not cal._from_family  # either way the linear start was tried: the chain is an ordinary one from now on


#: Spheres of this radius (m) on the arm's joints (2-7) stand in for its links in the outline stage's tests.
SPHERE_RADIUS = 0.06
#: Noise of the synthetic edge points, px.
EDGE_NOISE_PX = 0.2


def _sphere_contours(T, q):
    """The occluding circles of spheres on joints 2-7 of the Panda at q (n,), seen from T (``ContourRenderer``)."""
    return sphere_contour(T, [(tuple(PANDA.axis_and_point(q, j)[1]), SPHERE_RADIUS) for j in range(1, 7)])


def _sphere_edges(T_true, q, rng) -> OutlineImage:
    """An image's edges: the spheres' true outlines through the true camera, with noise."""
    contour = _sphere_contours(T_true, q)
    cam = contour.points_base @ T_true[:3, :3].T + T_true[:3, 3]
    px = pixels_from_camera_points(cam, K) + rng.normal(0.0, EDGE_NOISE_PX, (len(cam), 2))
    return OutlineImage(ImageEdges(px, -contour.outward), q, 0)


def _outline_episode(seed, n, config=None):
    """(tracks alone, tracks and outlines, T_true) after n noisy synthetic motions with two outline images each."""
    rng = np.random.default_rng(seed)
    T = sample_camera_pose(rng)
    scene = SyntheticScene(PANDA, K, T, SyntheticConfig(noise_px=0.5, outlier_fraction=0.1, tracks_per_motion=30), rng)
    alone = Calibrator(K, PANDA.axis_and_point)
    joint = Calibrator(K, PANDA.axis_and_point, config, contours=_sphere_contours)
    for _ in range(n):
        motion = scene.random_motion(rng)
        images = _motion_images(T, motion, rng)
        alone.add_motion(motion.observation, outlines=images)  # no contour renderer: ignored
        joint.add_motion(motion.observation, outlines=images)
    return alone, joint, T


def _motion_images(T_true, motion, rng) -> list[OutlineImage]:
    """A synthetic motion's two outline images: at its start and its end."""
    obs = motion.observation
    images = []
    for delta in (0.0, motion.delta):
        q = obs.q_start.copy()
        q[obs.joint] += delta
        images.append(_sphere_edges(T_true, q, rng))
    return images


def test_the_outlines_join_the_tracks_pose():
    alone, joint, T = _outline_episode(5, 8)
    s = joint.state
    assert alone.outlines is None and alone.state.outline is None and alone.state.outline_note == ""
    assert s.outline is not None and s.outline_note == "" and s.outline.n_groups == 8
    assert np.array_equal(s.T_camera_base, s.outline.T_camera_base) and np.array_equal(s.covariance,
                                                                                       s.outline.covariance)
    assert np.all(s.std[3:] < alone.state.std[3:])  # the outlines add information
    xi = pose_difference(s.T_camera_base, T)
    assert xi @ np.linalg.solve(s.covariance, xi) < CHI2_6_999
    assert s.seconds["outlines"] > 0


def _biased_tracks_update(sigmas, config=None, biased=1, placed=None, widen=1.0):
    """An outline episode of 8 motions, then ``biased`` more whose tracks' pose is moved ``sigmas`` of its 1-sigma
    along the camera's x (a narrow covariance where the pose went: the tracks' on as-shipped castings). (calibrator,
    T_true, the tracks' pose of the last update, the state after the 8th). ``placed``: whether the chain is taken
    for one the outlines placed alone (``Calibrator._outlines_placed``) from the 8th on. ``widen``: the biased
    updates' tracks' covariance is taken this many times (weak tracks beside the outlines)."""
    rng = np.random.default_rng(5)
    T = sample_camera_pose(rng)
    scene = SyntheticScene(PANDA, K, T, SyntheticConfig(noise_px=0.5, outlier_fraction=0.1, tracks_per_motion=30), rng)
    cal = Calibrator(K, PANDA.axis_and_point, config, contours=_sphere_contours)
    for _ in range(8):
        motion = scene.random_motion(rng)
        cal.add_motion(motion.observation, outlines=_motion_images(T, motion, rng))
    before = cal.state
    assert before.outline is not None
    if placed is not None:
        cal._outlines_placed = placed
    biased_poses: list[np.ndarray] = []
    weak = cal._without_weak_motions

    def moved(refined):
        refined = weak(refined)
        refined = replace(refined, covariance=widen * refined.covariance)
        xi = np.zeros(6)
        xi[3] = sigmas * np.sqrt(refined.covariance[3, 3])
        if widen != 1.0:  # ``sigmas`` from the pose in its covariance's metric (along a principal direction)
            xi = sigmas * np.linalg.cholesky(refined.covariance)[:, 3]
        biased_poses.append(perturb(refined.T_camera_base, xi))
        return replace(refined, T_camera_base=biased_poses[-1])

    cal._without_weak_motions = moved
    for _ in range(biased):
        motion = scene.random_motion(rng)
        cal.add_motion(motion.observation, outlines=_motion_images(T, motion, rng))
    return cal, T, biased_poses[-1], before


def test_outlines_that_agreed_hold_the_pose_when_the_tracks_pose_goes_astray():
    cal, T, tracks_pose, before = _biased_tracks_update(10.0)
    s = cal.state
    assert s.outline is not None and s.outline.prior_scale > 1.0 and s.outline_note == "", s.outline_note
    assert not s.converged  # the tracks disagree: not a pose to stop at
    assert np.array_equal(s.T_camera_base, s.outline.T_camera_base)
    xi = pose_difference(s.T_camera_base, T)
    assert xi @ np.linalg.solve(s.covariance, xi) < CHI2_6_999
    assert pose_errors(s.T_camera_base, T)[1] < 0.3 * pose_errors(tracks_pose, T)[1]
    # off: the tracks' pose alone, and why
    off, _, off_tracks, _ = _biased_tracks_update(10.0, CalibratorConfig(hold_outlines=False))
    assert off.state.outline is None and off.state.outline_note.startswith("OutlineDisagreementError")
    np.testing.assert_array_equal(off.state.T_camera_base, off_tracks)


def test_outlines_hold_the_pose_for_a_few_updates_in_a_row_only():
    from solver.pipeline import HOLD_MAX_UPDATES

    held, _, _, _ = _biased_tracks_update(10.0, biased=HOLD_MAX_UPDATES)
    assert held.state.outline is not None and held.state.outline.prior_scale > 1.0
    cal, _, tracks_pose, _ = _biased_tracks_update(10.0, biased=HOLD_MAX_UPDATES + 1)
    assert cal.state.outline is None and cal.state.outline_note.startswith("OutlineDisagreementError")
    np.testing.assert_array_equal(cal.state.T_camera_base, tracks_pose)


@pytest.mark.parametrize("sigmas", [5.5, 10.0])
def test_holds_that_widen_weak_tracks_a_little_do_not_count_towards_the_limit(sigmas):
    """Weak tracks (their covariance 100x) whose pose sits 5.5 of its 1-sigma from the truth need their covariance
    about 2.4x to agree with the outlines: such holds (at most ``HOLD_FREE_SCALE``) go on past ``HOLD_MAX_UPDATES``
    (seen: an as-shipped xArm 6 held 1 mm off at scale 2, then the tracks' pose alone 26-33 mm off). At 10 sigma the
    scale exceeds it and the hold ends after ``HOLD_MAX_UPDATES`` as before."""
    from solver.pipeline import HOLD_FREE_SCALE, HOLD_MAX_UPDATES

    cal, T, tracks_pose, _ = _biased_tracks_update(sigmas, biased=HOLD_MAX_UPDATES + 2, widen=100.0)
    s = cal.state
    if sigmas < 6:
        assert s.outline is not None and 1.0 < s.outline.prior_scale <= HOLD_FREE_SCALE and not s.converged
        assert cal._held_updates == 0 and s.outline_note == ""
        rot, trans = pose_errors(s.T_camera_base, T)
        assert rot < NOISY_ROT and trans < NOISY_TRANS
        xi = pose_difference(s.T_camera_base, T)
        assert xi @ np.linalg.solve(s.covariance, xi) < CHI2_6_999
    else:
        assert s.outline is None and s.outline_note.startswith("OutlineDisagreementError")
        np.testing.assert_array_equal(s.T_camera_base, tracks_pose)
        held, _, _, _ = _biased_tracks_update(sigmas, biased=1, widen=100.0)
        assert held.state.outline is not None and held.state.outline.prior_scale > HOLD_FREE_SCALE


@pytest.mark.parametrize("sigmas", [10.0, 1000.0])
def test_outlines_hold_a_pose_they_placed_alone_past_the_limit(sigmas):
    """In a chain the outlines began alone (a rescue), tracks' poses that disagree with them beyond the hold's limit
    (more updates, or too far) leave the outlines alone from the last pose: that pose, near the truth, never
    converged. (In a chain the tracks began, the tracks' pose as before: the test above.)"""
    from solver.pipeline import HOLD_MAX_UPDATES

    cal, T, tracks_pose, _ = _biased_tracks_update(sigmas, biased=HOLD_MAX_UPDATES + 2, placed=True)
    s = cal.state
    assert s.outline is not None and s.outline.prior_scale == 1.0 and s.outline_note == "" and not s.converged
    np.testing.assert_array_equal(s.T_camera_base, s.outline.T_camera_base)
    rot, trans = pose_errors(s.T_camera_base, T)
    assert rot < NOISY_ROT and trans < NOISY_TRANS and cal._outlines_placed


def test_outlines_do_not_hold_a_pose_the_tracks_left_by_too_far():
    cal, _, tracks_pose, _ = _biased_tracks_update(1000.0)
    s = cal.state
    assert s.outline is None and s.outline_note.startswith("OutlineDisagreementError") and "not held" in s.outline_note
    np.testing.assert_array_equal(s.T_camera_base, tracks_pose)


def test_too_few_outline_motions_leave_the_tracks_pose():
    config = CalibratorConfig(outlines=OutlineFusionConfig(min_groups=20))
    alone, joint, _ = _outline_episode(5, 6, config)
    assert joint.state.outline is None and "from 6 motion(s)" in joint.state.outline_note
    assert np.array_equal(joint.state.T_camera_base, alone.state.T_camera_base)


def test_the_outlines_fix_the_depth_the_shoulder_joints_leave_free():
    """Joints 1-3 alone turn the arm about one point: the tracks fit every depth, the outlines (spheres) fix it."""
    rng = np.random.default_rng(3)
    T = sample_camera_pose(rng)
    scene = SyntheticScene(PANDA, K, T, SyntheticConfig(noise_px=0.3, outlier_fraction=0.1, tracks_per_motion=30), rng)
    alone = Calibrator(K, PANDA.axis_and_point)
    joint = Calibrator(K, PANDA.axis_and_point, contours=_sphere_contours)
    for _ in range(4):
        motion = scene.random_motion(rng, joints=(0, 1, 2))
        images = _motion_images(T, motion, rng)
        alone.add_motion(motion.observation, outlines=images)
        joint.add_motion(motion.observation, outlines=images)
    assert alone.state.T_camera_base is None  # the tracks alone: no pose
    s = joint.state
    assert (s.stage, s.start, s.converged) == ("refined", "outlines", False), s.outline_note
    assert s.outline is not None and s.outline.n_groups == 4
    rot, trans = pose_errors(s.T_camera_base, T)
    assert rot < NOISY_ROT and trans < NOISY_TRANS
    xi = pose_difference(s.T_camera_base, T)
    assert xi @ np.linalg.solve(s.covariance, xi) < CHI2_6_999


@pytest.mark.parametrize("mismatch", [False, True])
@pytest.mark.parametrize("start", ["family", "linear"])
def test_a_first_pose_the_outlines_cannot_fit_is_refused(monkeypatch, mismatch, start):
    """The first pose comes from the family (two axes) or the linear calibration (every motion's axis). Outlines
    that fit near it keep it (true spheres' edges); outlines that cannot be fitted near it (``OutlineMismatchError``,
    as a wrong branch gives) refuse it: it is neither reported nor chained from, and the message says why."""
    if start == "family":
        _stage_one_for(monkeypatch, 2)
    source = "the two-axis pose family" if start == "family" else "the linear calibration"
    rng = np.random.default_rng(1)
    T = sample_camera_pose(rng)
    scene = SyntheticScene(PANDA, K, T, SyntheticConfig(noise_px=0.5, outlier_fraction=0.1, tracks_per_motion=20),
                           rng)
    cal = Calibrator(K, PANDA.axis_and_point, CalibratorConfig(rigid_axis=None, family_start=True, one_axis=None),
                     contours=_sphere_contours)  # (one axis and the outlines would give a pose before the family)
    if mismatch:
        def loose(*args, **kwargs):
            raise OutlineMismatchError("from 3 motions the outlines fit their edges too loosely")

        monkeypatch.setattr(cal.outlines, "fuse", loose)
    starts, refusals = [], 0
    for _ in range(5 if start == "family" else 8):
        motion = scene.random_motion(rng)
        cal.add_motion(motion.observation, outlines=_motion_images(T, motion, rng))
        s = cal.state
        starts.append(s.start)
        refusals += f"the first pose, from {source}, is refused by the robot's outlines" in s.message
    if mismatch:
        assert refusals > 0 and start not in starts and not cal._from_family and cal._refined is None
    else:
        assert refusals == 0 and start in starts and s.stage == "refined" and s.outline is not None
        rot, trans = pose_errors(s.T_camera_base, T)
        assert rot < NOISY_ROT and trans < NOISY_TRANS


@pytest.mark.parametrize("refuse", [True, False])
@pytest.mark.parametrize("kind", ["disagree", "refuted", "unjudged"])
def test_a_first_pose_the_outlines_refute_is_refused(monkeypatch, kind, refuse):
    """A first pose (the linear calibration's) that the outlines disagree with, or that is too wide for them and whose
    search along its weakest direction refutes it (``_rescue_from``'s verdict, made here; its own test is below), is
    refused with ``refuse_refuted`` (seen: an as-shipped iiwa's family start 296 mm off at a 1-sigma of 34 mm):
    neither reported nor chained from. Without it, or when the search could not judge the pose either, the pose is the
    tracks' and the note says why."""
    rng = np.random.default_rng(1)
    T = sample_camera_pose(rng)
    scene = SyntheticScene(PANDA, K, T, SyntheticConfig(noise_px=0.5, outlier_fraction=0.1, tracks_per_motion=20),
                           rng)
    cal = Calibrator(K, PANDA.axis_and_point, CalibratorConfig(rigid_axis=None, one_axis=None, mask_start=None,
                                                               refuse_refuted=refuse), contours=_sphere_contours)

    def judged(*args, **kwargs):
        if kind == "disagree":
            raise OutlineDisagreementError("the outlines disagree with the tracks (made to, by the test)", 99.0)
        raise OutlineReachError("the tracks' pose is too uncertain for the outlines (made to, by the test)")

    monkeypatch.setattr(cal.outlines, "fuse", judged)
    monkeypatch.setattr(cal, "_rescue_from", lambda *args: (None, "the search's verdict (made)", kind == "refuted"))
    refusals, starts = 0, []
    for _ in range(6):
        motion = scene.random_motion(rng)
        cal.add_motion(motion.observation, outlines=_motion_images(T, motion, rng))
        s = cal.state
        starts.append(s.start)
        refusals += "the first pose, from the linear calibration, is refused by the robot's outlines" in s.message
    said = "the outlines disagree" if kind == "disagree" else "searched along the tracks' weakest direction"
    if refuse and kind != "unjudged":
        assert refusals > 0 and "linear" not in starts and "previous" not in starts and cal._refined is None
        assert s.T_camera_base is None and said in s.message
    else:
        assert refusals == 0 and "linear" in starts and s.stage == "refined" and s.outline is None
        assert s.outline_note.startswith("OutlineDisagreementError" if kind == "disagree" else "OutlineReachError")
        assert said in s.outline_note


def _shoulder_rescue(rng_seed=3, motions=4, contours=_sphere_contours):
    """A calibrator fed ``motions`` noisy motions of joints 1-3 alone (the tracks leave the depth free) with outline
    images of the joint spheres, and T_true; and the scene and generator to make more motions. Without the one-axis
    search (its own tests are above): the rescue's notes are its own."""
    rng = np.random.default_rng(rng_seed)
    T = sample_camera_pose(rng)
    scene = SyntheticScene(PANDA, K, T, SyntheticConfig(noise_px=0.3, outlier_fraction=0.1, tracks_per_motion=30), rng)
    cal = Calibrator(K, PANDA.axis_and_point, CalibratorConfig(one_axis=None), contours=contours)
    for _ in range(motions):
        motion = scene.random_motion(rng, joints=(0, 1, 2))
        cal.add_motion(motion.observation, outlines=_motion_images(T, motion, rng))
    return cal, T, scene, rng


@pytest.mark.parametrize("outcome", ["fits", "mismatch", "disagree", "loose", "reach"])
def test_the_rescue_from_a_start_says_whether_the_outlines_refute_it(monkeypatch, outcome):
    """``_rescue_from``'s verdict: refuted when its search ran and the outlines fit their edges loosely at its best pose
    (the fusion's mismatch, or the rescue's own residual-scale test) or their pose disagreed with the tracks' there;
    not when the outlines could not judge (a reach failure) nor when they fit."""
    cal, T, scene, rng = _shoulder_rescue()
    tracks = cal._track_set(list(range(len(cal._motions))))
    joints = np.array([m.point_base for m in cal._motions])
    real = OutlineAdjustment.fuse

    def fuse(self, *args, **kwargs):
        if outcome == "mismatch":
            raise OutlineMismatchError("from 4 motions the outlines fit their edges too loosely (made)")
        if outcome == "disagree":
            raise OutlineDisagreementError("the outlines disagree with the tracks (made)", 99.0)
        if outcome == "reach":
            raise OutlineReachError("the tracks' pose is too uncertain for the outlines (made)")
        fused = real(self, *args, **kwargs)
        return replace(fused, sigma_px=3.0) if outcome == "loose" else fused

    monkeypatch.setattr(OutlineAdjustment, "fuse", fuse)
    fused, why, refuted = cal._rescue_from(cal.state.T_camera_base, list(range(len(cal._motions))), joints, tracks)
    assert refuted == (outcome in ("mismatch", "disagree", "loose"))
    if outcome == "fits":
        assert fused is not None and why == ""
        assert pose_errors(fused.T_camera_base, T)[1] < NOISY_TRANS
    else:
        assert fused is None and why.startswith("the outlines could not fix what the tracks leave free")


def test_a_rescued_pose_starts_the_next_rescue():
    """An update that rescued the pose with the outlines hands it to the next update's rescue as its first start
    (a fresh start may land on another branch), and the next rescue holds the truth as well."""
    cal, T, scene, rng = _shoulder_rescue()
    assert cal.state.start == "outlines"
    rescued = cal.state.T_camera_base.copy()
    starts = []
    real = cal._rescue_from

    def spy(start, *args):
        starts.append(start.copy())
        return real(start, *args)

    cal._rescue_from = spy
    motion = scene.random_motion(rng, joints=(0, 1, 2))
    cal.add_motion(motion.observation, outlines=_motion_images(T, motion, rng))
    s = cal.state
    assert starts and np.array_equal(starts[0], rescued)
    assert s.start == "outlines" and len(starts) == 1  # the first start served
    rot, trans = pose_errors(s.T_camera_base, T)
    assert rot < NOISY_ROT and trans < NOISY_TRANS


@pytest.mark.parametrize("search", [True, False])
def test_one_axis_searched_with_the_tracks_and_the_outlines_gives_a_first_pose(monkeypatch, search):
    """Only the first motion gives an axis: no linear calibration, no pose family; the other motions carry tracks
    and every motion outline images (the joints' spheres). The poses that one axis allows, searched with every
    motion's tracks and then the outlines, give a first pose near the truth on the outlines' tests; without the
    search there is none, and the message says why."""
    _stage_one_for(monkeypatch, 1)
    rng = np.random.default_rng(4)
    T = sample_camera_pose(rng)
    scene = SyntheticScene(PANDA, K, T, SyntheticConfig(noise_px=0.5, outlier_fraction=0.1, tracks_per_motion=30),
                           rng)
    cal = Calibrator(K, PANDA.axis_and_point, CalibratorConfig(rigid_axis=None, one_axis=OneAxisSearch() if search
                                                               else None), contours=_sphere_contours)
    for _ in range(3):  # the outlines' rescue needs three motions' images
        motion = scene.random_motion(rng)
        cal.add_motion(motion.observation, outlines=_motion_images(T, motion, rng))
    s = cal.state
    assert sum(cal.motion_geometry(k) is not None for k in range(3)) == 1
    if search:
        assert s.T_camera_base is not None and s.start == "outlines" and not s.converged, s.message
        rot, trans = pose_errors(s.T_camera_base, T)
        assert rot < NOISY_ROT and trans < NOISY_TRANS
        chi2 = pose_difference(s.T_camera_base, T) @ np.linalg.solve(s.covariance, pose_difference(s.T_camera_base, T))
        assert chi2 < 22.46  # its covariance holds the truth (chi-square, 6 dof, 0.999)
    else:
        assert s.T_camera_base is None and "1 motion(s) with an axis" in s.message


@pytest.mark.parametrize("weak_share", [0.15, None])
def test_a_weak_axis_is_searched_when_no_motion_has_an_axis(monkeypatch, weak_share):
    """No motion gives an axis: the first motion's rigid fit is made to need every track (1 in 10 is an outlier), the
    others' fail. The fit the most tracks followed (``NonRigidTracksError.fit``) is the weak axis: the one-axis search
    from it gives a first pose near the truth on the outlines' tests; with ``weak_share`` None there is none."""
    real = pipeline.rigid_axis_of_motion
    fits = []

    def first_weak(obs, intrinsics, config, *args, **kwargs):
        fits.append(len(fits))
        if len(fits) > 1:
            raise DegenerateMotionError("stage one switched off by the test")
        return real(obs, intrinsics, replace(config, min_inlier_fraction=1.0), *args, **kwargs)

    monkeypatch.setattr(pipeline, "rigid_axis_of_motion", first_weak)
    _stage_one_for(monkeypatch, 0)
    rng = np.random.default_rng(4)
    T = sample_camera_pose(rng)
    scene = SyntheticScene(PANDA, K, T, SyntheticConfig(noise_px=0.5, outlier_fraction=0.1, tracks_per_motion=30),
                           rng)
    cal = Calibrator(K, PANDA.axis_and_point, CalibratorConfig(one_axis=OneAxisSearch(weak_share=weak_share)),
                     contours=_sphere_contours)
    for _ in range(3):
        motion = scene.random_motion(rng)
        cal.add_motion(motion.observation, outlines=_motion_images(T, motion, rng))
    s = cal.state
    assert all(cal.motion_geometry(k) is None for k in range(3)) and "tracks move rigidly" in cal.reports[0].rigid
    if weak_share is None:
        assert s.T_camera_base is None and "0 motion(s) with an axis" in s.message
        return
    assert s.T_camera_base is not None and s.start == "outlines" and not s.converged, s.message
    rot, trans = pose_errors(s.T_camera_base, T)
    assert rot < NOISY_ROT and trans < NOISY_TRANS
    chi2 = pose_difference(s.T_camera_base, T) @ np.linalg.solve(s.covariance, pose_difference(s.T_camera_base, T))
    assert chi2 < 22.46  # its covariance holds the truth (chi-square, 6 dof, 0.999)


def test_one_axis_is_searched_a_few_times_only(monkeypatch):
    """A search that finds nothing (made to, here) is tried from the same axis at most ``max_tries`` updates: the
    three from motion 3, when the outlines have three motions' images; then the message says so."""
    _stage_one_for(monkeypatch, 1)
    calls = []

    def nothing(*args, **kwargs):
        calls.append(len(args[0].pivot))
        raise InsufficientMotionsError("no member of the one-axis family sees the tracks or the outlines")

    monkeypatch.setattr(pipeline, "search_one_axis", nothing)
    rng = np.random.default_rng(4)
    T = sample_camera_pose(rng)
    scene = SyntheticScene(PANDA, K, T, SyntheticConfig(noise_px=0.5, tracks_per_motion=20), rng)
    cal = Calibrator(K, PANDA.axis_and_point, CalibratorConfig(rigid_axis=None), contours=_sphere_contours)
    notes = []
    for _ in range(6):
        motion = scene.random_motion(rng)
        cal.add_motion(motion.observation, outlines=_motion_images(T, motion, rng))
        notes.append(cal.state.outline_note)
    assert len(calls) == 3 and cal.state.T_camera_base is None
    assert all("no member of the one-axis family" in note for note in notes[2:5])
    assert notes[5] == "no start from one motion's axis: searched 3 times from each axis or 6 in all"


def test_a_rescue_whose_outlines_fit_loosely_gives_no_pose(monkeypatch):
    """However many motions, a rescued pose needs outlines that fit their edges (residual scale at most
    ``max_early_sigma_px``): the fusion is made to report 3 px, and the rescue says so instead of a pose."""
    real = OutlineAdjustment.fuse

    def loose(self, *args, **kwargs):
        return replace(real(self, *args, **kwargs), sigma_px=3.0)

    monkeypatch.setattr(OutlineAdjustment, "fuse", loose)
    cal, _, _, _ = _shoulder_rescue()
    s = cal.state
    assert s.T_camera_base is None and s.start == ""
    assert "they fit their edges too loosely there (residual scale 3.00 px, at most 1)" in s.outline_note


def test_a_first_pose_whose_outlines_fit_loosely_is_refused_at_any_count(monkeypatch):
    """From six motions on the fusion itself no longer refuses a loose fit, the calibrator does; a first pose (linear)
    is then refused (seen: a family start 347 mm off fused at motion 6, 1-sigma 0.6 mm)."""
    real = OutlineAdjustment.fuse

    def loose(self, *args, **kwargs):
        return replace(real(self, *args, **kwargs), sigma_px=3.0)

    monkeypatch.setattr(OutlineAdjustment, "fuse", loose)
    rng = np.random.default_rng(1)
    T = sample_camera_pose(rng)
    scene = SyntheticScene(PANDA, K, T, SyntheticConfig(noise_px=0.5, outlier_fraction=0.1, tracks_per_motion=20),
                           rng)
    cal = Calibrator(K, PANDA.axis_and_point, CalibratorConfig(rigid_axis=None, one_axis=None),
                     contours=_sphere_contours)  # (the one-axis search, failing alike, would only cost time)
    messages = []
    for _ in range(8):
        motion = scene.random_motion(rng)
        cal.add_motion(motion.observation, outlines=_motion_images(T, motion, rng))
        messages.append(cal.state.message)
    s = cal.state
    assert s.T_camera_base is None and cal._refined is None and cal.outlines.n_groups >= 6
    assert "too loosely (residual scale 3.00 px, at most 1)" in messages[-1]
    assert "the first pose, from the linear calibration, is refused by the robot's outlines" in messages[-1]


def test_a_later_fusion_whose_outlines_fit_loosely_is_refused(monkeypatch):
    """After the outlines have fused with the tracks' pose, an update whose outlines fit their edges loosely (made to
    report 3 px) keeps the tracks' pose alone and says why: a loose fit is a pairing with other edges, however many
    motions (seen: 21 mm off with a 1-sigma of 0.5 mm at 2.81 px)."""
    rng = np.random.default_rng(1)
    T = sample_camera_pose(rng)
    scene = SyntheticScene(PANDA, K, T, SyntheticConfig(noise_px=0.5, tracks_per_motion=20), rng)
    cal = Calibrator(K, PANDA.axis_and_point, CalibratorConfig(rigid_axis=None, one_axis=None),
                     contours=_sphere_contours)
    for _ in range(7):
        motion = scene.random_motion(rng)
        cal.add_motion(motion.observation, outlines=_motion_images(T, motion, rng))
    assert cal.state.outline is not None and cal.outlines.n_groups >= 6
    real = OutlineAdjustment.fuse
    monkeypatch.setattr(OutlineAdjustment, "fuse", lambda self, *a, **k: replace(real(self, *a, **k), sigma_px=3.0))
    motion = scene.random_motion(rng)
    cal.add_motion(motion.observation, outlines=_motion_images(T, motion, rng))
    s = cal.state
    assert s.outline is None and s.stage == "refined" and not s.converged
    np.testing.assert_allclose(s.T_camera_base, cal._refined.T_camera_base)
    assert "too loosely (residual scale 3.00 px, at most 1)" in s.outline_note


@pytest.mark.parametrize("apart", [True, False])
def test_after_a_rescue_a_first_pose_the_outlines_do_not_vouch_for_is_refused_when_apart(apart):
    """The outlines rescued the pose (joints 1-3 alone); then motions of every joint give the tracks a first pose of
    their own (their adjustment from the rescued pose), which the outlines (made to, here) do not vouch for. When it
    lies outside the rescued pose's region (the rescued pose moved 0.3 m here) it is refused and the rescue goes on;
    inside it, it is the estimate."""
    cal, T, scene, rng = _shoulder_rescue()
    assert cal.state.start == "outlines"

    def disagree(refined):
        return None, InsufficientMotionsError("the outlines cannot judge the tracks' pose (made to, by the test)")

    cal._fuse_outlines = disagree
    refusals, starts = 0, []
    for _ in range(3):
        if apart and cal.state.start == "outlines":  # each rescued pose, as the next update sees it
            moved = perturb(cal.state.T_camera_base, np.array([0, 0, 0, 0.3, 0, 0]))
            cal.state = replace(cal.state, T_camera_base=moved)
        motion = scene.random_motion(rng)
        cal.add_motion(motion.observation, outlines=_motion_images(T, motion, rng))
        refusals += "is refused by the robot's outlines: the outlines cannot judge" in cal.state.message
        starts.append(cal.state.start)
    if apart:
        assert refusals > 0 and cal._refined is None and set(starts) <= {"outlines", ""}
    else:
        assert refusals == 0 and cal._refined is not None and "previous" in starts
        rot, trans = pose_errors(cal.state.T_camera_base, T)
        assert rot < NOISY_ROT and trans < NOISY_TRANS


def test_after_a_rescue_the_tracks_adjustment_starts_from_the_rescued_pose():
    """The update after a rescue adjusts the tracks from the rescued pose (which fit the edges), not from the linear
    pose or the family; the outlines then pair from there by its covariance (the tracks' own may still be too wide:
    ``OutlineAdjustment.fuse``'s ``start_covariance``), and the fused pose holds the truth."""
    cal, T, scene, rng = _shoulder_rescue()
    assert cal.state.start == "outlines"
    rescued = cal.state.T_camera_base.copy()
    starts = []
    real = cal._refine_checked

    def spy(tracks, start, points):
        starts.append(start.copy())
        return real(tracks, start, points)

    cal._refine_checked = spy
    for _ in range(4):
        motion = scene.random_motion(rng)
        cal.add_motion(motion.observation, outlines=_motion_images(T, motion, rng))
        if cal._refined is not None:
            break
    s = cal.state
    assert starts and np.array_equal(starts[0], rescued)
    assert cal._refined is not None and s.start == "previous" and s.outline is not None, (s.message, s.outline_note)
    rot, trans = pose_errors(s.T_camera_base, T)
    assert rot < NOISY_ROT and trans < NOISY_TRANS
    xi = pose_difference(s.T_camera_base, T)
    assert xi @ np.linalg.solve(s.covariance, xi) < CHI2_6_999


def test_when_the_rescue_along_one_direction_fails_the_rescued_pose_is_rescued_again(monkeypatch):
    """After a rescue, an update whose one-direction rescue (``_rescue_from``) fails from every start (the tracks
    it keeps leave more than one direction free) is rescued from the last rescued pose with every direction held
    weakly (``_rescue_near``): a pose that holds the truth, not none."""
    cal, T, scene, rng = _shoulder_rescue()
    assert cal.state.start == "outlines"

    def failing(start, *args):
        return None, "the outlines could not fix what the tracks leave free: forced by the test", False

    near = []
    real_near = cal._rescue_near

    def spy(start, tracks):
        near.append(start.copy())
        return real_near(start, tracks)

    monkeypatch.setattr(cal, "_rescue_from", failing)
    monkeypatch.setattr(cal, "_rescue_near", spy)
    rescued = cal.state.T_camera_base.copy()
    motion = scene.random_motion(rng, joints=(0, 1, 2))
    cal.add_motion(motion.observation, outlines=_motion_images(T, motion, rng))
    s = cal.state
    assert len(near) == 1 and np.array_equal(near[0], rescued)
    assert (s.stage, s.start, s.converged) == ("refined", "outlines", False), (s.message, s.outline_note)
    rot, trans = pose_errors(s.T_camera_base, T)
    assert rot < NOISY_ROT and trans < NOISY_TRANS
    xi = pose_difference(s.T_camera_base, T)
    assert xi @ np.linalg.solve(s.covariance, xi) < CHI2_6_999


def test_the_rescue_near_the_rescued_pose_fixes_what_one_joint_leaves_free():
    """One joint's motions alone leave several directions of the pose free: the adjustment held along the weakest
    one has singular equations, the one held weakly in every direction (``_rescue_near``) does not, and with the
    outlines it gives a pose that holds the truth."""
    cal, T, scene, rng = _shoulder_rescue()
    assert cal.state.start == "outlines"
    saved = cal.state
    rescued = saved.T_camera_base.copy()
    first = len(cal._motions)
    for _ in range(2):
        motion = scene.random_motion(rng, joints=(0,))
        cal.add_motion(motion.observation, outlines=_motion_images(T, motion, rng))
    own = [k for k in range(first, len(cal._motions)) if cal._motions[k] is not None]
    assert len(own) == 2
    tracks = cal._track_set(own)
    ratio, weakest = pipeline.track_observability(tracks, rescued)
    assert ratio < 1e-6
    with pytest.raises((np.linalg.LinAlgError, InvalidInputError)):
        pipeline.refine(tracks, rescued, cal.config.refinement, free_direction=weakest)
    cal.state = saved  # the rescued pose and its covariance, as the update after the rescue sees them
    fused, why = cal._rescue_near(rescued, tracks)
    assert fused is not None, why
    rot, trans = pose_errors(fused.T_camera_base, T)
    assert rot < NOISY_ROT and trans < NOISY_TRANS
    xi = pose_difference(fused.T_camera_base, T)
    assert xi @ np.linalg.solve(fused.covariance, xi) < CHI2_6_999


def test_a_tracks_pose_too_wide_for_the_outlines_is_rescued_along_its_weakest_direction():
    """A tracks' pose whose 1-sigma moves the contour points further than ``max_prior_px`` (here a tight 0.5 px, so
    that six noisy motions are too few) is not fused: with ``rescue_wide`` the outlines search its weakest direction
    and adjust from there with the wider ``max_rescue_prior_px``; the rescued pose holds the truth, closer than the
    tracks' own. Off, or with a rescue reach too tight even along the rest, the tracks' pose stays and the note says
    why."""
    tight = OutlineFusionConfig(max_prior_px=0.5)
    _, off, T = _outline_episode(5, 6, CalibratorConfig(rescue_wide=False, outlines=tight))
    assert off.state.outline is None and off.state.outline_note.startswith("OutlineReachError")
    tracks_rot, tracks_trans = pose_errors(off.state.T_camera_base, T)
    _, on, _ = _outline_episode(5, 6, CalibratorConfig(outlines=tight))
    s = on.state
    assert s.outline is not None and s.outline_note == "" and s.stage == "refined" and s.start != "outlines"
    rot, trans = pose_errors(s.T_camera_base, T)
    assert rot < NOISY_ROT and trans < NOISY_TRANS and trans < tracks_trans / 3
    xi = pose_difference(s.T_camera_base, T)
    assert xi @ np.linalg.solve(s.covariance, xi) < CHI2_6_999
    _, refused, _ = _outline_episode(5, 6, CalibratorConfig(outlines=replace(tight, max_rescue_prior_px=0.01)))
    note = refused.state.outline_note
    assert refused.state.outline is None and note.startswith("OutlineReachError")
    assert "searched along the tracks' weakest direction" in note
    np.testing.assert_array_equal(refused.state.T_camera_base, off.state.T_camera_base)


@pytest.mark.parametrize("fits_better", [True, False])
def test_after_a_wide_rescue_the_tracks_chain_goes_on_from_the_rescued_pose_when_it_fits_them_better(monkeypatch,
                                                                                                        fits_better):
    """After the rescue of a wide tracks' pose the tracks are adjusted again from the rescued pose; that adjustment
    (here its RMS made lower or higher than the first's, its pose the real one) replaces the tracks' chain only when
    it fits them at least as well, and the outlines are then adjusted with it as their prior."""
    tight = CalibratorConfig(outlines=OutlineFusionConfig(max_prior_px=0.5))
    real_refine, real_rescue = Calibrator._refine_checked, Calibrator._rescue_wide
    from_rescue, inside, chains = [], [], []

    def rescue_wide(self, refined, *args):
        inside.append(refined)
        try:
            fused, failure, chain = real_rescue(self, refined, *args)
        finally:
            inside.pop()
        if fused is not None:
            chains.append((chain is refined, bool(from_rescue) and chain is from_rescue[-1]))
        return fused, failure, chain

    def refine_checked(self, tracks, start, points_init):
        result, why, ran = real_refine(self, tracks, start, points_init)
        if result is not None and inside:  # the adjustment again from the rescued pose
            result = replace(result, rms_px=inside[-1].rms_px * (0.9 if fits_better else 1.1))
            from_rescue.append(result)
        return result, why, ran

    monkeypatch.setattr(Calibrator, "_rescue_wide", rescue_wide)
    monkeypatch.setattr(Calibrator, "_refine_checked", refine_checked)
    _, cal, T = _outline_episode(5, 6, tight)
    s = cal.state
    assert from_rescue and chains and s.outline is not None
    assert chains == [(not fits_better, fits_better)] * len(chains)
    rot, trans = pose_errors(s.T_camera_base, T)
    assert rot < NOISY_ROT and trans < NOISY_TRANS
