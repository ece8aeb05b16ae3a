"""The driver protocol: the simulator implements it; ``arc-calib run`` drives it and records the sweeps.

At 320x180 the speckle is sub-pixel and tracking finds little, so the run here checks the plumbing
(motions executed through the driver, joint readings turned into Q/J/delta, a readable recording,
no result from too little evidence), not accuracy: the round trip tests measure that.
"""

import numpy as np
import pytest

from arc_env.cli import main
from arc_env.robot.driver import RobotDriver
from arc_env.robot.recording import read_recording
from arc_env.robot.session import driver_session
from arc_env.sim.driver import SimulatedDriver


def small_driver():
    return SimulatedDriver(width=320, height=180, seed=2, fps=8.0)  # few frames: plumbing, not accuracy


@pytest.fixture(scope="module")
def driver():
    d = small_driver()
    yield d
    d.close()


def test_simulated_driver_implements_the_protocol(driver):
    assert isinstance(driver, RobotDriver)
    lower, upper = driver.joint_limits
    assert lower.shape == upper.shape == (len(driver.joint_names),) and np.all(lower < upper)
    q = np.clip(driver.scene.robot.home, lower, upper)
    driver.move_to(q)
    sweep = driver.sweep(3, 0.4)
    assert len(sweep.frames) >= 3 and sweep.frames[0].shape == (180, 320, 3)
    assert sweep.positions.shape == (len(sweep.frames), len(driver.joint_names))
    np.testing.assert_allclose(sweep.positions[-1, 3] - sweep.positions[0, 3], 0.4)
    others = np.delete(sweep.positions, 3, axis=1)
    np.testing.assert_array_equal(others, np.tile(np.delete(q, 3), (len(sweep.frames), 1)))


class _Narrow(SimulatedDriver):
    """Tighter limits than the model's on joint 0."""

    @property
    def joint_limits(self):
        lower, upper = super().joint_limits
        lower[0], upper[0] = -0.5, 0.5
        return lower, upper


def test_driver_session_intersects_limits_and_uses_the_driver_camera():
    d = _Narrow(width=320, height=180, seed=1)
    try:
        session = driver_session(d)
        assert session.robot.lower[0] == -0.5 and session.robot.upper[0] == 0.5
        session.reset(np.random.default_rng(0))
        assert session.calibrator.intrinsics is d.intrinsics
        q = session.robot.home.copy()
        q[0] = 0.9
        assert "outside the limits" in session.refusal_reason(q, 1, 0.5)
        assert session.renderer is None  # a real robot's session renders nothing
    finally:
        d.close()


def test_run_drives_the_robot_records_and_refuses_too_little_evidence(tmp_path, capsys):
    out = tmp_path / "result.json"
    rec = tmp_path / "rec"
    code = main(["run", "--driver", "tests.arc_env.cli.test_run:small_driver", "--motions", "3",
                 "--output", str(out), "--record", str(rec), "--all-motions"])
    captured = capsys.readouterr()
    assert code == 1, captured.out + captured.err
    assert "no usable calibration" in captured.out and not out.exists()
    recording = read_recording(rec)
    assert len(recording.motions) == 3 and all(m.joint is not None for m in recording.motions)


def test_run_with_a_bad_driver_spec(tmp_path, capsys):
    assert main(["run", "--driver", "no_such_module:X", "--output", str(tmp_path / "r.json")]) == 2
    assert "cannot load it" in capsys.readouterr().err
    assert main(["run", "--driver", "numpy:ndarray", "--output", str(tmp_path / "r.json")]) == 2
    assert "constructing it failed" in capsys.readouterr().err
    assert main(["run", "--driver", "collections:OrderedDict", "--output", str(tmp_path / "r.json")]) == 2
    assert "not a RobotDriver" in capsys.readouterr().err


def test_run_with_the_informed_planner_drives_the_robot(tmp_path, capsys):
    rec = tmp_path / "rec"
    code = main(["run", "--driver", "tests.arc_env.cli.test_run:small_driver", "--planner", "informed",
                 "--motions", "3", "--output", str(tmp_path / "result.json"), "--record", str(rec), "--all-motions"])
    captured = capsys.readouterr()
    assert code == 1, captured.out + captured.err  # 320x180 is too small to calibrate; the plumbing runs
    motions = read_recording(rec).motions
    assert len(motions) == 3 and all(m.joint is not None for m in motions)


def test_the_informed_planner_plans_without_a_renderer():
    from planners.informed import InformedPlanner

    d = small_driver()
    try:
        session = driver_session(d)
        session.reset(np.random.default_rng(0))
        planner = InformedPlanner(session, np.random.default_rng(0))  # image tests on by default: skipped
        action = planner.plan({"has_estimate": 0})
        assert not session.refusal_reason(action["Q"], int(action["J"]), float(action["delta"][0]))
    finally:
        d.close()


class _FailsOnFourthSweep(SimulatedDriver):
    """A driver that breaks (e.g. a protective stop) during its fourth sweep."""

    def __init__(self):
        super().__init__(width=320, height=180, seed=2, fps=8.0)

    def sweep(self, joint, delta):
        if self.n_sweeps == 3:
            raise RuntimeError("protective stop")
        return super().sweep(joint, delta)


@pytest.mark.parametrize("overlap", [[], ["--overlap"]], ids=["serial", "overlap"])
def test_a_driver_failure_keeps_the_motions_done_and_resume_continues(tmp_path, capsys, overlap):
    rec, out = tmp_path / "rec", tmp_path / "result.json"
    code = main(["run", "--driver", "tests.arc_env.cli.test_run:_FailsOnFourthSweep", "--motions", "6",
                 "--output", str(out), "--record", str(rec), "--all-motions", "--quiet"] + overlap)
    err = capsys.readouterr().err
    assert code == 1 and "motion 3 failed" in err and "protective stop" in err and "Traceback" not in err
    assert f"--resume {rec}" in err and not out.exists()
    kept = read_recording(rec)
    assert len(kept.motions) == 3  # the three finished sweeps; the failed one is not half-written
    before = {p: p.read_bytes() for p in rec.rglob("*") if p.is_file()}
    rec2 = tmp_path / "rec2"
    code = main(["run", "--driver", "tests.arc_env.cli.test_run:small_driver", "--motions", "5", "--resume", str(rec),
                 "--output", str(out), "--record", str(rec2), "--all-motions", "--quiet"] + overlap)
    captured = capsys.readouterr()
    assert code in (0, 1) and "Traceback" not in captured.err, captured.err
    assert {p: p.read_bytes() for p in rec.rglob("*") if p.is_file()} == before  # the resumed input untouched
    resumed = read_recording(rec2)
    assert len(resumed.motions) == 5  # the three resumed, then two new
    for old, new in zip(kept.motions, resumed.motions[:3], strict=True):
        np.testing.assert_array_equal(old.q_start, new.q_start)
        assert old.joint == new.joint


def test_resume_refuses_writing_into_the_resumed_recording(tmp_path, capsys):
    rec = tmp_path / "rec"
    assert main(["run", "--driver", "tests.arc_env.cli.test_run:small_driver", "--motions", "3",
                 "--output", str(tmp_path / "r.json"), "--record", str(rec), "--all-motions", "--quiet"]) == 1
    capsys.readouterr()
    assert main(["run", "--driver", "tests.arc_env.cli.test_run:small_driver", "--resume", str(rec),
                 "--output", str(rec / "result.json")]) == 2
    assert "is inside the input" in capsys.readouterr().err


def medium_driver():
    return SimulatedDriver(width=640, height=360, seed=2, fps=10.0)  # enough pixels for tracks to differ by motion


def test_run_with_overlap_reports_every_motion_as_without(tmp_path, capsys):
    """--overlap: the same motions, each diagnostic on its own row (joint, frames, tracks, verdict), plus waited.

    No estimate forms in these 5 motions, so the random planner (which tests visibility only against an
    estimate) chooses the same motions with the estimate one motion late.
    """
    tables = {}
    for flag in ([], ["--overlap"]):
        code = main(["run", "--driver", "tests.arc_env.cli.test_run:medium_driver", "--motions", "5", "--all-motions",
                     "--quiet", "--output", str(tmp_path / f"r{len(flag)}.json")] + flag)
        out = capsys.readouterr().out
        rows = [line for line in out.splitlines() if line.strip()[:3].isdigit()]
        tables[bool(flag)] = (code, rows, out)
    (code_off, rows_off, out_off), (code_on, rows_on, out_on) = tables[False], tables[True]
    assert len(rows_off) == 5 and code_on == code_off
    assert rows_on == rows_off, out_on
    assert len({row.split()[3] for row in rows_off}) > 1  # the tracks differ by motion: a mismatch would show
    assert "waited" in out_on and "waited" not in out_off
