"""The one calibration loop: refusals leave the robot where it is, drivers' bad answers are named errors."""

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from arc_env.robot.driver import Sweep
from arc_env.robot.model import RobotModel, RobotSource
from arc_env.robot.recording import RecordedMotion
from arc_env.robot.session import (
    CalibrationSession,
    DriverExecutor,
    UsableCriteria,
    state_unusable_reason,
    track_recorded,
)
from solver.errors import InvalidInputError
from solver.observations import CameraIntrinsics
from solver.pipeline import CalibrationState

CAMERA = CameraIntrinsics.from_fov(200.0, 320, 240)


class _BadDriver:
    """A driver whose sweep returns joint readings of the wrong shape."""

    robot = RobotSource()
    joint_names = tuple(f"panda0_joint{i}" for i in range(1, 8))
    intrinsics = CAMERA
    joint_limits = (np.full(7, -3.0), np.full(7, 3.0))

    def __init__(self):
        self.moved_to = None

    def move_to(self, q):
        self.moved_to = np.asarray(q)

    def sweep(self, joint, delta):
        frames = [np.zeros((240, 320, 3), np.uint8)] * 4
        return Sweep(frames, np.zeros((4, 6)))  # 6 joints, not 7


@pytest.fixture(scope="module")
def robot():
    return RobotModel.load(RobotSource())


def test_a_refused_motion_leaves_the_robot_unmoved_and_is_counted(robot):
    driver = _BadDriver()
    session = CalibrationSession(robot, CAMERA, DriverExecutor(driver))
    session.reset(np.random.default_rng(0))
    before = robot.q
    q = robot.home.copy()
    q[0] = robot.upper[0] + 0.5
    result = session.step(q, 1, 0.5)
    assert "outside the limits" in result.refused and session.n_refused == 1 and session.n_motions == 0
    assert driver.moved_to is None and session.executed == []
    np.testing.assert_array_equal(robot.q, before)
    assert "below the minimum" in session.step(robot.home, 1, 0.05).refused


def test_a_malformed_sweep_is_a_named_error(robot):
    session = CalibrationSession(robot, CAMERA, DriverExecutor(_BadDriver()))
    session.reset(np.random.default_rng(0))
    q = robot.home.copy()
    with pytest.raises(InvalidInputError, match=r"driver sweep must return >= 3 frames and finite positions"):
        session.step(q, 3, 0.4)


def test_a_session_without_executor_only_observes(robot):
    session = CalibrationSession(robot, CAMERA)
    with pytest.raises(InvalidInputError, match="reset"):
        session.step(robot.home, 3, 0.4)
    session.reset()
    with pytest.raises(InvalidInputError, match="no executor"):
        session.step(robot.home, 3, 0.4)
    outcome = session.observe(robot.home, 3, [])
    assert outcome.report is not None and not outcome.accepted


def test_recorded_tracks_carry_the_joint_velocity_of_their_frames(robot):
    rng = np.random.default_rng(0)
    texture = cv2.GaussianBlur(rng.uniform(0, 255, (60, 60)).astype(np.uint8), (0, 0), 1.5)
    n = 12
    frames = []
    for k in range(n):  # a textured patch sliding 4 px per frame over a plain background
        image = np.full((240, 320, 3), 90, np.uint8)
        image[90:150, 60 + 4 * k:120 + 4 * k] = texture[:, :, None]
        frames.append(image)
    delta = np.linspace(0.0, 0.5, n) ** 1.5  # increasing: a track's deltas name its frames
    velocity = np.gradient(delta) * 30.0
    motion = RecordedMotion(0, "000", Path("."), n, (), None, np.zeros(7), 1, delta, "", np.arange(n) / 30.0,
                            velocity)
    session = CalibrationSession(robot, CAMERA)
    session.reset()
    tracks = track_recorded(session, frames, motion)
    plain = session.track(frames, delta)
    assert len(tracks) == len(plain) > 0
    for track, same in zip(tracks, plain, strict=True):
        assert np.array_equal(track.pixels, same.pixels) and np.array_equal(track.delta, same.delta)
        np.testing.assert_array_equal(track.velocity, velocity[np.searchsorted(delta, track.delta)])
    assert all(t.velocity is None for t in track_recorded(session, frames, replace(motion, joint_velocity=None)))


def test_the_joints_are_read_again_at_the_corrected_time_offset(monkeypatch):
    """A first-order estimate that recovers 80 % of the remaining offset each pass: read again until it is small."""
    from types import SimpleNamespace

    from arc_env.robot import session as session_module

    true_offset, reads = 0.020, []

    def fake_calibrate(recording, tracker=None, config=None, on_motion=None, observer=None, outline_frames=0):
        remaining = true_offset - recording.time_offset_s
        state = SimpleNamespace(time_offset_s=0.8 * remaining, time_offset_std_s=0.0002)
        return SimpleNamespace(calibrator=SimpleNamespace(state=state), recording=recording)

    def read(offset):
        reads.append(offset)
        return SimpleNamespace(time_offset_s=offset)

    monkeypatch.setattr(session_module, "calibrate_recording", fake_calibrate)
    run = session_module.calibrate_reading_offset(read, 0.0)
    # passes read at 0, 16 and 19.2 ms; the third one corrects by 0.64 ms, below 1 ms: no fourth
    np.testing.assert_allclose(reads, [0.0, 0.016, 0.0192], atol=1e-12)
    assert run.recording.time_offset_s == pytest.approx(0.0192)
    reads.clear()
    session_module.calibrate_reading_offset(read, 0.0, max_passes=1)
    assert reads == [0.0]
    with pytest.raises(InvalidInputError, match="max_passes"):
        session_module.calibrate_reading_offset(read, 0.0, max_passes=0)
    # no estimate (format 1 recordings, or the estimate off): one pass
    monkeypatch.setattr(session_module, "calibrate_recording", lambda recording, *a, **k: SimpleNamespace(
        calibrator=SimpleNamespace(state=SimpleNamespace(time_offset_s=None, time_offset_std_s=None))))
    reads.clear()
    session_module.calibrate_reading_offset(read, 0.005)
    assert reads == [0.005]


# -- overlap: the robot executes motion k+1 while a worker tracks and calibrates motion k ----------------
OVERLAP_CAMERA = CameraIntrinsics.from_fov(500.0, 640, 480)
#: A fixed list of exploratory motions from the Panda's home (Q offsets, joint, delta): all valid, varied axes.
OVERLAP_MOTIONS = (((0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0), 0, 0.8), ((0.3, -0.2, 0.0, 0.0, 0.0, 0.0, 0.0), 1, 0.5),
                   ((0.0, 0.0, 0.0, 0.3, 0.0, 0.0, 0.0), 2, -0.7), ((0.5, 0.0, 0.0, 0.0, 0.0, 0.3, 0.0), 3, 0.6),
                   ((-0.4, 0.2, 0.0, 0.0, 0.0, 0.0, 0.0), 4, 0.9), ((0.0, 0.0, 0.3, 0.0, 0.0, 0.0, 0.0), 5, -0.6))


class _ProjectingExecutor:
    """Executes a motion by projecting the moving links' mesh points through a fixed camera (no rendering).

    Its noise comes from its own generator, drawn on the thread that executes (as the simulator's); the
    frames it hands on are tiny blank images so that a session tracks them (``track`` is replaced in
    these tests by a lookup of the projected tracks), or None (``oracle``: the tracks come with them).
    """

    def __init__(self, robot, oracle=True, seed=0, sleep_s=0.0):
        from solver.synthetic import sample_camera_pose

        self.robot = robot
        self.oracle = oracle
        self.rng = np.random.default_rng(seed)
        self.T_camera_base = sample_camera_pose(np.random.default_rng(seed + 1), target=np.array([0.3, 0.0, 0.45]),
                                                distance=(1.4, 1.6))
        self.sleep_s = sleep_s
        self.by_frames: dict[int, list] = {}  # id of a frame list -> its tracks
        self.threads: list[str] = []
        self.before_return = None  # called at the end of each execute (a test's hook)

    def execute(self, q, joint, delta):
        import threading
        import time

        from arc_env.robot.session import Acquisition
        from solver.observations import KeypointTrack

        self.threads.append(threading.current_thread().name)
        deltas = np.linspace(0.0, delta, 12)
        body, local = self.robot.surface_points(joint)
        pick = self.rng.choice(len(body), size=min(60, len(body)), replace=False)
        pix = np.empty((len(deltas), len(pick), 2))
        ok = np.empty((len(deltas), len(pick)), bool)
        for k, d in enumerate(deltas):
            self.robot.set_swept(q, joint, d)
            uv, ok[k] = self.robot.project_points(body[pick], local[pick], self.T_camera_base, OVERLAP_CAMERA, 0.05)
            pix[k] = uv + self.rng.normal(0.0, 0.3, uv.shape)
        tracks = [KeypointTrack(pix[ok[:, p], p], deltas[ok[:, p]]) for p in range(len(pick)) if ok[:, p].sum() >= 3]
        time.sleep(self.sleep_s)
        if self.before_return is not None:
            self.before_return()
        q_end = q.copy()
        q_end[joint] += delta
        if self.oracle:
            return Acquisition(q, q_end, deltas, tracks=tracks, seconds={"render": 0.0})
        frames = [np.zeros((4, 4, 3), np.uint8) for _ in deltas]
        self.by_frames[id(frames)] = tracks
        return Acquisition(q, q_end, deltas, frames=frames, seconds={"render": 0.0})


def _overlap_session(robot, overlap, oracle=True, seed=0, sleep_s=0.0):
    from arc_env.robot.session import SessionConfig

    executor = _ProjectingExecutor(robot, oracle, seed, sleep_s)
    session = CalibrationSession(robot, OVERLAP_CAMERA, executor, SessionConfig(overlap=overlap))
    if not oracle:
        session.track = lambda frames, deltas, velocities=None: executor.by_frames[id(frames)]
    session.reset(np.random.default_rng(seed))
    return session, executor


def _motion(robot, k):
    offsets, joint, delta = OVERLAP_MOTIONS[k]
    return robot.home + np.asarray(offsets), joint, delta


def _estimates(session, robot, n):
    """T_camera_base (or None) after each processed motion, by motion index; the results, in order."""
    estimates, results = {}, []
    for k in range(n):
        results.append(session.step(*_motion(robot, k)))
        assert not results[-1].refused, results[-1].refused
        if results[-1].index is not None:
            estimates[results[-1].index] = session.calibrator.state.T_camera_base
    flushed = session.flush()
    if flushed is not None:
        results.append(flushed)
        estimates[flushed.index] = session.calibrator.state.T_camera_base
    return estimates, results


def test_overlap_gives_the_calibrator_the_same_motions_and_estimates(robot):
    """Same actions, overlap on and off: the estimate after every motion is the same, bit for bit."""
    n = len(OVERLAP_MOTIONS)
    off, _ = _overlap_session(robot, False)  # each reset puts the shared robot at home: run one after the other
    before_off, results_off = _estimates(off, robot, n)
    on, _ = _overlap_session(robot, True)
    before_on, results_on = _estimates(on, robot, n)
    assert sorted(before_off) == sorted(before_on) == list(range(n))
    assert before_on[n - 1] is not None  # the test means something: the motions gave an estimate
    for k in range(n):
        if before_off[k] is None:
            assert before_on[k] is None
        else:
            np.testing.assert_array_equal(before_on[k], before_off[k])
    # the outcomes match motion for motion (the overlapped results are lagged by one, the first pending)
    assert [r.index for r in results_off] == list(range(n)) and not any(r.pending for r in results_off)
    assert results_on[0].pending and results_on[0].motion is None and results_on[0].index is None
    assert [r.index for r in results_on[1:]] == list(range(n))
    for a, b in zip(results_off, results_on[1:], strict=True):
        assert a.motion.as_info() == b.motion.as_info() and a.n_frames == b.n_frames
        assert a.transit.length_rad == b.transit.length_rad
    assert on.executed and [e[1] for e in on.executed] == [e[1] for e in off.executed]
    assert on.n_motions == off.n_motions == n and on.flush() is None


def test_overlap_tracks_on_a_worker_while_the_next_motion_executes(robot):
    """Tracking motion 0 happens during motion 1's execution, on another thread; the observer runs in order.

    Each side waits for the other to have begun (a handshake): done one after the other, a wait times out.
    """
    import threading

    session, executor = _overlap_session(robot, True, oracle=False)
    executing, tracking = threading.Event(), threading.Event()
    track_threads, seen, met = [], [], []
    lookup = session.track

    def track(frames, deltas, velocities=None):
        track_threads.append(threading.current_thread().name)
        tracking.set()
        met.append(("tracking saw the execution", executing.wait(timeout=5.0)))
        return lookup(frames, deltas, velocities)

    session.track = track
    session.observer = lambda m: seen.append((m.index, threading.current_thread().name,
                                              len(m.calibrator.reports)))
    first = session.step(*_motion(robot, 0))
    assert first.pending and not tracking.is_set() and session.pending

    def meet():
        executing.set()
        met.append(("the execution saw tracking", tracking.wait(timeout=5.0)))

    executor.before_return = meet
    second = session.step(*_motion(robot, 1))
    assert sorted(met) == [("the execution saw tracking", True), ("tracking saw the execution", True)]
    assert second.index == 0 and second.motion is not None and second.seconds["waited"] >= 0.0
    main = threading.current_thread().name
    assert executor.threads == [main, main] and track_threads and track_threads[0] != main
    executor.before_return = None
    flushed = session.flush()
    assert flushed.index == 1 and not session.pending
    assert seen == [(0, main, 1), (1, main, 2)]  # on the calling thread, in order, each after its own update


@pytest.mark.parametrize("execute_s", [0.6, 0.0], ids=["slow-robot", "fast-robot"])
def test_waited_is_the_time_the_robot_stood_idle(robot, execute_s):
    """0.3 s of tracking: hidden by a 0.6 s execution (little waited), or waited for entirely after a fast one."""
    import time

    track_s = 0.3
    session, _ = _overlap_session(robot, True, oracle=False, sleep_s=execute_s)
    lookup = session.track

    def slow_track(frames, deltas, velocities=None):
        time.sleep(track_s)
        return lookup(frames, deltas, velocities)

    session.track = slow_track
    assert session.step(*_motion(robot, 0)).seconds == {"waited": 0.0}
    result = session.step(*_motion(robot, 1))
    assert result.index == 0 and result.seconds["tracking"] >= track_s
    if execute_s > track_s:
        assert result.seconds["waited"] < track_s / 2
    else:
        assert result.seconds["waited"] >= track_s
    flushed = session.flush()
    assert flushed.index == 1 and flushed.seconds["waited"] >= flushed.seconds["tracking"] >= track_s


def test_refusals_keep_the_pending_motion_and_reset_drops_it(robot):
    session, _ = _overlap_session(robot, True)
    assert session.step(*_motion(robot, 0)).pending
    refused = session.step(robot.home, 1, 0.05)
    assert "below the minimum" in refused.refused and session.pending and session.n_refused == 1
    result = session.step(*_motion(robot, 1))
    assert result.index == 0 and result.motion.n_tracks > 0
    with pytest.raises(InvalidInputError, match="flush"):
        session.replay(robot.home, 0, np.linspace(0, 0.5, 5), [])
    session.reset(np.random.default_rng(0))
    assert not session.pending and session.flush() is None and session.n_motions == 0
    assert session.calibrator.reports == []
    assert session.step(*_motion(robot, 0)).pending  # a fresh start: the first step is pending again
    assert session.flush().index == 0 and len(session.calibrator.reports) == 1


@pytest.mark.parametrize("overlap", [False, True], ids=["off", "on"])
def test_an_error_while_processing_surfaces_from_step_or_flush(robot, overlap):
    session, _ = _overlap_session(robot, overlap, oracle=False)
    lookup = session.track

    def failing_track(frames, deltas, velocities=None):
        if len(session.calibrator.reports) == 1:
            raise RuntimeError("tracker broke on the second motion")
        return lookup(frames, deltas, velocities)

    session.track = failing_track
    session.step(*_motion(robot, 0))
    # without overlap the second motion's own step raises; with it, the step after it (or flush)
    if overlap:
        assert session.step(*_motion(robot, 1)).index == 0
    with pytest.raises(RuntimeError, match="tracker broke on the second motion"):
        session.step(*_motion(robot, 2 if overlap else 1))
    assert session.pending == overlap  # overlapped, motion 2 was executed and waits
    if overlap:  # the last motion's processing fails in flush
        session.reset(np.random.default_rng(0))
        session.step(*_motion(robot, 0))
        assert session.step(*_motion(robot, 1)).index == 0
        with pytest.raises(RuntimeError, match="tracker broke on the second motion"):
            session.flush()
        assert not session.pending


def test_a_failed_execution_finishes_the_motion_in_processing(robot):
    session, executor = _overlap_session(robot, True)
    seen = []
    session.observer = lambda m: seen.append(m.index)
    session.step(*_motion(robot, 0))
    executor.before_return = lambda: (_ for _ in ()).throw(OSError("the arm stopped"))
    with pytest.raises(OSError, match="the arm stopped"):
        session.step(*_motion(robot, 1))
    assert seen == [0] and len(session.calibrator.reports) == 1 and not session.pending


def test_the_kinematics_give_the_same_answers_from_several_threads(robot):
    """``axis_and_point`` shares one MjData between callers: under a lock, threads never mix their states."""
    import sys
    import threading

    rng = np.random.default_rng(0)
    qs = [rng.uniform(robot.lower, robot.upper) for _ in range(300)]
    expected = [robot.axis_and_point(q, 3) for q in qs]
    mismatches = []

    def work(order):
        for _ in range(5):
            for i in order:
                axis, point = robot.axis_and_point(qs[i], 3)
                if not (np.array_equal(axis, expected[i][0]) and np.array_equal(point, expected[i][1])):
                    mismatches.append(i)

    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)  # switch threads as often as possible: without the lock this mixes states
    try:
        threads = [threading.Thread(target=work, args=(list(range(300))[::step],)) for step in (1, -1, 1, -1)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    finally:
        sys.setswitchinterval(interval)
    assert mismatches == []


@pytest.mark.parametrize("overlap", [False, True], ids=["serial", "overlap"])
def test_outline_frames_reach_the_calibrator_with_their_configurations(robot, overlap):
    from arc_env.robot.session import SessionConfig

    executor = _ProjectingExecutor(robot, oracle=False)
    session = CalibrationSession(robot, OVERLAP_CAMERA, executor, SessionConfig(overlap=overlap, outline_frames=3))
    session.track = lambda frames, deltas, velocities=None: executor.by_frames[id(frames)]
    session.reset(np.random.default_rng(0))
    for k in range(3):
        session.step(*_motion(robot, k))
    session.flush()
    images = session.calibrator.outlines.images
    assert len(images) == 9 and [im.group for im in images] == [0, 0, 0, 1, 1, 1, 2, 2, 2]
    for k in range(3):
        q, joint, delta = _motion(robot, k)
        for im, frac in zip(images[3 * k:3 * k + 3], (0.0, 6 / 11, 1.0), strict=True):  # frames 0, 6, 11 of 12
            expected = q.copy()
            expected[joint] += frac * delta
            np.testing.assert_allclose(im.q, expected, atol=1e-12)
    with pytest.raises(InvalidInputError, match="outline_frames"):
        SessionConfig(outline_frames=-1)


def test_the_unusable_reason_of_a_rescued_pose_says_what_it_rests_on():
    std = np.full(6, 1e-4)
    state = CalibrationState(np.eye(4), "refined", None, np.diag(std**2), std, None, False, 0, 3, None, "",
                             start="outlines")
    why = state_unusable_reason(state, 0, UsableCriteria())
    assert "outlines" in why and "inform the estimate" not in why
    ordinary = replace(state, start="linear")
    assert state_unusable_reason(ordinary, 0, UsableCriteria()) == "only 0 motion(s) inform the estimate (need 4)"
    assert state_unusable_reason(ordinary, 4, UsableCriteria()) == ""
