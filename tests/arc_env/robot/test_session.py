"""The one calibration loop: refusals leave the robot where it is, drivers' bad answers are named errors."""

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from arc_env.robot.driver import Sweep
from arc_env.robot.model import RobotModel, RobotSource
from arc_env.robot.recording import RecordedMotion
from arc_env.robot.session import CalibrationSession, DriverExecutor, track_recorded
from solver.errors import InvalidInputError
from solver.observations import CameraIntrinsics

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

    def fake_calibrate(recording, tracker=None, config=None, on_motion=None, observer=None):
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
