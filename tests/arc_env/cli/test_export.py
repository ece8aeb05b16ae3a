"""``arc-calib export result.json``: every export rewritten from a result, bad results refused in one line.

The results here are written by hand with the keys ``export`` reads (the round trip test runs it on a
real ``calibrate`` result); the pose is a known camera looking down, so the exports can be checked
against numbers, not only against each other.
"""

import json
import os
import shlex

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from arc_env.cli import main
from arc_env.robot.exports import R_LINK_OPTICAL, RESULT_FORMAT
from solver.frames import transform_from_rt
from solver.synthetic import look_at

#: A camera 1.5 m above (0.5, 1e-05, 0) looking down: its optical centre in the base is that point.
EYE = np.array([0.5, 1e-05, 1.5])
TARGET = np.array([0.5, 0.0, 0.0])
T_CAMERA_BASE = look_at(EYE, TARGET)
#: The exports print 9 significant digits.
PRINTED_TOL = 1e-8
EXPORTS = ("result.calib", "result.tf.sh", "result.urdf", "result.urdf.xacro", "result.launch.py")


def _result(**changes):
    data = {"format": RESULT_FORMAT, "usable": True, "unusable_reason": "", "source": "/data/lab rig 3",
            "T_camera_base": T_CAMERA_BASE.tolist(),
            "frames": {"parent": "panda_link0", "child": "camera_color_optical_frame",
                       "child_is": "optical", "optical_frame": "camera_color_optical_frame"},
            "calib_name": "rig3", "exports": {}}
    data.update(changes)
    return data


@pytest.fixture
def home(tmp_path, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    return tmp_path / "home"


@pytest.fixture
def result(tmp_path):
    path = tmp_path / "out" / "result.json"
    path.parent.mkdir()
    path.write_text(json.dumps(_result(), indent=2))
    return path


def _calib_T(path):
    tf = yaml.safe_load(path.read_text())["transform"]
    t, r = tf["translation"], tf["rotation"]
    return transform_from_rt(Rotation.from_quat([r[k] for k in "xyzw"]).as_matrix(), [t[k] for k in "xyz"])


def _tf_words(path):
    words = shlex.split(path.read_text().splitlines()[-1])
    return dict(zip(words[5::2], words[6::2], strict=True))


def test_export_rewrites_every_file_beside_the_result_and_leaves_it_alone(result, home, capsys):
    before = result.read_bytes()
    assert main(["export", str(result)]) == 0
    out = capsys.readouterr().out
    folder = result.parent
    assert sorted(p.name for p in folder.iterdir()) == sorted(["result.json", *EXPORTS])
    assert result.read_bytes() == before
    np.testing.assert_allclose(_calib_T(folder / "result.calib") @ T_CAMERA_BASE, np.eye(4), atol=PRINTED_TOL)
    calib = yaml.safe_load((folder / "result.calib").read_text())["parameters"]
    assert calib["name"] == "rig3" and calib["robot_base_frame"] == "panda_link0"
    assert _tf_words(folder / "result.tf.sh")["--child-frame-id"] == "camera_color_optical_frame"
    assert os.access(folder / "result.tf.sh", os.X_OK)
    assert "ros2 launch easy_handeye2 publish.launch.py name:=rig3" in out
    assert not home.exists()  # nothing installed unless asked


def test_export_with_new_names_into_a_folder_and_install(result, home, tmp_path, capsys):
    args = ["export", str(result), "--output", str(tmp_path / "re"), "--base-frame", "base_link",
            "--camera-frame", "cam_optical", "--calib-name", "cell-2", "--install-calib"]
    assert main(args) == 0
    assert "ros2 launch easy_handeye2 publish.launch.py name:=cell-2" in capsys.readouterr().out
    assert sorted(p.name for p in (tmp_path / "re").iterdir()) == sorted(EXPORTS)
    assert sorted(p.name for p in result.parent.iterdir()) == ["result.json"]
    installed = home / ".ros2" / "easy_handeye2" / "calibrations" / "cell-2.calib"
    assert installed.read_text() == (tmp_path / "re" / "result.calib").read_text()
    p = yaml.safe_load(installed.read_text())["parameters"]
    assert (p["name"], p["robot_base_frame"], p["tracking_base_frame"]) == ("cell-2", "base_link", "cam_optical")
    # a second install of the same name is refused without --force, and nothing is rewritten
    installed.write_text("an earlier calibration\n")
    assert main(args) == 2
    assert "cell-2.calib: already exists; use --force" in capsys.readouterr().err
    assert installed.read_text() == "an earlier calibration\n"
    assert main([*args, "--force"]) == 0 and "eye_on_base" in installed.read_text()


def test_export_to_the_camera_link(result, home, capsys):
    assert main(["export", str(result), "--camera-link-frame", "camera_link"]) == 0
    capsys.readouterr()
    words = _tf_words(result.parent / "result.tf.sh")
    assert (words["--frame-id"], words["--child-frame-id"]) == ("panda_link0", "camera_link")
    T_base_link = _calib_T(result.parent / "result.calib")
    T_link_optical = np.eye(4)
    T_link_optical[:3, :3] = R_LINK_OPTICAL
    np.testing.assert_allclose(T_base_link @ T_link_optical @ T_CAMERA_BASE, np.eye(4), atol=PRINTED_TOL)
    np.testing.assert_allclose(T_base_link[:3, 3], EYE, atol=PRINTED_TOL)  # the same origin
    lens = (TARGET - EYE) / np.linalg.norm(TARGET - EYE)
    np.testing.assert_allclose(T_base_link[:3, 0], lens, atol=PRINTED_TOL)  # link x: along the lens (down)


def test_update_result_records_the_new_frames(result, home, capsys):
    assert main(["export", str(result), "--base-frame", "world", "--update-result"]) == 0
    data = json.loads(result.read_text())
    assert data["frames"]["parent"] == "world" and data["calib_name"] == "rig3"
    assert data["exports"]["urdf"] == "result.urdf"
    np.testing.assert_array_equal(np.asarray(data["T_camera_base"]), T_CAMERA_BASE)
    assert main(["export", str(result), "--update-result", "--output", str(result.parent.parent)]) == 2
    assert "--update-result" in capsys.readouterr().err


def test_the_calib_name_defaults_to_the_source_when_the_result_has_none(tmp_path, home, capsys):
    path = tmp_path / "result.json"
    data = _result()
    del data["calib_name"]
    path.write_text(json.dumps(data))
    assert main(["export", str(path)]) == 0
    assert "name:=lab_rig_3" in capsys.readouterr().out


def test_an_unusable_result_is_refused_with_exit_1(tmp_path, capsys):
    path = tmp_path / "result.json"
    path.write_text(json.dumps(_result(usable=False, unusable_reason="the estimate is too uncertain")))
    assert main(["export", str(path)]) == 1
    err = capsys.readouterr().err
    assert "the result is not usable (the estimate is too uncertain)" in err and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["result.json"]


def _nan_pose():
    T = T_CAMERA_BASE.tolist()
    T[0][3] = float("nan")
    return T


BAD = {
    "missing": (None, "no such file"),
    "not json": ("{usable: true", "not valid JSON"),
    "a list": ("[1, 2]", "expected a JSON object"),
    "other format": (json.dumps(_result(format="something else")), "'format' is 'something else'"),
    "no pose": (json.dumps({k: v for k, v in _result().items() if k != "T_camera_base"}),
                "missing key 'T_camera_base'"),
    "no usable": (json.dumps({k: v for k, v in _result().items() if k != "usable"}), "missing key 'usable'"),
    "usable a string": (json.dumps(_result(usable="yes")), "'usable' must be true or false"),
    "nan in the pose": (json.dumps(_result(T_camera_base=_nan_pose())), "contains NaN or infinite values"),
    "3x3 pose": (json.dumps(_result(T_camera_base=np.eye(3).tolist())), "must be 4x4"),
    "text pose": (json.dumps(_result(T_camera_base="identity")), "'T_camera_base' is not a 4x4 array"),
    "ragged pose": (json.dumps(_result(T_camera_base=[[1, 0], [0]])), "'T_camera_base' is not a 4x4 array"),
    "no frames": (json.dumps({k: v for k, v in _result().items() if k != "frames"}), "missing key 'frames'"),
    "hostile base": (json.dumps(_result(frames={"parent": "b; rm -rf ~"})), "is not a valid ROS frame name"),
    "hostile name": (json.dumps(_result(calib_name="../../.bashrc")), "is not a valid calibration name"),
    "binary": (b"\xff\xfe\x00", "cannot be read"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_results_give_one_line_and_exit_2(tmp_path, capsys, case):
    content, needle = BAD[case]
    path = tmp_path / "result.json"
    if isinstance(content, bytes):
        path.write_bytes(content)
    elif content is not None:
        path.write_text(content)
    assert main(["export", str(path)]) == 2
    err = capsys.readouterr().err
    assert needle in err and str(path) in err, err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert sorted(p.name for p in tmp_path.iterdir()) == (["result.json"] if content is not None else [])


@pytest.mark.parametrize(("option", "needle"), [("--base-frame", "is not a valid ROS frame name"),
                                                ("--camera-link-frame", "is not a valid ROS frame name"),
                                                ("--calib-name", "is not a valid calibration name")])
def test_hostile_options_are_refused(result, capsys, option, needle):
    assert main(["export", str(result), option, "x$(touch PWNED)"]) == 2
    assert needle in capsys.readouterr().err
    assert sorted(p.name for p in result.parent.iterdir()) == ["result.json"]
