"""``arc-calib plan`` -> the simulator replays the trajectory (``record --trajectory``) -> ``calibrate`` the bag.

The end-to-end case is small (3 motions at 480x270, 15 Hz, faster joints than the defaults): it checks the
script's shape, its collision-freedom against the planner's checker with the obstacles, that the links stay
in the real camera's image when planned with a rough guess, that segmentation of the recorded joint stream
finds exactly the planned sweeps, and that calibrate runs and reports (too few tracks at this size for a
pose; the README gives a 960x540 run's accuracy).
"""

import csv
import json

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from arc_env.bench.poses import benchmark_camera_pose
from arc_env.cli import main
from arc_env.robot.bag import read_bag
from arc_env.robot.model import RobotModel, RobotSource
from arc_env.robot.motion_script import (
    SEGMENT_DELTA_TOL,
    read_camera_pose,
    read_trajectory,
    trajectory_positions,
)
from arc_env.robot.obstacles import Obstacle, read_obstacles
from arc_env.robot.recording import read_recording
from arc_env.sim.record import BAG_EPOCH_S
from planners.collision import CollisionChecker
from solver.errors import InvalidInputError
from solver.frames import perturb, pose_errors
from solver.observations import CameraIntrinsics

WIDTH, HEIGHT = 480, 270
#: s: a segment starts (stops) at most half the 0.1 s window plus a 200 Hz sample away from the planned turn,
#: plus the part of the cubic's slow start (end) under the 2 mrad rest threshold (< 0.1 s at these speeds).
EDGE_TOL = 0.05 + 0.005 + 0.1
#: The fraction of the moving links' points in the true image at both ends of each sweep: the planner asked
#: for 0.7 (20 px inside the border) under a guess 2-4 degrees and 5 cm off.
MIN_IN_TRUE_VIEW = 0.5
OBSTACLES = """\
- {type: box, size: [0.3, 0.3, 0.6], pos: [0.6, 0.5, 0.3]}
- {radius: 0.15, pos: [-0.5, -0.5, 0.8], name: lamp}
- {type: box, half_size: [0.05, 0.05, 0.2], pos: [0.0, 0.7, 0.5], quat: [0, 0, 0.3826834, 0.9238795]}
"""


def camera_info_yaml(intrinsics: CameraIntrinsics) -> str:
    return yaml.safe_dump({"image_width": intrinsics.width, "image_height": intrinsics.height,
                           "camera_matrix": {"rows": 3, "cols": 3, "data": intrinsics.K.ravel().tolist()},
                           "distortion_model": "plumb_bob",
                           "distortion_coefficients": {"rows": 1, "cols": 5, "data": [0.0] * 5}})


@pytest.fixture(scope="module")
def e2e(tmp_path_factory):
    d = tmp_path_factory.mktemp("plan")
    T_true = benchmark_camera_pose(0)
    guess = perturb(T_true, np.array([0.03, -0.02, 0.02, 0.05, -0.04, 0.03]))  # ~2.4 deg, 7 cm
    (d / "camera_true.json").write_text(json.dumps({"T_camera_base": T_true.tolist()}))
    (d / "guess.yaml").write_text(yaml.safe_dump({"translation": guess[:3, 3].tolist(),
                                                   "quaternion_xyzw": Rotation.from_matrix(guess[:3, :3]).as_quat()
                                                   .tolist()}))
    intrinsics = CameraIntrinsics.from_fov(1380.0 * WIDTH / 1920, WIDTH, HEIGHT)
    (d / "camera.yaml").write_text(camera_info_yaml(intrinsics))
    (d / "obstacles.yaml").write_text(OBSTACLES)
    out = d / "motions.yaml"
    assert main(["plan", "--motions", "3", "--seed", "1", "--camera-info", str(d / "camera.yaml"),
                 "--camera-pose-guess", str(d / "guess.yaml"), "--obstacles", str(d / "obstacles.yaml"),
                 "--max-speed", "1.0", "--sweep-speed", "0.8", "--max-accel", "2", "--output", str(out)]) == 0
    bag = d / "bag"
    assert main(["record", "--trajectory", str(out), "--camera-pose", str(d / "camera_true.json"), "--format",
                 "mcap", "--width", str(WIDTH), "--height", str(HEIGHT), "--fps", "15", "--out", str(bag)]) == 0
    return d, out, bag, T_true, intrinsics


def test_the_trajectory_is_a_joint_trajectory_with_increasing_times_and_the_csv_agrees(e2e):
    _, out, _, _, _ = e2e
    msg = yaml.safe_load(out.read_text())
    assert list(msg) == ["header", "joint_names", "points"]
    assert msg["header"] == {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": ""}
    assert msg["joint_names"] == RobotModel.load(RobotSource()).joint_names
    n = len(msg["joint_names"])
    times = []
    for p in msg["points"]:
        assert set(p) == {"positions", "velocities", "time_from_start"}
        assert len(p["positions"]) == n and p["velocities"] == [0.0] * n
        stamp = p["time_from_start"]
        assert set(stamp) == {"sec", "nanosec"} and all(type(v) is int for v in stamp.values())
        assert 0 <= stamp["nanosec"] < 10**9
        times.append(stamp["sec"] + stamp["nanosec"] * 1e-9)
    assert times[0] == 0.0 and np.all(np.diff(times) > 0)
    with out.with_suffix(".csv").open(newline="") as f:
        rows = list(csv.reader(f))
    assert rows[0] == ["t", *msg["joint_names"]]
    table = np.array(rows[1:], dtype=float)
    np.testing.assert_allclose(table[:, 0], times, atol=1e-9)
    np.testing.assert_array_equal(table[:, 1:], [p["positions"] for p in msg["points"]])


def test_every_waypoint_and_segment_is_collision_free_with_the_obstacles(e2e):
    d, out, _, _, _ = e2e
    robot = RobotModel.load(RobotSource(), obstacles=read_obstacles(d / "obstacles.yaml"))
    checker = CollisionChecker(robot.model, robot.arm_joints, qpos_ref=robot.data.qpos.copy())
    assert sum("arc_obstacle_" in robot.model.geom(g).name for g in range(robot.model.ngeom)) == 3
    points = read_trajectory(out).positions
    for k, q in enumerate(points):
        assert not checker.in_collision(q)[0], f"point {k}"
        assert np.all(q >= robot.lower - 1e-9) and np.all(q <= robot.upper + 1e-9)
    for k, (a, b) in enumerate(zip(points[:-1], points[1:], strict=True)):
        free, why = checker.path_free(a, b, 0.005)
        assert free, f"segment {k}: {why}"


def test_the_moving_links_are_in_the_true_image_though_planned_with_a_guess(e2e):
    d, out, _, T_true, intrinsics = e2e
    sweeps = yaml.safe_load(out.with_name("motions.sweeps.yaml").read_text())
    assert sweeps["view_check"].startswith("moving links") and sweeps["obstacles"] == 3
    robot = RobotModel.load(RobotSource())
    rot, trans = pose_errors(read_camera_pose(d / "guess.yaml"), T_true)
    assert 0.02 < rot < 0.1 and 0.03 < trans < 0.1  # the guess is rough indeed
    for s in sweeps["sweeps"]:
        body, local = robot.surface_points(s["joint_index"])
        for turn in (0.0, s["delta"]):
            robot.set_swept(np.asarray(s["Q"]), s["joint_index"], turn)
            _, visible = robot.project_points(body, local, T_true, intrinsics, min_depth=0.1)
            assert visible.mean() >= MIN_IN_TRUE_VIEW


def test_segmentation_of_the_recorded_bag_finds_the_planned_sweeps(e2e):
    _, out, bag, _, _ = e2e
    truth = json.loads(bag.with_name("bag.ground_truth.json").read_text())
    planned = yaml.safe_load(out.with_name("motions.sweeps.yaml").read_text())["sweeps"]
    rec = read_bag(bag, truth["robot_model"], truth["base_body"])
    assert len(rec.segments) == len(planned) == 3
    assert all("joints move" in s.reason for s in rec.skipped) and len(rec.skipped) >= 3  # the transits
    for m, seg, p in zip(rec.motions, rec.segments, planned, strict=True):
        assert rec.joint_names[m.joint] == p["joint"] and not m.pruned
        assert seg.delta == pytest.approx(p["delta"], abs=SEGMENT_DELTA_TOL)
        start, stop = (BAG_EPOCH_S + p[k] for k in ("t_start", "t_stop"))
        assert abs(seg.t_start - start) <= EDGE_TOL and abs(seg.t_stop - stop) <= EDGE_TOL


def test_calibrate_runs_on_the_replayed_bag_and_reports(e2e, tmp_path, capsys):
    _, _, bag, _, _ = e2e
    truth = json.loads(bag.with_name("bag.ground_truth.json").read_text())
    result = tmp_path / "r.json"
    code = main(["calibrate", str(bag), "--robot", truth["robot_model"], "--base-body", truth["base_body"],
                 "--output", str(result), "--quiet"])
    err = capsys.readouterr().err
    assert "Traceback" not in err and "3 exploratory motion(s) found in /joint_states" in err
    assert code in (0, 1)
    if code == 0:
        assert json.loads(result.read_text())["usable"] is True
    elif result.exists():  # an estimate that is not usable is written as such, without the ROS exports
        assert json.loads(result.read_text())["usable"] is False
        assert not [p for p in tmp_path.iterdir() if p.suffix in (".calib", ".sh", ".urdf", ".xacro", ".py")]


def test_a_replayed_trajectory_without_velocities_becomes_a_recording_directory(tmp_path):
    names = RobotModel.load(RobotSource()).joint_names
    home = [0.0, -0.5, 0.0, -2.0, 0.0, 1.5, 0.0]
    turned = list(home)
    turned[5] += 0.6
    points = [(0.0, home), (0.5, home), (1.5, turned), (2.0, turned)]
    traj = {"joint_names": names[::-1],  # any order: matched by name
            "points": [{"positions": q[::-1], "time_from_start": {"sec": int(t), "nanosec": int(t % 1 * 1e9)}}
                       for t, q in points]}
    (tmp_path / "t.yaml").write_text(yaml.safe_dump(traj))
    out = tmp_path / "rec"
    assert main(["record", "--trajectory", str(tmp_path / "t.yaml"), "--format", "dir", "--width", "64",
                 "--height", "48", "--fps", "20", "--out", str(out)]) == 0
    rec = read_recording(out, min_motions=1)
    assert len(rec.motions) == 1 and names[rec.motions[0].joint] == names[5]
    # linear motion at 0.6 rad/s: frames every 50 ms along the turn, the segment spans it to within a window
    assert np.ptp(rec.motions[0].delta) == pytest.approx(0.6, abs=0.03)
    assert rec.motions[0].n_frames == pytest.approx(20, abs=3)


# -- the parts ---------------------------------------------------------------------------------------------
def test_trajectory_positions_stop_at_every_point_and_keep_to_the_straight_segment():
    times = np.array([0.0, 1.0, 3.0])
    positions = np.array([[0.0, 0.0], [1.0, 2.0], [1.0, -1.0]])
    t = np.linspace(-0.5, 3.5, 801)
    q = trajectory_positions(times, positions, np.zeros_like(positions), t)
    np.testing.assert_allclose(trajectory_positions(times, positions, np.zeros_like(positions), times), positions)
    inside = (t > 0) & (t < 1)
    np.testing.assert_allclose(q[inside, 1], 2 * q[inside, 0], atol=1e-12)  # on the segment from point 0 to 1
    assert np.all(np.diff(q[inside, 0]) > 0)  # monotone: no overshoot
    speed = np.abs(np.gradient(q[:, 0], t))
    assert speed[np.argmin(np.abs(t - 1.0))] < 0.02 and speed.max() == pytest.approx(1.5, rel=0.01)  # peak 1.5x mean
    np.testing.assert_allclose(q[t < 0], [[0.0, 0.0]] * int((t < 0).sum()))  # holds the first point
    lin = trajectory_positions(times, positions, None, np.array([0.5, 2.0]))
    np.testing.assert_allclose(lin, [[0.5, 1.0], [1.0, 0.5]])


def test_obstacles_file_errors_name_the_entry_and_the_valid_keys(tmp_path):
    f = tmp_path / "o.yaml"
    cases = {
        "{type: box}": "must be a list",
        "- {type: cone, pos: [0, 0, 0]}": "type must be one of",
        "- {size: [1, 1, 1], pos: [0, 0, 0], colour: red}": r"unknown key\(s\) \['colour'\].*valid keys",
        "- {size: [1, -1, 1], pos: [0, 0, 0]}": "size must be > 0",
        "- {size: [1, 1, 1], half_size: [1, 1, 1], pos: [0, 0, 0]}": "exactly one of size",
        "- {radius: 0.1}": "needs pos",
        "- {radius: .nan, pos: [0, 0, 0]}": "radius must be a number > 0",
        "- {size: [1, 1, 1], pos: [0, 0]}": "pos must be 3 finite numbers",
        "- {size: [1, 1, 1], pos: [0, 0, 0], quat: [0, 0, 0, 0]}": "must not be zero",
        "- {radius: 0.1, pos: [0, 0, 0], name: a b}": "name 'a b'",
        "- [1, 2]": "entry 0: must be a mapping",
    }
    for text, message in cases.items():
        f.write_text(text)
        with pytest.raises(InvalidInputError, match=message):
            read_obstacles(f)
    f.write_text("- {size: [0.2, 0.4, 0.6], pos: [1, 2, 3], quat: [0, 0, 2, 0]}\n- {radius: 0.5, pos: [0, 0, 1]}")
    box, sphere = read_obstacles(f)
    assert box.half_size == (0.1, 0.2, 0.3) and box.quat_xyzw == (0.0, 0.0, 1.0, 0.0) and box.kind == "box"
    assert sphere.kind == "sphere" and sphere.half_size == (0.5, 0.5, 0.5)


def test_an_obstacle_in_the_base_frame_blocks_the_configuration_it_overlaps():
    q = np.array([0.0, 0.3, 0.0, -1.5, 0.0, 1.8, 0.0])
    free = RobotModel.load(RobotSource())
    free.set_q(q)
    hand = free.points_base(*free.surface_points(6))[:1][0]  # a point on the hand, base frame
    blocked = RobotModel.load(RobotSource(), obstacles=[Obstacle("sphere", tuple(hand), (0.05, 0.05, 0.05))])
    checker = CollisionChecker(blocked.model, blocked.arm_joints, qpos_ref=blocked.data.qpos.copy())
    hit, why = checker.in_collision(q)
    assert hit and "arc_obstacle_0" in why
    assert not CollisionChecker(free.model, free.arm_joints, qpos_ref=free.data.qpos.copy()).in_collision(q)[0]


def test_camera_pose_files_in_every_documented_shape(tmp_path):
    T = benchmark_camera_pose(3)
    shapes = {"T_camera_base": {"T_camera_base": T.tolist()}, "T_base_camera": {"T_base_camera": np.linalg.inv(
        T).tolist()}, "quat": {"translation": T[:3, 3].tolist(), "quaternion_xyzw": Rotation.from_matrix(
            T[:3, :3]).as_quat().tolist()}, "bare": T.tolist()}
    for name, data in shapes.items():
        (tmp_path / f"{name}.json").write_text(json.dumps(data))
        np.testing.assert_allclose(read_camera_pose(tmp_path / f"{name}.json"), T, atol=1e-12)
    (tmp_path / "bad.yaml").write_text("{rotation: [1, 2, 3]}")
    with pytest.raises(InvalidInputError, match="not a camera pose"):
        read_camera_pose(tmp_path / "bad.yaml")
    (tmp_path / "bad.yaml").write_text("{T_camera_base: [[1, 0], [0, 1]]}")
    with pytest.raises(InvalidInputError, match="must be 4x4"):
        read_camera_pose(tmp_path / "bad.yaml")


def test_read_trajectory_refuses_malformed_points(tmp_path):
    f = tmp_path / "t.yaml"

    def point(t, q):
        return {"positions": q, "time_from_start": {"sec": t, "nanosec": 0}}

    cases = {
        "not a trajectory": {"points": []},
        "not usable in a trajectory": {"joint_names": ["a,b"], "points": [point(0, [0.0])]},
        "strictly increasing|goes back|repeats": {"joint_names": ["a"], "points": [point(1, [0.0]), point(1, [1.0])]},
        "positions must be 1 finite": {"joint_names": ["a"], "points": [point(0, [0.0, 1.0])]},
        "integer sec and nanosec": {"joint_names": ["a"], "points": [{"positions": [0.0],
                                                                       "time_from_start": {"sec": 0.5, "nanosec": 0}}]},
        "some points only": {"joint_names": ["a"], "points": [point(0, [0.0]), {**point(1, [1.0]),
                                                                                 "velocities": [0.0]}]},
    }
    for message, data in cases.items():
        f.write_text(yaml.safe_dump(data))
        with pytest.raises(InvalidInputError, match=message):
            read_trajectory(f)


def test_plan_refuses_to_overwrite_or_to_write_over_its_input(tmp_path, capsys):
    out = tmp_path / "m.yaml"
    out.write_text("mine")
    assert main(["plan", "--motions", "1", "--output", str(out)]) == 2
    assert "already exists; use --force" in capsys.readouterr().err and out.read_text() == "mine"
    obstacles = tmp_path / "o.yaml"
    obstacles.write_text("[]")
    assert main(["plan", "--motions", "1", "--obstacles", str(obstacles), "--output", str(obstacles), "--force"]) == 2
    assert "is the input" in capsys.readouterr().err and obstacles.read_text() == "[]"
    assert main(["plan", "--motions", "1", "--camera-pose-guess", str(obstacles), "--output",
                 str(tmp_path / "x.yaml")]) == 2
    assert "needs --camera-info" in capsys.readouterr().err
    assert main(["plan", "--motions", "1", "--output", str(tmp_path / "x.txt")]) == 2
    assert not list(tmp_path.glob("x.*"))
    assert main(["plan", "--motions", "1", "--start", "0,0", "--output", str(tmp_path / "x.yaml")]) == 2
    assert "--start must be 7" in capsys.readouterr().err
