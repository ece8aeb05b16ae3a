"""ROS exports of a calibration: they parse back, and they carry base -> optical frame (the inverse)."""

import shlex
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from arc_env.robot.exports import (
    DEFAULT_CAMERA_FRAME,
    ParentChild,
    check_frame_name,
    easy_handeye2_calib,
    export_paths,
    export_texts,
    static_transform_publisher_args,
    urdf_joint,
    write_files_atomic,
)
from solver.errors import InvalidInputError
from solver.frames import transform_from_rt
from solver.synthetic import look_at

#: Exports print 9 significant digits: about 1e-9 relative.
PRINTED_TOL = 1e-8


def _random_T(seed):
    rng = np.random.default_rng(seed)
    return transform_from_rt(Rotation.random(random_state=seed).as_matrix(), rng.uniform(-2, 2, 3))


def _matrix_from_xyzw(q):
    return Rotation.from_quat(q).as_matrix()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_calib_yaml_parses_back_to_the_inverse(seed):
    T_camera_base = _random_T(seed)
    edge = ParentChild.from_T_camera_base(T_camera_base, "panda_link0")
    data = yaml.safe_load(easy_handeye2_calib(edge))
    p = data["parameters"]
    assert p["calibration_type"] == "eye_on_base"
    assert p["robot_base_frame"] == "panda_link0" and p["tracking_base_frame"] == DEFAULT_CAMERA_FRAME
    t = data["transform"]["translation"]
    r = data["transform"]["rotation"]
    T_base_camera = transform_from_rt(_matrix_from_xyzw([r["x"], r["y"], r["z"], r["w"]]), [t["x"], t["y"], t["z"]])
    np.testing.assert_allclose(T_base_camera @ T_camera_base, np.eye(4), atol=PRINTED_TOL)


def test_tf_line_has_named_arguments_in_order_and_the_inverse():
    T_camera_base = _random_T(3)
    edge = ParentChild.from_T_camera_base(T_camera_base, "base_link", "cam_optical")
    args = static_transform_publisher_args(edge)
    keys = args[0::2]
    assert keys == ["--x", "--y", "--z", "--qx", "--qy", "--qz", "--qw", "--frame-id", "--child-frame-id"]
    values = dict(zip(keys, args[1::2], strict=True))
    assert values["--frame-id"] == "base_link" and values["--child-frame-id"] == "cam_optical"
    q = [float(values[k]) for k in ("--qx", "--qy", "--qz", "--qw")]
    t = [float(values[k]) for k in ("--x", "--y", "--z")]
    T_parent_child = transform_from_rt(_matrix_from_xyzw(q), t)
    np.testing.assert_allclose(T_parent_child, np.linalg.inv(T_camera_base), atol=PRINTED_TOL)
    line = export_texts(edge)["static_transform_publisher"].splitlines()[-1]
    assert shlex.split(line)[:4] == ["ros2", "run", "tf2_ros", "static_transform_publisher"]
    assert shlex.split(line)[4:] == args


def test_tf_of_a_camera_looking_down_is_its_position_in_the_base():
    # A camera 1.5 m above the point (0.5, 0, 0), looking straight down: in the base frame the optical
    # centre is at (0.5, 0, 1.5) and the optical z axis points along -z.
    T_camera_base = look_at(np.array([0.5, 0.0, 1.5]), np.array([0.5, 0.0, 0.0]))
    edge = ParentChild.from_T_camera_base(T_camera_base, "base")
    np.testing.assert_allclose(edge.translation, [0.5, 0.0, 1.5], atol=1e-12)
    z_optical_in_base = _matrix_from_xyzw(edge.quaternion_xyzw)[:, 2]
    np.testing.assert_allclose(z_optical_in_base, [0, 0, -1], atol=1e-12)


@pytest.mark.parametrize("seed", [4, 5])
def test_urdf_joint_rpy_rebuilds_the_inverse(seed):
    T_camera_base = _random_T(seed)
    edge = ParentChild.from_T_camera_base(T_camera_base, "base")
    text = urdf_joint(edge)
    root = ET.fromstring(f"<robot>{text}</robot>")
    joint = root.find("joint")
    assert joint.get("type") == "fixed"
    assert joint.find("parent").get("link") == "base" and joint.find("child").get("link") == DEFAULT_CAMERA_FRAME
    xyz = [float(v) for v in joint.find("origin").get("xyz").split()]
    roll, pitch, yaw = (float(v) for v in joint.find("origin").get("rpy").split())
    # URDF: fixed axes, R = Rz(yaw) @ Ry(pitch) @ Rx(roll)
    R = (Rotation.from_euler("z", yaw) * Rotation.from_euler("y", pitch) * Rotation.from_euler("x", roll)).as_matrix()
    np.testing.assert_allclose(transform_from_rt(R, xyz) @ T_camera_base, np.eye(4), atol=PRINTED_TOL)


def test_export_paths_sit_beside_the_result(tmp_path):
    paths = export_paths(tmp_path / "result.json")
    assert {p.name for p in paths.values()} == {"result.calib", "result.tf.sh", "result.urdf.xml"}


def test_write_files_atomic_commits_all_or_nothing(tmp_path):
    (tmp_path / "a.txt").write_text("old")
    (tmp_path / "not_a_dir").write_text("x")
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    with pytest.raises(OSError):  # the second target's parent is a file: its move fails after a.txt's
        write_files_atomic({tmp_path / "a.txt": "new", tmp_path / "new_dir" / "c.png": b"c",
                            tmp_path / "not_a_dir" / "b.txt": b"b"})
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before  # a.txt restored, nothing new left
    with pytest.raises(InvalidInputError, match="is a directory"):
        write_files_atomic({tmp_path / "b.txt": "b", tmp_path: "x"})
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


def test_write_files_atomic_creates_folders_and_replaces(tmp_path):
    write_files_atomic({tmp_path / "a.txt": "new", tmp_path / "out" / "deep" / "b.png": b"b"})
    write_files_atomic({tmp_path / "a.txt": "newer"})
    assert (tmp_path / "a.txt").read_text() == "newer" and (tmp_path / "out" / "deep" / "b.png").read_bytes() == b"b"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "out"]  # no staging folder left


#: Names an attacker might put in a robot file or on the command line.
HOSTILE = ["L0$(touch${IFS}PWNED)", "base; rm -rf ~", "a\nb", "1base", "", "base link", 'x"/><evil/>', "--", "a--b>"]


@pytest.mark.parametrize("name", HOSTILE)
def test_hostile_frame_names_never_reach_an_export(name):
    with pytest.raises(InvalidInputError, match="is not a valid ROS frame name"):
        ParentChild.from_T_camera_base(np.eye(4), name)
    with pytest.raises(InvalidInputError, match="is not a valid ROS frame name"):
        ParentChild.from_T_camera_base(np.eye(4), "base", name)


@settings(max_examples=200, deadline=None)
@given(st.text(min_size=1, max_size=20))
def test_any_accepted_name_round_trips_through_every_serializer(name):
    try:
        check_frame_name(name, "name")
    except InvalidInputError:
        return
    edge = ParentChild.from_T_camera_base(np.eye(4), name, name + "_optical")
    texts = export_texts(edge)
    words = shlex.split(texts["static_transform_publisher"].splitlines()[-1])
    assert words[-4:] == ["--frame-id", name, "--child-frame-id", name + "_optical"]
    assert yaml.safe_load(texts["easy_handeye2"])["parameters"]["robot_base_frame"] == name
    joint = ET.fromstring(f"<robot>{texts['urdf_joint']}</robot>").find("joint")
    assert joint.find("parent").get("link") == name
