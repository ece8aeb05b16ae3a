"""Damaged and hostile inputs to ``arc-calib calibrate``: a clear refusal, nothing run, nothing of the user's lost.

Every case starts from a copy of one small recorded episode, damages it (or names its outputs badly),
runs ``calibrate`` and checks the invariants: the documented exit code, a message naming the file or
option, no traceback, the input byte-identical afterwards, and no output file left behind.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import cv2
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from arc_env.cli import main
from arc_env.sim.record import RecordSettings, record_episode
from tests.support.joints_csv import read_joints_csv, write_joints_csv

TINY = {"motions": 4, "width": 320, "height": 180, "fps": 8.0, "seed": 3}
HOSTILE = "L0$(touch${IFS}PWNED)"


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    out = tmp_path_factory.mktemp("hostile") / "rec"
    record_episode(RecordSettings(out=out, **TINY))
    return out


@pytest.fixture
def rec(recorded, tmp_path):
    """A private copy of the recording (its robot model copied too, so it can be damaged)."""
    dst = tmp_path / "rec"
    shutil.copytree(recorded, dst)
    return dst


def _snapshot(root: Path) -> dict[str, bytes | str]:
    out: dict[str, bytes | str] = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for name in dirnames + filenames:
            path = Path(dirpath) / name
            key = str(path.relative_to(root))
            if path.is_symlink():
                out[key] = "link:" + os.readlink(path)
            elif path.is_file():
                out[key] = path.read_bytes()
            elif not path.is_dir():
                out[key] = "special"
    return out


def _refused(rec: Path, out_dir: Path, capsys, code: int, needles: tuple[str, ...], *args: str) -> str:
    """Run calibrate on rec with args, check the invariants, return the printed text."""
    out_dir.mkdir(exist_ok=True)
    before_in, before_out = _snapshot(rec), _snapshot(out_dir)
    argv = ["calibrate", str(rec), "--output", str(out_dir / "result.json"), "--quiet", *args]
    cwd = Path.cwd()
    os.chdir(out_dir)  # where a `touch PWNED` would land if anything ran
    try:
        assert main(argv) == code
    finally:
        os.chdir(cwd)
    captured = capsys.readouterr()
    text = captured.err + captured.out
    for needle in needles:
        assert needle in text, text
    assert "Traceback" not in text
    assert _snapshot(rec) == before_in, "the input changed"
    assert _snapshot(out_dir) == before_out, "an output was left behind"
    assert not list(out_dir.rglob("PWNED")) and not (rec / "PWNED").exists()
    return text


def _edit_json(path: Path, **changes) -> None:
    data = json.loads(path.read_text())
    data.update(changes)
    path.write_text(json.dumps(data))


def _set_K(rec: Path, row: int, col: int, value: float) -> None:
    data = json.loads((rec / "camera.json").read_text())
    data["K"][row][col] = value
    (rec / "camera.json").write_text(json.dumps(data))


# -- names that reach the exports ----------------------------------------------------------------
def test_a_hostile_base_body_in_the_robot_model_is_refused(rec, tmp_path, capsys):
    model = rec / "robot" / "robot.xml"
    model.write_text(model.read_text().replace('"panda0_link0"', json.dumps(HOSTILE)))
    _edit_json(rec / "robot.json", base=HOSTILE)
    _refused(rec, tmp_path / "out", capsys, 2, ("is not a valid ROS frame name", "robot.json"))


@pytest.mark.parametrize("option", ["--base-frame", "--camera-frame", "--camera-link-frame"])
def test_hostile_frame_options_are_refused_before_any_work(rec, tmp_path, capsys, option):
    _refused(rec, tmp_path / "out", capsys, 2, (option, "is not a valid ROS frame name"), option, HOSTILE)


@pytest.mark.parametrize("name", [HOSTILE, "../../.bashrc", "-rf"])
def test_hostile_calibration_names_are_refused_before_any_work(rec, tmp_path, capsys, name, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    _refused(rec, tmp_path / "out", capsys, 2, ("--calib-name", "is not a valid calibration name"),
             f"--calib-name={name}", "--install-calib")
    assert not (tmp_path / "home").exists()


def test_an_installed_calibration_is_not_replaced_without_force(rec, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    installed = tmp_path / "home" / ".ros2" / "easy_handeye2" / "calibrations" / "rec.calib"
    installed.parent.mkdir(parents=True)
    installed.write_text("an earlier calibration\n")
    _refused(rec, tmp_path / "out", capsys, 2, ("rec.calib: already exists; use --force",), "--install-calib")
    assert installed.read_text() == "an earlier calibration\n"


# -- outputs that would damage the input or an earlier result -----------------------------------
def test_the_result_may_not_overwrite_the_recordings_intrinsics(rec, tmp_path, capsys):
    before = _snapshot(rec)
    assert main(["calibrate", str(rec), "--output", str(rec / "camera.json"), "--quiet", "--force"]) == 2
    text = capsys.readouterr().err
    assert "is inside the input" in text and _snapshot(rec) == before


def test_overlays_may_not_go_into_a_motion(rec, tmp_path, capsys):
    _refused(rec, tmp_path / "out", capsys, 2, ("is inside the input",), "--overlay", str(rec / "motions" / "000" /
                                                                                        "frames"))


def test_outputs_through_a_symlink_into_the_input_are_refused(rec, tmp_path, capsys):
    (tmp_path / "alias").symlink_to(rec)
    before = _snapshot(rec)
    assert main(["calibrate", str(rec), "--output", str(tmp_path / "alias" / "result.json"), "--quiet"]) == 2
    assert "is inside the input" in capsys.readouterr().err and _snapshot(rec) == before


def test_an_existing_result_is_not_replaced_without_force(rec, tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / "result.tf.sh").write_text("an earlier export\n")
    _refused(rec, out, capsys, 2, ("result.tf.sh: already exists; use --force",))


def test_an_output_that_is_a_directory_is_refused(rec, tmp_path, capsys):
    out = tmp_path / "out"
    (out / "result.json").mkdir(parents=True)
    _refused(rec, out, capsys, 2, ("result.json: is a directory",), "--force")


# -- magnitudes and damaged files ------------------------------------------------------------------
@pytest.mark.parametrize(("field", "value", "needle"), [
    ("width", 2147483648, "width and height must be integers in 16..16384"),
    ("width", 320.0, "width and height must be integers"),
    ("dist", [0.1, 1e9, 0, 0], "dist[1] = 1e+09 is not a distortion coefficient"),
])
def test_camera_json_magnitudes(rec, tmp_path, capsys, field, value, needle):
    _edit_json(rec / "camera.json", **{field: value})
    _refused(rec, tmp_path / "out", capsys, 2, ("camera.json", needle))


@pytest.mark.parametrize("value", [1e300, 1e-300, -5.0])
def test_absurd_focal_lengths_name_the_field(rec, tmp_path, capsys, value):
    _set_K(rec, 1, 1, value)
    _refused(rec, tmp_path / "out", capsys, 2, ("camera.json",))


def test_a_principal_point_far_outside_the_image(rec, tmp_path, capsys):
    _set_K(rec, 0, 2, 5000.0)
    _refused(rec, tmp_path / "out", capsys, 2, ("camera.json", "K[0][2] (cx) = 5000 px"))


@pytest.mark.parametrize(("mutate", "needles"), [
    (lambda rows: rows[2].__setitem__(3, 100.0), ("line 4 (frame 2)", "panda0_joint3 = 100 rad is outside its limits")),
    (lambda rows: rows[1].__setitem__(2, float("nan")), ("line 3 (frame 1)", "panda0_joint2'] are NaN")),
], ids=["out-of-range", "nan"])
def test_joint_values_out_of_range_or_nan(rec, tmp_path, capsys, mutate, needles):
    path = rec / "motions" / "001" / "joints.csv"
    header, rows = read_joints_csv(path)
    mutate(rows)
    write_joints_csv(path, header, rows)
    _refused(rec, tmp_path / "out", capsys, 2, (str(path), *needles))


def test_strings_and_short_rows_in_joints_csv(rec, tmp_path, capsys):
    path = rec / "motions" / "002" / "joints.csv"
    lines = path.read_text().splitlines()
    path.write_text("\n".join([*lines[:3], "3,abc", *lines[4:]]) + "\n")
    _refused(rec, tmp_path / "out", capsys, 2, (str(path), "line 4"))


@pytest.mark.parametrize("damage", ["truncated", "garbage"])
def test_damaged_pngs(rec, tmp_path, capsys, damage):
    png = rec / "motions" / "000" / "frames" / "000002.png"
    data = png.read_bytes()
    png.write_bytes(data[: len(data) // 3] if damage == "truncated" else b"\x89PNG garbage" * 10)
    _refused(rec, tmp_path / "out", capsys, 2, (str(png),))


@pytest.fixture(scope="module")
def recorded_video(tmp_path_factory):
    out = tmp_path_factory.mktemp("hostile_video") / "rec"
    record_episode(RecordSettings(out=out, video=True, **TINY))
    return out


@pytest.fixture
def video_rec(recorded_video, tmp_path):
    dst = tmp_path / "video_rec"
    shutil.copytree(recorded_video, dst)
    return dst


def _drop_last_frame(path: Path) -> None:
    """Re-encode an MP4 without its last frame (a recorder that stopped one frame early)."""
    capture = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, image = capture.read()
        if not ok:
            break
        frames.append(image)
    capture.release()
    h, w = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 8.0, (w, h))
    for image in frames[:-1]:
        writer.write(image)
    writer.release()


@pytest.mark.parametrize("damage", ["head", "half", "tail", "garbage", "one frame short", "empty"])
def test_damaged_mp4s(video_rec, tmp_path, capsys, damage):
    video = video_rec / "motions" / "001" / "video.mp4"
    data = video.read_bytes()
    if damage == "one frame short":
        _drop_last_frame(video)
    else:
        cut = {"head": 64, "half": len(data) // 2, "tail": len(data) - 100}.get(damage)
        video.write_bytes(data[:cut] if cut is not None else
                          b"" if damage == "empty" else b"\x00\x00\x00\x18ftypisom" + os.urandom(4096))
    text = _refused(video_rec, tmp_path / "out", capsys, 2, (str(video),))
    if damage == "one frame short":
        assert "joints.csv" in text


def test_an_intact_mp4_recording_passes_the_checks(video_rec, tmp_path, capsys):
    """The control: undamaged, the same videos are read and tracked (this tiny episode is too small to
    give tracks, so calibrate ends with exit 1 and no result, not with exit 2 naming a file)."""
    out = tmp_path / "out"
    out.mkdir()
    assert main(["calibrate", str(video_rec), "--output", str(out / "result.json"), "--quiet"]) == 1
    text = capsys.readouterr().out
    assert "motions: 4, accepted 0, rejected 4" in text and "video.mp4" not in text


def test_a_missing_file(rec, tmp_path, capsys):
    (rec / "camera.json").unlink()
    _refused(rec, tmp_path / "out", capsys, 2, ("camera.json: missing",))


def test_a_looping_motion_symlink_is_named(rec, tmp_path, capsys):
    (rec / "motions" / "loop").symlink_to(rec / "motions" / "loop")
    _refused(rec, tmp_path / "out", capsys, 2, ("motions/loop: not a motion directory",))


def test_a_fifo_instead_of_joints_csv_is_refused_without_blocking(rec, tmp_path, capsys):
    path = rec / "motions" / "003" / "joints.csv"
    path.unlink()
    os.mkfifo(path)
    _refused(rec, tmp_path / "out", capsys, 2, (str(path), "not a regular file"))


# -- property: any damage to the three text files keeps the invariants ----------------------------
_VALUES = st.one_of(st.none(), st.booleans(), st.integers(-(2**40), 2**40),
                    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8),
                    st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=6))


@settings(max_examples=30, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(target=st.sampled_from(["camera.json", "robot.json", "joints.csv"]), key=st.integers(0, 20), value=_VALUES,
       text=st.text(max_size=12))
def test_any_damage_to_the_text_files_keeps_the_invariants(recorded, tmp_path_factory, target, key, value, text):
    work = tmp_path_factory.mktemp("prop")
    rec, out = work / "rec", work / "out"
    shutil.copytree(recorded, rec)
    out.mkdir()
    if target == "joints.csv":
        path = rec / "motions" / f"{key % TINY['motions']:03d}" / "joints.csv"
        lines = path.read_text().splitlines()
        row = 1 + key % (len(lines) - 1)
        cells = lines[row].split(",")
        cells[key % len(cells)] = text
        lines[row] = ",".join(cells)
        path.write_text("\n".join(lines) + "\n")
    else:
        path = rec / target
        data = json.loads(path.read_text())
        fields = sorted(data) + ["K"]
        field = fields[key % len(fields)]
        if field == "K" and target == "camera.json" and key % 2:
            data["K"][key % 3][(key // 3) % 3] = value
        else:
            data[field] = value
        path.write_text(json.dumps(data))
    before = _snapshot(rec)
    code = main(["calibrate", str(rec), "--output", str(out / "result.json"), "--quiet"])
    assert code in (0, 1, 2)
    assert _snapshot(rec) == before
    if code != 0:
        assert list(out.iterdir()) == []


# -- Ctrl-C --------------------------------------------------------------------------------------
def test_ctrl_c_while_tracking_leaves_no_output(rec, tmp_path, capsys, monkeypatch):
    import arc_env.robot.session as session

    calls = []

    def interrupted(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    real = session.track_keypoints
    monkeypatch.setattr(session, "track_keypoints", interrupted)
    out = tmp_path / "out"
    out.mkdir()
    before = _snapshot(rec)
    assert main(["calibrate", str(rec), "--output", str(out / "result.json"), "--quiet"]) == 130
    assert "interrupted; no result written" in capsys.readouterr().err
    assert _snapshot(rec) == before and list(out.iterdir()) == []


def test_ctrl_c_while_committing_the_outputs_rolls_them_back(tmp_path, monkeypatch):
    import arc_env.robot.exports as exports

    (tmp_path / "result.json").write_text("an earlier result")
    calls = []
    real = os.replace

    def interrupted(src, dst):
        calls.append(dst)
        if len(calls) == 3:  # after the earlier result was moved aside and the first new file moved in
            raise KeyboardInterrupt
        return real(src, dst)

    monkeypatch.setattr(exports.os, "replace", interrupted)
    with pytest.raises(KeyboardInterrupt):
        exports.write_files_atomic({tmp_path / "result.json": "new", tmp_path / "result.calib": "new",
                                    tmp_path / "overlay" / "a.png": b"png"})
    monkeypatch.setattr(exports.os, "replace", real)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["result.json"]
    assert (tmp_path / "result.json").read_text() == "an earlier result"
