"""Bags in: real bags written with the rosbags writers (ROS 2 sqlite3, MCAP, ROS 1), read back as recordings.

Each bag holds a 64x48 camera at 20 Hz, camera_info and 200 Hz joint states of the Panda: a transit
(three joints), three exploratory motions and a small turn. Frame k is flat: red = k, green 100, blue 200,
so colour-order mistakes and frame mix-ups show. Nothing is tracked here (the images are flat): these
tests cover reading; the CLI tests calibrate a rendered bag.
"""

import json
import shutil

import numpy as np
import pytest

from arc_env.cli import main
from arc_env.robot.bag import BagWriter, intrinsics_from_camera_info, read_bag, read_camera_info_yaml
from arc_env.robot.model import RobotModel, RobotSource
from arc_env.robot.recording import write_robot_model
from solver.errors import InvalidInputError
from solver.observations import CameraIntrinsics

W, H = 64, 48
T0 = 1_700_000_000.0  #: s: the camera clock's time at the start of the stream
FPS = 20.0
JOINT_HZ = 200.0
#: rad: the deltas read from the bag match the script's when the offset is right (the trajectory is piecewise
#: linear with corners at joint samples, so interpolation is exact) up to the stamps' float64 resolution at
#: 1.7e9 s (2.4e-7 s, so 2.4e-7 rad at 1 rad/s).
EXACT = 1e-6
#: grey levels: JPEG at quality 95 of a flat image.
JPEG_TOL = 3
CAMERA = CameraIntrinsics(K=np.array([[60.0, 0, 32], [0, 60.0, 24], [0, 0, 1]]),
                          dist=np.array([-0.1, 0.01, 0.0, 0.0, 0.0]), width=W, height=H)
#: an equidistant (fisheye) camera: CameraInfo distortion_model "equidistant", D = k1..k4
FISHEYE = CameraIntrinsics(K=np.array([[38.0, 0, 31.7], [0, 38.5, 23.9], [0, 0, 1]]),
                           dist=np.array([0.05, -0.01, 0.002, -0.0003]), width=W, height=H, model="fisheye")
#: the motions of the script: (joint index, delta rad)
MOTIONS = [(3, 0.5), (5, -0.4), (1, 0.3)]


@pytest.fixture(scope="module")
def robot(tmp_path_factory):
    folder = tmp_path_factory.mktemp("robot")
    name, base = write_robot_model(RobotSource(), folder)
    model = RobotModel.load(RobotSource(path=str(folder / name), base_body=base, home=()))
    return folder / name, base, model


def _knots(q0):
    """(time s, q) knots of the true trajectory: rest, transit, then each motion between rests."""
    knots, t, q = [(0.0, q0.copy())], 0.3, q0.copy()
    knots.append((t, q.copy()))
    q = q + np.array([0.3, -0.2, 0.2, 0, 0, 0, 0])  # transit: three joints
    t += 0.5
    knots += [(t, q.copy()), (t + 0.3, q.copy())]
    t += 0.3
    for joint, delta in [*MOTIONS, (2, 0.05)]:  # the last one turns too little
        q = q.copy()
        q[joint] += delta
        t += abs(delta)  # 1 rad/s
        knots += [(t, q.copy()), (t + 0.3, q.copy())]
        t += 0.3
    return knots


def _true_q(knots, t):
    times = np.array([k[0] for k in knots])
    qs = np.array([k[1] for k in knots])
    return np.column_stack([np.interp(t, times, qs[:, j]) for j in range(qs.shape[1])])


def frame_image(k):
    image = np.empty((H, W, 3), np.uint8)
    image[..., 0], image[..., 1], image[..., 2] = k, 100, 200
    return image


def write_test_bag(path, model, storage="mcap", encoding="rgb8", latency_s=0.0, joint_names=None,
                   clock_gap_s=0.0, images=True, joints=True, extra_joint_topic=False, distortion_model="",
                   compress=False, camera=CAMERA):
    """The script as a bag; joint stamps = true time + latency_s (+ clock_gap_s)."""
    names = joint_names or list(model.joint_names)
    knots = _knots(model.default_q)
    end = knots[-1][0]
    writer = BagWriter(path, storage, encoding, compress=compress)
    if extra_joint_topic:
        second = writer.writer.add_connection("/other/joint_states", "sensor_msgs/msg/JointState",
                                              typestore=writer.typestore)
    ns = lambda t: int(round((T0 + t) * 1e9))  # noqa: E731
    writer.camera_info(ns(0.0), camera, distortion_model)
    events = []
    if images:
        events += [(k / FPS, "image", k) for k in range(int(end * FPS))]
    if joints:
        events += [(t, "joints", None) for t in np.arange(0.0, end, 1 / JOINT_HZ)]
    for t, kind, k in sorted(events, key=lambda e: e[0]):
        if kind == "image":
            writer.image(ns(t), frame_image(k))
        else:
            stamp = ns(t + latency_s + clock_gap_s)
            writer.joints(stamp, names, _true_q(knots, np.array([t]))[0])
            if extra_joint_topic:  # the same states on a second topic
                main_topic, writer.joint_conn = writer.joint_conn, second
                writer.joints(stamp, names, _true_q(knots, np.array([t]))[0])
                writer.joint_conn = main_topic
    return writer.close(), knots


@pytest.mark.parametrize("encoding", ["rgb8", "bgr8", "jpeg"])
@pytest.mark.parametrize("storage", ["sqlite3", "mcap", "ros1"])
def test_a_bag_reads_back_as_motions_with_their_frames(robot, tmp_path, storage, encoding):
    model_path, base, model = robot
    bag, knots = write_test_bag(tmp_path / ("b.bag" if storage == "ros1" else "b"), model, storage, encoding)
    rec = read_bag(bag, model_path, base)
    assert [(m.joint, round(float(m.delta[-1]), 6)) for m in rec.motions] == [(j, d) for j, d in MOTIONS]
    assert len(rec.skipped) == 2 and "3 joints move" in rec.skipped[0].reason
    assert "turns by only +0.050 rad" in rec.skipped[1].reason
    for m in rec.motions:
        t = m.times - T0
        np.testing.assert_allclose(m.delta, _true_q(knots, t)[:, m.joint] - _true_q(knots, t[:1])[0, m.joint],
                                   atol=EXACT)
        frames = rec.frames(m)
        assert len(frames) == m.n_frames >= 3
        ks = np.rint(t * FPS).astype(int)
        tol = JPEG_TOL if encoding == "jpeg" else 0
        for k, image in zip(ks, frames, strict=True):
            assert image.shape == (H, W, 3)
            assert np.abs(image.astype(int) - frame_image(k)).max() <= tol


def test_a_single_mcap_file_reads_like_its_directory(robot, tmp_path):
    model_path, base, model = robot
    bag, _ = write_test_bag(tmp_path / "b", model, "mcap")
    single = tmp_path / "only.mcap"
    shutil.copy(next(bag.glob("*.mcap")), single)
    a, b = read_bag(bag, model_path, base), read_bag(single, model_path, base)
    assert [m.n_frames for m in a.motions] == [m.n_frames for m in b.motions]
    np.testing.assert_allclose(b.intrinsics.K, CAMERA.K)
    np.testing.assert_allclose(b.intrinsics.dist, CAMERA.dist)


def test_a_late_joint_clock_is_undone_by_the_time_offset(robot, tmp_path):
    model_path, base, model = robot
    latency = 0.02
    bag, knots = write_test_bag(tmp_path / "late", model, latency_s=latency)
    exact = read_bag(bag, model_path, base, time_offset_s=latency)
    late = read_bag(bag, model_path, base)
    for m_exact, m_late in zip(exact.motions, late.motions, strict=True):
        t = m_exact.times - T0
        truth = _true_q(knots, t)
        np.testing.assert_allclose(m_exact.delta, truth[:, m_exact.joint] - truth[0, m_exact.joint], atol=EXACT)
        np.testing.assert_allclose(m_exact.q_start, truth[0], atol=EXACT)
        moving = np.abs(m_exact.joint_velocity) > 0.99  # frames inside the 1 rad/s turn
        assert moving.sum() >= 3
        # read 20 ms early, a frame of a 1 rad/s turn lags by 20 mrad
        late_q = _true_q(knots, m_late.times - T0 - latency)[:, m_late.joint]
        np.testing.assert_allclose(m_late.q_start[m_late.joint] + m_late.delta, late_q, atol=EXACT)


def test_camera_info_models(tmp_path):
    K = CAMERA.K.reshape(-1)
    rational = intrinsics_from_camera_info("rational_polynomial", K, np.arange(8) * 0.01, W, H, "x")
    assert rational.dist.size == 8
    assert intrinsics_from_camera_info("", K, np.zeros(5), W, H, "x").dist.size == 0
    for name in ("equidistant", "fisheye"):
        fisheye = intrinsics_from_camera_info(name, K, FISHEYE.dist, W, H, "x")
        assert fisheye.model == "fisheye" and fisheye.dist.tolist() == FISHEYE.dist.tolist()
    ideal = intrinsics_from_camera_info("equidistant", K, np.zeros(4), W, H, "x")
    assert ideal.model == "fisheye" and ideal.dist.tolist() == [0, 0, 0, 0]  # r = f theta, not a pinhole
    with pytest.raises(InvalidInputError,
                       match=r"^x: distortion_model 'equidistant' takes \(4,\) coefficients, got 5$"):
        intrinsics_from_camera_info("equidistant", K, np.zeros(5), W, H, "x")
    with pytest.raises(InvalidInputError, match="^x: .*skew.*fisheye"):
        intrinsics_from_camera_info("equidistant", K + [0, 0.5, 0, 0, 0, 0, 0, 0, 0], np.zeros(4), W, H, "x")
    with pytest.raises(InvalidInputError, match="takes \\(8,\\) coefficients, got 5"):
        intrinsics_from_camera_info("rational_polynomial", K, np.zeros(5), W, H, "x")
    with pytest.raises(InvalidInputError, match="zero focal length"):
        intrinsics_from_camera_info("plumb_bob", np.zeros(9), np.zeros(5), W, H, "x")
    yml = tmp_path / "cam.yaml"
    yml.write_text("image_width: 64\nimage_height: 48\ncamera_name: cam\n"
                   "camera_matrix: {rows: 3, cols: 3, data: [61, 0, 31, 0, 62, 23, 0, 0, 1]}\n"
                   "distortion_model: plumb_bob\n"
                   "distortion_coefficients: {rows: 1, cols: 5, data: [-0.2, 0.03, 0, 0, 0]}\n")
    cam = read_camera_info_yaml(yml)
    assert cam.K[0, 0] == 61 and cam.K[1, 2] == 23 and cam.dist.tolist() == [-0.2, 0.03, 0, 0, 0]
    yml.write_text("image_width: 64\nimage_height: 48\ncamera_name: cam\n"
                   "camera_matrix: {rows: 3, cols: 3, data: [38, 0, 31.7, 0, 38.5, 23.9, 0, 0, 1]}\n"
                   "distortion_model: equidistant\n"
                   "distortion_coefficients: {rows: 1, cols: 4, data: [0.05, -0.01, 0.002, -0.0003]}\n")
    cam = read_camera_info_yaml(yml)
    assert cam.model == "fisheye" and cam.dist.tolist() == FISHEYE.dist.tolist()
    np.testing.assert_array_equal(cam.K, FISHEYE.K)
    yml.write_text(yml.read_text().replace("cols: 4, data: [", "cols: 3, data: ["))
    yml.write_text(yml.read_text().replace("0.002, -0.0003]", "0.002]"))
    with pytest.raises(InvalidInputError, match=r"cam.yaml: distortion_model 'equidistant' takes \(4,\) "
                       r"coefficients, got 3$"):
        read_camera_info_yaml(yml)


@pytest.mark.parametrize("storage", ["mcap", "ros1"])
def test_an_equidistant_camera_info_reads_as_a_fisheye(robot, tmp_path, storage):
    model_path, base, model = robot
    bag, _ = write_test_bag(tmp_path / ("b.bag" if storage == "ros1" else "b"), model, storage, camera=FISHEYE)
    cam = read_bag(bag, model_path, base).intrinsics
    assert cam.model == "fisheye"
    np.testing.assert_array_equal(cam.K, FISHEYE.K)
    np.testing.assert_array_equal(cam.dist, FISHEYE.dist)


# -- bad bags: one line naming the topic, exit 2, nothing written ---------------------------------------
def _fails(bag, tmp_path, capsys, robot, *needles, extra=()):
    model_path, base, _ = robot
    out = tmp_path / "result.json"
    code = main(["calibrate", str(bag), "--robot", str(model_path), "--base-body", base, "--output", str(out),
                 "--quiet", *extra])
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith("arc-calib calibrate:")]
    assert code == 2, err
    assert len(lines) == 1 and "Traceback" not in err, err
    for needle in needles:
        assert needle in lines[0], lines[0]
    assert not any(p.name.startswith(("result", ".result")) for p in tmp_path.iterdir())
    return lines[0]


def test_no_joint_states(robot, tmp_path, capsys):
    bag, _ = write_test_bag(tmp_path / "b", robot[2], joints=False)
    _fails(bag, tmp_path, capsys, robot, "topic /joint_states: no joint states")


def test_no_images(robot, tmp_path, capsys):
    bag, _ = write_test_bag(tmp_path / "b", robot[2], images=False)
    _fails(bag, tmp_path, capsys, robot, "topic /camera/color/image_raw: holds no images")


def test_a_joint_unknown_to_the_model(robot, tmp_path, capsys):
    names = [*robot[2].joint_names[:-1], "elbow_joint"]
    bag, _ = write_test_bag(tmp_path / "b", robot[2], joint_names=names)
    _fails(bag, tmp_path, capsys, robot, "topic /joint_states message #0", "'elbow_joint' is not a joint of")


def test_clocks_that_never_overlap(robot, tmp_path, capsys):
    bag, _ = write_test_bag(tmp_path / "b", robot[2], clock_gap_s=3600.0)
    _fails(bag, tmp_path, capsys, robot, "no image on /camera/color/image_raw was exposed while /joint_states",
           "clocks that never overlap")


def test_several_joint_topics_need_a_choice(robot, tmp_path, capsys):
    bag, _ = write_test_bag(tmp_path / "b", robot[2], extra_joint_topic=True)
    _fails(bag, tmp_path, capsys, robot, "several sensor_msgs/JointState topics: ['/joint_states', "
           "'/other/joint_states']; choose one with --joint-topic")
    assert len(read_bag(bag, robot[0], robot[1], joint_topic="/other/joint_states").motions) == 3


def test_an_equidistant_camera_info_with_five_coefficients(robot, tmp_path, capsys):
    bag, _ = write_test_bag(tmp_path / "b", robot[2], distortion_model="equidistant")  # CAMERA's 5 plumb_bob
    _fails(bag, tmp_path, capsys, robot, "topic /camera/color/camera_info",
           "distortion_model 'equidistant' takes (4,) coefficients, got 5")


@pytest.mark.parametrize("damage", ["truncated", "corrupt chunk"])
@pytest.mark.parametrize("storage", ["sqlite3", "mcap", "ros1"])
def test_a_truncated_or_corrupt_bag(robot, tmp_path, capsys, storage, damage):
    # compressed ROS 1 chunks: an uncompressed ROS 1 bag has no checksum, garbage over pixels reads as pixels
    bag, _ = write_test_bag(tmp_path / ("b.bag" if storage == "ros1" else "b"), robot[2], storage,
                            compress=storage == "ros1")
    data = bag if storage == "ros1" else next(p for p in bag.iterdir() if p.suffix in (".mcap", ".db3"))
    raw = bytearray(data.read_bytes())
    middle = len(raw) // 2
    if damage == "truncated":
        raw = raw[:middle]
    else:  # garbage over 4 KiB in the middle: message data, the file's index intact
        raw[middle:middle + 4096] = np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes()
    data.write_bytes(bytes(raw))
    line = _fails(bag, tmp_path, capsys, robot, str(bag))
    assert "bag" in line or "topic" in line


def test_bag_options_on_a_recording_directory_are_refused(tmp_path, capsys):
    rec = tmp_path / "rec"
    rec.mkdir()
    assert main(["calibrate", str(rec), "--joint-topic", "/j", "--output", str(tmp_path / "r.json")]) == 2
    assert "--joint-topic apply to bags only" in capsys.readouterr().err


def test_a_bag_without_robot_is_refused(robot, tmp_path, capsys):
    bag, _ = write_test_bag(tmp_path / "b", robot[2])
    assert main(["calibrate", str(bag), "--output", str(tmp_path / "r.json")]) == 2
    assert "a bag needs --robot FILE" in capsys.readouterr().err


def test_camera_info_file_replaces_the_topic(robot, tmp_path):
    bag, _ = write_test_bag(tmp_path / "b", robot[2])
    yml = tmp_path / "cam.yaml"
    yml.write_text(json.dumps({"image_width": W, "image_height": H, "distortion_model": "plumb_bob",
                               "camera_matrix": {"data": [70, 0, 32, 0, 70, 24, 0, 0, 1]},
                               "distortion_coefficients": {"data": [0, 0, 0, 0, 0]}}))
    rec = read_bag(bag, robot[0], robot[1], camera_info_file=yml)
    assert rec.intrinsics.K[0, 0] == 70 and rec.topics.camera_info is None
