"""ROS exports of a calibration: they parse back, and they carry base -> optical frame (the inverse)."""

import ast
import os
import py_compile
import shlex
import shutil
import subprocess
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from arc_env.robot.exports import (
    DEFAULT_CAMERA_FRAME,
    R_LINK_OPTICAL,
    XACRO_MACRO,
    XACRO_NS,
    ParentChild,
    calib_name_from,
    check_calib_name,
    check_frame_name,
    easy_handeye2_calib,
    easy_handeye2_install_path,
    export_paths,
    export_texts,
    launch_file,
    ros_base_frame,
    static_transform_publisher_args,
    urdf_joint,
    urdf_robot,
    write_files_atomic,
    xacro_macro,
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
    assert shlex.split(line)[:5] == ["exec", "ros2", "run", "tf2_ros", "static_transform_publisher"]
    assert shlex.split(line)[5:] == args


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


def test_export_paths_sit_beside_the_result_or_in_a_folder(tmp_path):
    paths = export_paths(tmp_path / "result.json")
    assert {p.name for p in paths.values()} == {"result.calib", "result.tf.sh", "result.urdf", "result.urdf.xacro",
                                                "result.launch.py"}
    assert {p.parent for p in paths.values()} == {tmp_path}
    assert {p.parent for p in export_paths(tmp_path / "result.json", tmp_path / "elsewhere").values()} == {
        tmp_path / "elsewhere"}


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
    joint = ET.fromstring(texts["urdf"]).find("joint")
    assert joint.find("parent").get("link") == name
    assert _launch_arguments(texts["launch"])[-4:] == ["--frame-id", name, "--child-frame-id", name + "_optical"]


# -- files that load as they are -----------------------------------------------------------------------

#: Poses whose exports hold tiny numbers (1e-05 m, a quaternion component of ~1e-7): PyYAML reads
#: ``1e-05`` (no dot) as a string, so these catch a writer that prints numbers itself.
TINY = [(np.array([0.5, 1e-05, 1.5]), np.array([0.5, 0.0, 0.0])),
        (np.array([-3e-07, 0.8, 1.2]), np.array([0.0, 0.0, 0.0]))]


def _numbers(tree):
    if isinstance(tree, dict):
        for v in tree.values():
            yield from _numbers(v)
    elif isinstance(tree, list):
        for v in tree:
            yield from _numbers(v)
    else:
        yield tree


@pytest.mark.parametrize(("eye", "target"), TINY)
def test_every_number_of_the_calib_loads_as_a_float(eye, target):
    edge = ParentChild.from_T_camera_base(look_at(eye, target), "panda_link0")
    data = yaml.safe_load(easy_handeye2_calib(edge, "rig-1"))
    values = list(_numbers(data["transform"]))
    assert len(values) == 7 and all(type(v) is float for v in values), values
    assert min(abs(v) for v in values if v != 0) < 1e-4  # a tiny value was among them
    assert data["parameters"]["name"] == "rig-1"


def _launch_arguments(text):
    """The ARGUMENTS list of a generated launch file, read as a literal (never executed)."""
    tree = ast.parse(text)
    [assign] = [n for n in tree.body if isinstance(n, ast.Assign) and n.targets[0].id == "ARGUMENTS"]
    return ast.literal_eval(assign.value)


def _require_check_urdf():
    """check_urdf's path; a skip where it is absent, but a failure in CI, which installs it (scripts/dev.sh)."""
    path = shutil.which("check_urdf")
    if path is None:
        if os.environ.get("CI") == "true":
            pytest.fail("check_urdf is missing in CI: scripts/dev.sh installs Debian's liburdfdom-tools")
        pytest.skip("check_urdf (Debian package liburdfdom-tools) is not installed here; CI installs it")
    return path


def _check_urdf(path):
    out = subprocess.run([_require_check_urdf(), str(path)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and "Successfully Parsed XML" in out.stdout, out.stdout + out.stderr
    return out.stdout


@pytest.mark.parametrize("link", [None, "camera_link"])
def test_the_urdf_is_a_robot_that_check_urdf_accepts(tmp_path, link):
    edge = ParentChild.from_T_camera_base(_random_T(6), "base_link")
    if link:
        edge = edge.to_camera_link(link)
    text = urdf_robot(edge, "rig-1")
    root = ET.fromstring(text.encode())  # one document: no junk after the root element
    assert root.tag == "robot" and root.get("name") == "rig-1"
    assert [e.get("name") for e in root.findall("link")] == ["base_link", link or DEFAULT_CAMERA_FRAME]
    [joint] = root.findall("joint")
    assert (joint.find("parent").get("link"), joint.find("child").get("link")) == ("base_link",
                                                                                     link or DEFAULT_CAMERA_FRAME)
    (tmp_path / "result.urdf").write_text(text)
    printed = _check_urdf(tmp_path / "result.urdf")
    assert "root Link: base_link has 1 child(ren)" in printed
    assert f"child(1):  {link or DEFAULT_CAMERA_FRAME}" in printed


def test_the_xacro_macro_expands_inside_a_robot_with_another_parent(tmp_path):
    import xacro

    edge = ParentChild.from_T_camera_base(_random_T(7), "panda_link0")
    (tmp_path / "camera.urdf.xacro").write_text(xacro_macro(edge))
    wrapper = tmp_path / "robot.urdf.xacro"
    wrapper.write_text(f"""<?xml version="1.0"?>
<robot name="wrapper" xmlns:xacro="{XACRO_NS}">
  <link name="arm_base"/>
  <xacro:include filename="{tmp_path / 'camera.urdf.xacro'}"/>
  <xacro:{XACRO_MACRO} parent="arm_base"/>
</robot>
""")
    expanded = xacro.process_file(str(wrapper)).toprettyxml()
    root = ET.fromstring(expanded.encode())
    assert [e.get("name") for e in root.findall("link")] == ["arm_base", DEFAULT_CAMERA_FRAME]
    [joint] = root.findall("joint")
    assert joint.get("name") == f"arm_base_to_{DEFAULT_CAMERA_FRAME}" and joint.get("type") == "fixed"
    assert joint.find("parent").get("link") == "arm_base"
    xyz = [float(v) for v in joint.find("origin").get("xyz").split()]
    rpy = [float(v) for v in joint.find("origin").get("rpy").split()]
    T = transform_from_rt(Rotation.from_euler("xyz", rpy).as_matrix(), xyz)
    np.testing.assert_allclose(T @ _random_T(7), np.eye(4), atol=PRINTED_TOL)
    (tmp_path / "expanded.urdf").write_text(expanded)
    if shutil.which("check_urdf") or os.environ.get("CI") == "true":  # the expansion is checked either way
        _check_urdf(tmp_path / "expanded.urdf")


def test_the_launch_file_compiles_and_passes_the_publisher_its_arguments(tmp_path):
    edge = ParentChild.from_T_camera_base(_random_T(8), "ur/base_link", "cam_optical")
    text = launch_file(edge)
    path = tmp_path / "result.launch.py"
    path.write_text(text)
    py_compile.compile(str(path), doraise=True)
    assert _launch_arguments(text) == static_transform_publisher_args(edge)
    assert "'--frame-id', 'ur/base_link'," in text and "'--child-frame-id', 'cam_optical'," in text
    assert 'package="tf2_ros", executable="static_transform_publisher"' in text


def test_tf_sh_is_written_executable_and_runs_the_publisher(tmp_path):
    edge = ParentChild.from_T_camera_base(_random_T(9), "base_link")
    paths = export_paths(tmp_path / "result.json")
    texts = export_texts(edge)
    write_files_atomic({paths[k]: texts[k] for k in paths}, {paths["static_transform_publisher"]: 0o755})
    script = paths["static_transform_publisher"]
    assert os.access(script, os.X_OK) and not os.access(paths["urdf"], os.X_OK)
    lines = script.read_text().splitlines()
    assert lines[0] == "#!/bin/sh" and all(line.startswith("#") for line in lines[:-1])
    assert shlex.split(lines[-1]) == ["exec", "ros2", "run", "tf2_ros", "static_transform_publisher",
                                      *static_transform_publisher_args(edge)]


def test_a_hostile_name_is_refused_before_any_serializer_and_quoting_holds_anyway():
    with pytest.raises(InvalidInputError, match="is not a valid ROS frame name"):
        ParentChild.from_T_camera_base(np.eye(4), "base", "cam'; touch PWNED; '")
    # the serializer alone would still keep a hostile word one word (defence in depth)
    hostile = "cam'; touch PWNED; '"
    assert shlex.split(shlex.join(["--child-frame-id", hostile])) == ["--child-frame-id", hostile]


def test_base_and_camera_frame_must_differ():
    with pytest.raises(InvalidInputError, match="both 'base'"):
        ParentChild.from_T_camera_base(np.eye(4), "base", "base")


# -- the camera link (REP 103) ---------------------------------------------------------------------------

def test_the_camera_link_rotation_is_rep_103():
    # independent construction: URDF rpy of the optical frame in camera_link is (-pi/2, 0, -pi/2)
    # (R = Rz(yaw) Ry(pitch) Rx(roll)), the rotation every ROS camera description uses
    R = (Rotation.from_euler("z", -np.pi / 2) * Rotation.from_euler("x", -np.pi / 2)).as_matrix()
    np.testing.assert_allclose(R_LINK_OPTICAL, R, atol=1e-12)
    # and its meaning: a point straight ahead of the lens is ahead (+x) in camera_link, right is -y, down is -z
    np.testing.assert_allclose(R_LINK_OPTICAL @ [0, 0, 2.0], [2.0, 0, 0])
    np.testing.assert_allclose(R_LINK_OPTICAL @ [1.0, 0, 0], [0, -1.0, 0])
    np.testing.assert_allclose(R_LINK_OPTICAL @ [0, 1.0, 0], [0, 0, -1.0])


def test_the_camera_link_edge_puts_the_lens_axis_along_link_x():
    # a camera 1.5 m above (0.5, 0, 0) looking down: its camera_link's x axis points down (-z of the base),
    # its origin is the optical centre, and composing back gives the optical frame's pose
    T_camera_base = look_at(np.array([0.5, 0.0, 1.5]), np.array([0.5, 0.0, 0.0]))
    optical = ParentChild.from_T_camera_base(T_camera_base, "base")
    link = optical.to_camera_link("camera_link")
    assert not link.optical and link.camera_frame == "camera_link" and link.base_frame == "base"
    np.testing.assert_allclose(link.translation, [0.5, 0.0, 1.5], atol=1e-12)
    np.testing.assert_allclose(link.T_base_camera[:3, 0], [0, 0, -1], atol=1e-12)
    T_link_optical = np.eye(4)
    T_link_optical[:3, :3] = R_LINK_OPTICAL
    np.testing.assert_allclose(link.T_base_camera @ T_link_optical, optical.T_base_camera, atol=1e-12)
    args = dict(zip(*[iter(static_transform_publisher_args(link))] * 2, strict=True))
    assert args["--child-frame-id"] == "camera_link"
    with pytest.raises(InvalidInputError, match="not a valid ROS frame name"):
        optical.to_camera_link("camera link")


# -- names and the easy_handeye2 folder --------------------------------------------------------------------

@pytest.mark.parametrize("name", ["", "-x", "a/b", "..", "a.calib", "a b", "$(id)", "x" * 101, "é"])
def test_bad_calibration_names_are_refused(name):
    with pytest.raises(InvalidInputError, match="is not a valid calibration name"):
        check_calib_name(name, "--calib-name")


@pytest.mark.parametrize(("source", "name"), [("rec0", "rec0"), ("lab rig 2024-05-01", "lab_rig_2024-05-01"),
                                              ("--x", "x"), ("..", "__"), ("", "arc_calib")])
def test_calib_names_from_recording_names_are_valid(source, name):
    assert calib_name_from(source) == name
    check_calib_name(calib_name_from(source), "name")


def test_the_install_path_honours_home(tmp_path, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path))
    assert easy_handeye2_install_path("rig-1") == tmp_path / ".ros2/easy_handeye2/calibrations/rig-1.calib"
    with pytest.raises(InvalidInputError, match="calibration name"):
        easy_handeye2_install_path("../evil")


def test_the_ros_base_frame_of_the_default_panda():
    assert ros_base_frame("panda0_link0") == "panda_link0" and ros_base_frame("link_base") == "link_base"


def test_every_public_name_imports():
    import arc_env.robot.exports as exports

    missing = [name for name in exports.__all__ if not hasattr(exports, name)]
    assert missing == [] and len(set(exports.__all__)) == len(exports.__all__)
