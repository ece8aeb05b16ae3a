"""``arc-calib demo`` on the MuJoCo scene: table, final pose, overlay with IoU, exit codes."""

import re

import cv2
import numpy as np

from arc_env.cli import main
from arc_env.robot.overlay import mask_iou


def test_mask_iou_against_hand_counts():
    a = np.zeros((4, 4), bool)
    b = np.zeros((4, 4), bool)
    a[:2] = True  # 8 pixels
    b[1:3] = True  # 8 pixels, 4 shared
    assert mask_iou(a, b) == 4 / 12
    assert mask_iou(a, a) == 1.0
    assert mask_iou(np.zeros((2, 2), bool), np.zeros((2, 2), bool)) == 1.0


def test_demo_with_overlay(tmp_path, capsys):
    out = tmp_path / "overlay.png"
    code = main(["demo", "--oracle", "--width", "960", "--height", "540", "--motions", "8", "--seed", "1",
                 "--noise", "0.25", "--overlay", str(out)])
    text = capsys.readouterr().out
    assert code == 0, text
    assert "T_camera_base" in text and "final error" in text
    rows = [line for line in text.splitlines() if re.match(r"\s+\d+\s+\d\s", line)]
    assert len(rows) == 8
    iou = float(re.search(r"IoU of the robot mask .*: ([0-9.]+)", text).group(1))
    assert 0.8 < iou <= 1.0
    image = cv2.imread(str(out))
    assert image is not None and image.shape == (540, 960, 3)


def test_demo_with_the_informed_planner(capsys):
    code = main(["demo", "--oracle", "--width", "320", "--height", "180", "--motions", "6", "--seed", "2",
                 "--planner", "informed"])
    text = capsys.readouterr().out
    assert code == 0, text
    assert "informed motions" in text and "final error" in text
    final = re.search(r"final error: rotation ([0-9.e+-]+) rad .*translation ([0-9.]+) mm", text)
    assert float(final.group(1)) < 0.01 and float(final.group(2)) < 10.0


def test_demo_synthetic_refuses_the_informed_planner(capsys):
    assert main(["demo", "--synthetic", "--planner", "informed"]) == 2
    assert "MuJoCo scene" in capsys.readouterr().err


def test_demo_without_enough_motions_exits_nonzero(capsys):
    code = main(["demo", "--oracle", "--width", "320", "--height", "180", "--motions", "1"])
    text = capsys.readouterr().out
    assert code == 1
    assert "no estimate" in text


def test_demo_robot_without_base_body(capsys):
    assert main(["demo", "--robot", "arm.xml"]) == 1
    assert "--base-body" in capsys.readouterr().err


def test_the_command_lines_look_choices_are_the_simulators():
    from arc_env import cli
    from arc_env.sim import background, imaging

    assert cli.REALISMS == imaging.REALISMS and cli.APPEARANCES == imaging.APPEARANCES
    assert cli.BACKGROUNDS == background.BACKGROUNDS
