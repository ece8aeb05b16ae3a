"""ROS exports of a calibration: they parse back, and they carry base -> optical frame (the inverse)."""

import shlex
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from arc_env.robot.exports import (
    DEFAULT_CAMERA_FRAME,
    ParentChild,
    easy_handeye2_calib,
    export_paths,
    export_texts,
    static_transform_publisher_args,
    urdf_joint,
    write_files_atomic,
)
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


def test_write_files_atomic_writes_nothing_when_one_fails(tmp_path):
    good = tmp_path / "a.txt"
    bad = tmp_path / "missing_dir" / "b.txt"
    with pytest.raises(OSError):
        write_files_atomic({good: "a", bad: b"b"})
    assert list(tmp_path.iterdir()) == []
