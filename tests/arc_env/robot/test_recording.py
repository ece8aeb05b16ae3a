"""Recordings: the writer's output reads back; every kind of bad recording gets a message naming the
file or motion, and ``arc-calib calibrate`` writes nothing for it.

A tiny recording (320x180, 4 short motions: no tracking happens at this size, so these tests cost
little) is made once per module; each test copies it (its robot model is shared by an absolute path,
which the format allows) and breaks one thing.
"""

import json
import re
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from arc_env.cli import main
from arc_env.robot.model import RobotSource, panda_mjcf_dir
from arc_env.robot.recording import RecordingWriter, read_camera, read_recording, write_robot_model
from arc_env.sim.distortion import Distorter
from arc_env.sim.record import RecordSettings, ground_truth_path, record_episode
from solver.camera import normalized_from_pixels
from solver.errors import InvalidInputError
from solver.observations import CameraIntrinsics
from tests.support.arms import arm_urdf, forward_axes, random_arm
from tests.support.joints_csv import read_joints_csv, write_joints_csv

#: rad and m: how closely a model survives MuJoCo's MJCF export into the recording.
EXPORT_PRECISION = 1e-6
TINY = {"motions": 4, "width": 320, "height": 180, "fps": 8.0, "seed": 3}


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    out = tmp_path_factory.mktemp("tiny") / "rec"
    truth = record_episode(RecordSettings(out=out, **TINY))
    return out, truth


@pytest.fixture
def copy(tiny, tmp_path):
    """A private copy of the tiny recording (robot model referenced by absolute path)."""
    src, _ = tiny
    dst = tmp_path / "rec"
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("robot"))
    (dst / "robot.json").write_text(json.dumps({"model": str(src / "robot" / "robot.xml"), "base": "panda0_link0"}))
    return dst


def _calibrate_fails(rec, tmp_path, capsys, code, *needles, extra=()):
    out = tmp_path / "result.json"
    assert main(["calibrate", str(rec), "--output", str(out), "--quiet", *extra]) == code
    captured = capsys.readouterr()
    text = captured.err + captured.out
    for needle in needles:
        assert needle in text, text
    assert "Traceback" not in text
    assert not any(p.name.startswith(("result", ".result")) for p in tmp_path.iterdir()), list(tmp_path.iterdir())
    return text


# -- the writer --------------------------------------------------------------------------------------
def test_record_writes_the_format_and_the_ground_truth_beside_it(tiny):
    rec, truth = tiny
    assert sorted(p.name for p in rec.iterdir()) == ["camera.json", "motions", "robot", "robot.json"]
    assert ground_truth_path(rec).is_file() and ground_truth_path(rec).parent == rec.parent
    assert not list(rec.rglob("*ground_truth*"))
    recording = read_recording(rec)
    assert len(recording.motions) == TINY["motions"] and not any(m.pruned for m in recording.motions)
    for m in recording.motions:
        header, rows = read_joints_csv(m.path / "joints.csv")
        assert header[0] == "frame" and tuple(header[1:]) == recording.joint_names
        frames = recording.frames(m)
        assert len(frames) == m.n_frames == len(rows) and frames[0].shape == (180, 320, 3)
        np.testing.assert_allclose(m.delta, np.array(rows)[:, 1 + m.joint] - rows[0][1 + m.joint])
    T = np.asarray(truth["T_camera_base"])
    assert T.shape == (4, 4) and np.allclose(T[3], [0, 0, 0, 1])


def test_video_recording_reads_back_with_matching_frames(tmp_path):
    out = tmp_path / "vid"
    record_episode(RecordSettings(out=out, motions=2, width=320, height=180, fps=8.0, seed=5, video=True),
                   )
    recording = read_recording(out, min_motions=1)
    for m in recording.motions:
        assert m.video is not None and not m.frame_paths
        frames = recording.frames(m)
        assert len(frames) == m.n_frames and frames[0].shape == (180, 320, 3)


def test_record_refuses_an_existing_output(tiny, capsys):
    rec, _ = tiny
    assert main(["record", "--out", str(rec), "--width", "320", "--height", "180"]) == 2
    assert "already exists" in capsys.readouterr().err


def test_joint_latency_shifts_the_logged_sweep_by_latency_times_speed(tiny, tmp_path, capsys):
    rec, truth = tiny
    latency_s = 0.04
    out = tmp_path / "late"
    args = ["record", "--out", str(out), "--motions", "2", "--width", str(TINY["width"]),
            "--height", str(TINY["height"]), "--fps", str(TINY["fps"]), "--seed", str(TINY["seed"]),
            "--joint-latency-ms", str(latency_s * 1e3)]
    assert main(args) == 0
    assert "joint log +40 ms" in capsys.readouterr().out
    assert truth["joint_latency_s"] == 0.0
    late_truth = json.loads(ground_truth_path(out).read_text())
    assert late_truth["joint_latency_s"] == latency_s and late_truth["T_camera_base"] == truth["T_camera_base"]
    exact, late = read_recording(rec).motions[:2], read_recording(out, min_motions=1).motions
    assert len(late) == 2
    for a, b in zip(exact, late, strict=True):
        assert a.joint == b.joint and a.n_frames == b.n_frames
        for k in range(a.n_frames):  # the same frames: the camera is not affected
            frame = Path("frames") / f"{k:06d}.png"
            assert (a.path / frame).read_bytes() == (b.path / frame).read_bytes()
        rows_a = np.array(read_joints_csv(a.path / "joints.csv")[1])
        rows_b = np.array(read_joints_csv(b.path / "joints.csv")[1])
        column = 1 + a.joint
        still = np.ones(rows_a.shape[1], bool)
        still[column] = False
        np.testing.assert_array_equal(rows_a[:, still], rows_b[:, still])
        velocity = (rows_a[1, column] - rows_a[0, column]) * TINY["fps"]  # rad/s of the sweep's frames
        assert 0 < abs(velocity) <= 1.0 + 1e-9  # EnvConfig.joint_speed
        np.testing.assert_allclose(rows_a[:, column] - rows_b[:, column], latency_s * velocity, atol=1e-12)
    with pytest.raises(InvalidInputError, match="joint latency"):
        RecordSettings(out=tmp_path / "never", joint_latency_s=2.0)


# -- distortion ----------------------------------------------------------------------------------------
def test_distorter_maps_each_pixel_to_its_pinhole_ray():
    target = CameraIntrinsics(K=np.array([[300.0, 0, 161.0], [0, 300.0, 88.0], [0, 0, 1]]),
                              dist=np.array([-0.25, 0.08, 0.001, -0.001, 0.0]), width=320, height=180)
    d = Distorter(target)
    ys, xs = np.mgrid[0:180:17, 0:320:23]
    px = np.column_stack([xs.ravel(), ys.ravel()]).astype(float)
    src = np.column_stack([d.map_x[ys.ravel(), xs.ravel()], d.map_y[ys.ravel(), xs.ravel()]])
    np.testing.assert_allclose(normalized_from_pixels(src, d.pinhole), normalized_from_pixels(px, target), atol=1e-5)
    # barrel distortion: the render is wider than the target and every pixel maps inside it
    assert d.pinhole.K[0, 0] < 300.0
    assert src.min() >= 0 and np.all(src.max(axis=0) <= [319, 179])
    image = np.full((180, 320, 3), 200, np.uint8)
    assert d(image).min() > 0  # no black border


def test_record_with_distortion_writes_dist(tmp_path):
    out = tmp_path / "dist"
    record_episode(RecordSettings(out=out, motions=1, width=320, height=180, fps=8.0, seed=6,
                                  dist=(-0.2, 0.05, 0.0, 0.0, 0.0)))
    camera = json.loads((out / "camera.json").read_text())
    assert camera["dist"] == [-0.2, 0.05, 0.0, 0.0, 0.0]
    assert read_recording(out, min_motions=1).intrinsics.dist.size == 5


# -- bad recordings ----------------------------------------------------------------------------------
def test_missing_recording(tmp_path, capsys):
    _calibrate_fails(tmp_path / "nowhere", tmp_path, capsys, 2, "nowhere", "not a directory")


@pytest.mark.parametrize("name", ["camera.json", "robot.json"])
def test_missing_top_level_file(copy, tmp_path, capsys, name):
    (copy / name).unlink()
    _calibrate_fails(copy, tmp_path, capsys, 2, str(copy / name), "missing")


def test_invalid_camera_json(copy, tmp_path, capsys):
    (copy / "camera.json").write_text('{"width": 320, "height": 180, "K": [[1, 0], [0, 1]]}')
    _calibrate_fails(copy, tmp_path, capsys, 2, "camera.json", "K must be 3x3")
    (copy / "camera.json").write_text("{not json")
    _calibrate_fails(copy, tmp_path, capsys, 2, "camera.json", "not valid JSON")


def test_missing_robot_model(copy, tmp_path, capsys):
    (copy / "robot.json").write_text(json.dumps({"model": "robot/nothing.xml"}))
    _calibrate_fails(copy, tmp_path, capsys, 2, "robot.json", "nothing.xml", "does not exist")


def test_missing_joints_csv(copy, tmp_path, capsys):
    (copy / "motions" / "001" / "joints.csv").unlink()
    _calibrate_fails(copy, tmp_path, capsys, 2, str(Path("motions") / "001" / "joints.csv"), "missing")


def test_missing_frame(copy, tmp_path, capsys):
    frames = sorted((copy / "motions" / "002" / "frames").iterdir())
    frames[1].unlink()
    _calibrate_fails(copy, tmp_path, capsys, 2, str(Path("motions") / "002" / "frames"),
                     f"{len(frames) - 1} PNG frames but", f"has {len(frames)} rows")


def test_extra_csv_row(copy, tmp_path, capsys):
    path = copy / "motions" / "000" / "joints.csv"
    header, rows = read_joints_csv(path)
    write_joints_csv(path, header, rows + [[len(rows), *rows[-1][1:]]])
    _calibrate_fails(copy, tmp_path, capsys, 2, str(Path("motions") / "000"), f"has {len(rows) + 1} rows")


def test_unknown_joint_name(copy, tmp_path, capsys):
    path = copy / "motions" / "003" / "joints.csv"
    header, rows = read_joints_csv(path)
    header[2] = "elbow_of_another_robot"
    write_joints_csv(path, header, rows)
    _calibrate_fails(copy, tmp_path, capsys, 2, str(Path("motions") / "003" / "joints.csv"),
                     "unknown joint(s) ['elbow_of_another_robot']", "robot:panda0_joint1")


def test_nan_joint_value(copy, tmp_path, capsys):
    path = copy / "motions" / "001" / "joints.csv"
    header, rows = read_joints_csv(path)
    rows[2][3] = float("nan")
    write_joints_csv(path, header, rows)
    _calibrate_fails(copy, tmp_path, capsys, 2, str(Path("motions") / "001" / "joints.csv"), "line 4 (frame 2)",
                     header[3], "NaN")


def test_png_that_is_not_a_png(copy, tmp_path, capsys):
    bad = copy / "motions" / "002" / "frames" / "000003.png"
    bad.write_bytes(b"this is not an image")
    _calibrate_fails(copy, tmp_path, capsys, 2, str(Path("motions") / "002" / "frames" / "000003.png"),
                     "not a PNG")


def test_truncated_png(copy, tmp_path, capsys):
    bad = copy / "motions" / "000" / "frames" / "000001.png"
    bad.write_bytes(bad.read_bytes()[:200])  # the header survives, the pixels do not
    _calibrate_fails(copy, tmp_path, capsys, 2, str(Path("motions") / "000" / "frames" / "000001.png"),
                     "does not decode")


def test_frame_of_the_wrong_size(copy, tmp_path, capsys):
    bad = copy / "motions" / "001" / "frames" / "000000.png"
    cv2.imwrite(str(bad), np.zeros((90, 160, 3), np.uint8))
    _calibrate_fails(copy, tmp_path, capsys, 2, "000000.png", "160x90", "320x180")


def test_corrupt_video(copy, tmp_path, capsys):
    motion = copy / "motions" / "001"
    shutil.rmtree(motion / "frames")
    (motion / "video.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42" + bytes(range(256)) * 8)
    _calibrate_fails(copy, tmp_path, capsys, 2, str(Path("motions") / "001" / "video.mp4"))


def test_frames_and_video_both(copy, tmp_path, capsys):
    (copy / "motions" / "001" / "video.mp4").write_bytes(b"x")
    _calibrate_fails(copy, tmp_path, capsys, 2, str(Path("motions") / "001"), "both frames/ and video.mp4")


def _freeze(path):
    """Make every row of a joints.csv equal to row 0: no joint moves."""
    header, rows = read_joints_csv(path)
    write_joints_csv(path, header, [[k, *rows[0][1:]] for k in range(len(rows))])
    return header


def _second_joint_moves(path, which):
    header, rows = read_joints_csv(path)
    for k, r in enumerate(rows):
        r[1 + which] += 0.3 * k / len(rows)
    write_joints_csv(path, header, rows)
    return header


def test_motions_with_no_or_two_moving_joints_are_pruned_with_reasons(copy):
    _freeze(copy / "motions" / "000" / "joints.csv")
    recording = read_recording(copy)
    m0 = recording.motions[0]
    assert m0.pruned.startswith("no joint moves") and m0.joint is None
    moving = recording.motions[1].joint
    _second_joint_moves(copy / "motions" / "001" / "joints.csv", (moving + 1) % 7)
    with pytest.raises(InvalidInputError, match=r"too few usable motions: 2 of 4 \(need 3\)") as info:
        read_recording(copy)
    assert "motion 000: no joint moves" in str(info.value)
    assert "motion 001: 2 joints move" in str(info.value)


def test_too_few_usable_motions_exits_2_naming_each_pruned_motion(copy, tmp_path, capsys):
    for name in ("000", "001"):
        _freeze(copy / "motions" / name / "joints.csv")
    _calibrate_fails(copy, tmp_path, capsys, 2, "too few usable motions", "motion 000: no joint moves",
                     "motion 001: no joint moves")


def test_robot_never_in_the_image(copy, tmp_path, capsys):
    blank = np.full((180, 320, 3), 90, np.uint8)
    for png in (copy / "motions").rglob("*.png"):
        cv2.imwrite(str(png), blank)
    text = _calibrate_fails(copy, tmp_path, capsys, 1, "no usable calibration", "Nothing written")
    assert "none of the 4 motions gave keypoint tracks" in text and "is the robot in view?" in text


def test_a_urdf_arm_records_and_reads_back_with_its_own_kinematics(tmp_path):
    spec = random_arm(5)
    urdf = tmp_path / "arm.urdf"
    urdf.write_text(arm_urdf(spec))
    out = tmp_path / "arm_rec"
    record_episode(RecordSettings(out=out, motions=3, width=320, height=180, fps=8.0, seed=1,
                                  robot=RobotSource(str(urdf), "arm_base", home=())))
    recording = read_recording(out)
    assert recording.base_body == "arm_base" and len(recording.joint_names) == spec.n_joints
    q = np.random.default_rng(0).uniform(-1, 1, spec.n_joints)
    axes, anchors = forward_axes(spec, q)
    for j in range(spec.n_joints):
        axis, point = recording.kinematics(q, j)
        # MuJoCo's MJCF export prints ~7 significant digits: 1e-6 is a thousand times below what a
        # calibration resolves (mrad, mm)
        np.testing.assert_allclose(axis, axes[j], atol=EXPORT_PRECISION)
        np.testing.assert_allclose(np.cross(point - anchors[j], axes[j]), 0, atol=EXPORT_PRECISION)  # same line


def test_robot_model_with_relative_meshes_is_copied_self_contained(tmp_path):
    src = tmp_path / "src"
    (src / "m").mkdir(parents=True)
    shutil.copy(panda_mjcf_dir() / "meshes" / "collision" / "link1.stl", src / "m" / "link.stl")
    (src / "arm.xml").write_text(
        '<mujoco><compiler meshdir="m"/><asset><mesh name="l" file="link.stl"/></asset><worldbody>'
        '<body name="b"><geom type="mesh" mesh="l"/><body name="c"><joint name="j" axis="0 0 1"/>'
        '<geom type="mesh" mesh="l"/></body></body></worldbody></mujoco>')
    name, base = write_robot_model(RobotSource(str(src / "arm.xml"), "b"), tmp_path / "robot")
    shutil.rmtree(src)  # the written model must not need the original files
    import mujoco  # after arc_env (imported above), which picks MuJoCo's GL backend

    model = mujoco.MjModel.from_xml_path(str(tmp_path / "robot" / name))
    assert base == "b" and model.nmesh == 1 and model.joint("j").id == 0


# -- format 2: exposure times and a joint series on its own clock ------------------------------------
T0 = 100.0  #: s, the camera clock when the first frame is exposed
JOINT_HZ = 200.0


def _to_format_2(motion_dir, latency_s=0.0, fps=TINY["fps"]):
    """Rewrite a format 1 motion as format 2: frames.csv at fps, joints at 200 Hz stamped latency_s late.

    The per-frame rows of the recorder are a constant-speed sweep, so the joint samples between them are
    the linear interpolation of the rows (exact, no model error). Returns the frame times and per-frame rows.
    """
    header, rows = read_joints_csv(motion_dir / "joints.csv")
    rows = np.array(rows)[:, 1:]
    t_frames = T0 + np.arange(len(rows)) / fps
    t_true = np.arange(t_frames[0] - 0.1, t_frames[-1] + 0.1, 1 / JOINT_HZ)
    samples = np.column_stack([np.interp(t_true, t_frames, rows[:, j]) for j in range(rows.shape[1])])
    with (motion_dir / "frames.csv").open("w") as f:
        f.write("frame,t\n" + "".join(f"{k},{float(t)!r}\n" for k, t in enumerate(t_frames)))
    with (motion_dir / "joints.csv").open("w") as f:
        f.write(",".join(["t", *header[1:]]) + "\n")
        for t, s in zip(t_true, samples, strict=True):
            f.write(",".join(repr(float(v)) for v in [t + latency_s, *s]) + "\n")
    return t_frames, rows


def test_format_2_reads_joints_at_the_exposures_and_honours_the_time_offset(copy):
    latency = 0.05
    expected = {}
    for m in ("000", "001", "002", "003"):
        expected[m] = _to_format_2(copy / "motions" / m, latency)
    late = read_recording(copy)  # offset not given: deltas lag by latency * speed
    exact = read_recording(copy, time_offset_s=latency)
    assert exact.time_offset_s == latency
    for a, b in zip(late.motions, exact.motions, strict=True):
        t_frames, rows = expected[b.name]
        np.testing.assert_allclose(b.times, t_frames)
        np.testing.assert_allclose(b.delta, rows[:, b.joint] - rows[0, b.joint], atol=1e-9)
        np.testing.assert_allclose(b.q_start, rows[0], atol=1e-9)
        speed = (rows[-1, b.joint] - rows[0, b.joint]) / (t_frames[-1] - t_frames[0])
        np.testing.assert_allclose(b.joint_velocity[1:-1], speed, atol=1e-6)  # the ends: the sweep's corners
        # without the offset every frame after the first (still at rest then) reads latency * speed too early
        late_delta = rows[1:, b.joint] - latency * speed - rows[0, b.joint]
        np.testing.assert_allclose(a.delta[1:], late_delta, atol=1e-9)


def test_format_2_calibrate_reads_a_time_offset_and_format_1_refuses_one(copy, tmp_path, capsys):
    _calibrate_fails(copy, tmp_path, capsys, 2, "a time offset needs time stamps", "format 1",
                     extra=["--time-offset", "0.02"])


@pytest.mark.parametrize(("edit", "needles"), [
    ("frames_missing", ["frames.csv: missing", "needs frames.csv"]),
    ("nan_time", ["joints.csv line 5: t is NaN"]),
    ("duplicate_time", ["joints.csv line 5: t = ", "repeats the previous row"]),
    ("backwards_time", ["frames.csv line 3: t = ", "earlier than the previous row"]),
    ("outside_span", ["outside the joint samples' span", "never extrapolated"]),
    ("frames_csv_with_format_1", ["frames.csv: exposure times need a joints.csv with a t column"]),
], ids=lambda v: v if isinstance(v, str) else "")
def test_bad_format_2_motions_are_named(copy, tmp_path, capsys, edit, needles):
    motion = copy / "motions" / "002"
    if edit == "frames_csv_with_format_1":
        (motion / "frames.csv").write_text("frame,t\n0,0.0\n")
    else:
        _to_format_2(motion)
    joints, frames = (motion / "joints.csv").read_text().splitlines(), (motion / "frames.csv").read_text().splitlines()
    if edit == "frames_missing":
        (motion / "frames.csv").unlink()
    elif edit in ("nan_time", "duplicate_time"):
        cells = joints[4].split(",")
        cells[0] = "nan" if edit == "nan_time" else joints[3].split(",")[0]
        joints[4] = ",".join(cells)
    elif edit == "backwards_time":
        frames[2] = "1,0.0"
    elif edit == "outside_span":
        frames[-1] = f"{len(frames) - 2},{T0 + 60!r}"
    if edit != "frames_missing":
        (motion / "joints.csv").write_text("\n".join(joints) + "\n")
        (motion / "frames.csv").write_text("\n".join(frames) + "\n")
    _calibrate_fails(copy, tmp_path, capsys, 2, *needles)


# -- camera.json's distortion_model ------------------------------------------------------------------------
FISHEYE_CAMERA = {"width": 640, "height": 400, "K": [[260.0, 0, 320.5], [0, 261.0, 199.0], [0, 0, 1]],
                  "dist": [0.08, -0.03, 0.008, -0.001]}


def test_camera_json_distortion_model(tmp_path):
    path = tmp_path / "camera.json"
    for name in ("equidistant", "fisheye"):
        path.write_text(json.dumps({**FISHEYE_CAMERA, "distortion_model": name}))
        cam = read_camera(path)
        assert cam.model == "fisheye" and cam.dist.tolist() == FISHEYE_CAMERA["dist"]
    path.write_text(json.dumps(FISHEYE_CAMERA))  # no model: the pinhole model, as before
    assert read_camera(path).model == "pinhole"
    for name, count in (("plumb_bob", 5), ("rational_polynomial", 8)):
        path.write_text(json.dumps({**FISHEYE_CAMERA, "dist": [0.01] * count, "distortion_model": name}))
        assert read_camera(path).model == "pinhole" and read_camera(path).dist.size == count
    path.write_text(json.dumps({**FISHEYE_CAMERA, "dist": [0.01] * 5, "distortion_model": "equidistant"}))
    with pytest.raises(InvalidInputError, match=r"camera.json: distortion_model 'equidistant' takes \(4,\) "
                       r"coefficients in dist, got 5$"):
        read_camera(path)
    for name in ("kannala_brandt", ["equidistant"]):
        path.write_text(json.dumps({**FISHEYE_CAMERA, "distortion_model": name}))
        with pytest.raises(InvalidInputError, match=rf"camera.json: distortion_model {re.escape(repr(name))} is not "
                           r"supported; supported: \['equidistant', 'plumb_bob', 'rational_polynomial'\]"):
            read_camera(path)


def test_recording_writer_keeps_a_fisheye(tmp_path):
    cam = CameraIntrinsics(K=np.array(FISHEYE_CAMERA["K"]), dist=np.array(FISHEYE_CAMERA["dist"]), width=640,
                           height=400, model="fisheye")
    writer = RecordingWriter(tmp_path / "rec", cam, RobotSource())
    try:
        written = json.loads((writer.tmp / "camera.json").read_text())
        assert written["distortion_model"] == "equidistant"
        back = read_camera(writer.tmp / "camera.json")
        assert back.model == "fisheye" and back.dist.tolist() == FISHEYE_CAMERA["dist"]
        np.testing.assert_array_equal(back.K, cam.K)
    finally:
        writer.abort()
