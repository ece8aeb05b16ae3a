"""``report.html``: its residuals are right, it parses, it escapes names from input files, and it renders."""

import html.parser
import shutil
import subprocess

import numpy as np
import pytest

from arc_env.robot.report import (
    ReportCollector,
    _MotionTracks,
    histogram_svg,
    report_html,
    report_path,
    reprojection_residuals,
)
from arc_env.robot.session import CalibrationRun, MotionDiagnostic
from solver import Calibrator, d415_intrinsics, sample_camera_pose
from solver.frames import perturb, rotation_about_axis
from solver.observations import KeypointTrack
from solver.pipeline import CalibrationState

HOSTILE = '<script>alert("x")</script>&<img src=x onerror=alert(1)>'


def _motion(T_camera_base, intrinsics, rng, n_tracks=6, n_frames=20):
    """Tracks of points turning about a base-frame axis, projected exactly."""
    from solver.camera import pixels_from_camera_points

    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    pivot = np.array([0.3, 0.0, 0.5])
    deltas = np.linspace(0.0, 1.2, n_frames)
    tracks = []
    for _ in range(n_tracks):
        p0 = pivot + rng.normal(scale=0.15, size=3)
        p_base = (rotation_about_axis(axis, deltas) @ (p0 - pivot)) + pivot
        p_cam = p_base @ T_camera_base[:3, :3].T + T_camera_base[:3, 3]
        tracks.append(KeypointTrack(pixels_from_camera_points(p_cam, intrinsics), deltas))
    return _MotionTracks("m", axis, pivot, tracks)


def test_residuals_vanish_at_the_true_pose_and_grow_away_from_it(rng):
    intrinsics = d415_intrinsics(640, 360)
    T = sample_camera_pose(rng)
    motions = [_motion(T, intrinsics, rng) for _ in range(3)]
    at_truth = reprojection_residuals(T, motions, intrinsics)
    assert at_truth.size == 3 * 6 * 20 and np.max(at_truth) < 1e-6  # px: exact tracks, exact pose
    # away from it the triangulated points absorb part of the error, not all: 50 mrad leaves about a pixel
    off = reprojection_residuals(perturb(T, np.array([0.0, 0.05, 0.0, 0.0, 0.0, 0.0])), motions, intrinsics)
    assert np.median(off) > 0.3


class _Collect(html.parser.HTMLParser):
    def __init__(self):
        super().__init__()
        self.tags, self.rows, self.text, self._row = [], [], [], None

    def handle_starttag(self, tag, attrs):
        self.tags.append(tag)
        if tag == "tr":
            self._row = []
        if tag == "script":
            raise AssertionError("the report holds a script element")
        for name, _ in attrs:
            assert not name.startswith("on"), name

    def handle_endtag(self, tag):
        if tag == "tr" and self._row is not None:
            self.rows.append(self._row)
            self._row = None

    def handle_data(self, data):
        self.text.append(data)
        if self._row is not None and data.strip():
            self._row.append(data.strip())


def _hostile_report(rng):
    intrinsics = d415_intrinsics(640, 360)
    T = sample_camera_pose(rng)
    calibrator = Calibrator(intrinsics, lambda q, j: (np.array([0.0, 0.0, 1.0]), np.zeros(3)))
    calibrator.state = CalibrationState(T, "refined", None, np.eye(6) * 1e-6, np.full(6, 1e-3), None, False, 1, 1,
                                        0.3, "")
    diagnostics = [MotionDiagnostic("000", HOSTILE, 20, 30, True, "", 25, 0.003, 0.001, True, front_end="rigid"),
                   MotionDiagnostic(HOSTILE, "joint2", 18, 0, False, "pruned: " + HOSTILE)]
    run = CalibrationRun(f"/recordings/{HOSTILE}", calibrator, diagnostics, {"total": 1.0})
    collector = ReportCollector()
    collector.motions.append(_motion(T, intrinsics, rng))
    result = {"usable": False, "unusable_reason": HOSTILE, "quaternion": [0, 0, 0, 1], "frames": {}}
    return report_html(run, result, collector, intrinsics, {}, None)


def test_report_parses_has_a_row_per_motion_and_escapes_names_from_input_files(rng):
    page = _hostile_report(rng)
    assert page.startswith("<!DOCTYPE html>")
    assert "<script>" not in page and "<img src=x" not in page and "&lt;script&gt;" in page
    parser = _Collect()
    parser.feed(page)
    parser.close()
    motion_rows = [r for r in parser.rows if len(r) >= 10]  # the motion table's rows (header included)
    assert motion_rows[0][:2] == ["motion", "joint"]
    assert [r[0] for r in motion_rows[1:]] == ["000", HOSTILE]  # the parser unescapes: the name came through whole
    assert motion_rows[1][1] == HOSTILE and "accepted" in motion_rows[1] and "rejected" in motion_rows[2]
    assert {"svg", "table", "style"} <= set(parser.tags) and "link" not in parser.tags  # standalone
    assert "http://" not in page and "https://" not in page


def test_histogram_counts_every_value_and_clips_the_tail():
    svg = histogram_svg(np.array([0.1, 0.1, 0.3, 7.0, 9.0]), max_px=5.0, bins=5)
    titles = [t.text for t in svg.iter("title")]
    assert "0.0-1.0 px: 3" in titles and "4.0-5.0 px: 2" in titles  # 7 and 9 px land in the last bin


def test_report_path_sits_beside_the_result(tmp_path):
    assert report_path(tmp_path / "result.json") == tmp_path / "report.html"


CHROMIUM = next((shutil.which(c) for c in ("chromium-headless-shell", "chromium", "chromium-browser")
                 if shutil.which(c)), None)


@pytest.mark.skipif(CHROMIUM is None, reason="no headless Chromium (apt install chromium-headless-shell)")
def test_report_renders_in_headless_chromium(rng, tmp_path):
    import cv2

    page = tmp_path / "report.html"
    page.write_text(_hostile_report(rng))
    shot = tmp_path / "shot.png"
    subprocess.run([CHROMIUM, "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--window-size=1000,1400",
                    f"--screenshot={shot}", page.as_uri()], check=True, capture_output=True, timeout=60)
    image = cv2.imread(str(shot))
    assert image.shape[:2] == (1400, 1000)
    # the "not usable" verdict box is drawn in its background colour (#f8dcd9, BGR below) over a wide area,
    # and the histogram's bars (#4a78c2): the CSS and the inline SVG were applied
    for bgr, at_least in (((0xd9, 0xdc, 0xf8), 5000), ((0xc2, 0x78, 0x4a), 500)):
        assert np.sum(np.all(np.abs(image.astype(int) - bgr) <= 2, axis=2)) >= at_least, bgr


def test_collector_keeps_only_motions_the_calibrator_took_and_restarts_on_a_new_pass(rng):
    from arc_env.robot.session import MotionOutcome, SeenMotion
    from solver.errors import InvalidInputError

    def kinematics(q, joint):
        if joint == 6:
            raise InvalidInputError("the model rejects joint 6")
        return np.array([0.0, 0.0, 1.0]), np.zeros(3)

    calibrator = Calibrator(d415_intrinsics(640, 360), kinematics)
    track = KeypointTrack(np.zeros((5, 2)), np.linspace(0.0, 0.5, 5))
    taken = MotionOutcome(1, 1, True, "", report=object())
    refused = MotionOutcome(6, 1, False, "the robot model rejects this motion")
    collector = ReportCollector()
    for index, joint, outcome in ((0, 1, taken), (1, 6, refused), (2, 1, taken)):
        collector(SeenMotion(index, np.zeros(7), joint, track.delta, None, [track], outcome, calibrator))
    assert [m.name for m in collector.motions] == ["000", "002"] and len(collector.history) == 3
    collector(SeenMotion(0, np.zeros(7), 1, track.delta, None, [track], taken, calibrator, "000"))  # pass 2
    assert [m.name for m in collector.motions] == ["000"] and len(collector.history) == 1
