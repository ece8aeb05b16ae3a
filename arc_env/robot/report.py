"""``report.html``: one calibration for a person to read, in one standalone file (no network).

``arc-calib calibrate`` writes it beside the result (``report_path``: ``report.html`` beside ``result.json``),
committed with the result and its exports, for usable and unusable results alike. It holds the verdict
and the estimate, a table of the motions (joint, front end, axis error, tracks kept, accepted or why not),
a histogram of the reprojection residuals of every track at the final pose, the 1-sigma (and, in
simulation, the true error) over the motions, and the overlay images as PNG data URIs. Charts are inline
SVG and the style is inline CSS.

The document is built as an element tree and serialized by ``xml.etree.ElementTree`` (HTML method), which
escapes every text and attribute: names from input files (recording paths, joint and motion names,
reasons) never reach the page unescaped.

``ReportCollector`` is the ``CalibrationSession`` observer that keeps what the report needs from each
motion (its tracks, the estimate's 1-sigma after it); the residuals are recomputed here at the final pose
(``reprojection_residuals``: each track's point triangulated, then projected through the lens model).
"""

from __future__ import annotations

import base64
import xml.etree.ElementTree as ET
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from arc_env.robot.session import CalibrationRun, SeenMotion
from solver.arrays import FloatArray
from solver.camera import normalized_from_pixels, pixels_from_camera_points
from solver.errors import InsufficientMotionsError
from solver.frames import pose_errors
from solver.observations import CameraIntrinsics, KeypointTrack
from solver.refinement import RefinementConfig, build_track_set, triangulate_tracks

#: Residuals at or above this many px share the histogram's last bin.
HISTOGRAM_MAX_PX = 5.0
HISTOGRAM_BINS = 25

_CSS = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1100px; color: #222; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; margin-top: 1.6em; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; font-size: 0.9em; }
td, th { border: 1px solid #ccc; padding: 0.25em 0.5em; text-align: right; vertical-align: top; }
td.text, th.text { text-align: left; }
tr.accepted td.status { color: #176b2c; font-weight: bold; }
tr.rejected td.status { color: #a3231a; font-weight: bold; }
.verdict { padding: 0.6em 1em; border-radius: 4px; display: inline-block; }
.usable { background: #dff3e3; } .unusable { background: #f8dcd9; }
.charts { display: flex; flex-wrap: wrap; gap: 1.5em; }
figure { margin: 0; } figcaption { font-size: 0.85em; color: #555; max-width: 520px; }
img { max-width: 100%; border: 1px solid #ccc; }
code { font-size: 0.9em; }
"""


def report_path(output: Path) -> Path:
    """The report of result file ``output``: ``report.html`` beside it (the name the issue gives users)."""
    return Path(output).with_name("report.html")


@dataclass
class _MotionTracks:
    name: str
    axis_base: FloatArray
    point_base: FloatArray
    tracks: Sequence[KeypointTrack]


@dataclass
class ReportCollector:
    """Keeps, from each motion the calibrator takes, what the report needs (a ``CalibrationSession`` observer).

    Args:
        T_camera_base_true: (4, 4) float64, metres: the true pose (simulation), or None.

    Attributes:
        motions: per motion the calibrator took: its name, joint axis and point (base frame, at Q) and tracks.
        history: per motion seen: (name, 1-sigma (6,) rad and m or None, true error (rad, m) or None).
    """

    T_camera_base_true: FloatArray | None = None
    motions: list[_MotionTracks] = field(default_factory=list)
    history: list[tuple[str, FloatArray | None, tuple[float, float] | None]] = field(default_factory=list)
    _last_index: int = -1

    def __call__(self, seen: SeenMotion) -> None:
        """Take one motion (a new pass over the same motions starts over)."""
        if seen.index <= self._last_index:
            self.motions.clear()
            self.history.clear()
        self._last_index = seen.index
        name = seen.name or f"{seen.index:03d}"
        if seen.outcome.report is not None:  # the calibrator took it (the robot model accepted the motion)
            axis, point = seen.calibrator.kinematics(seen.q_start, seen.joint)
            self.motions.append(_MotionTracks(name, np.asarray(axis, float), np.asarray(point, float), seen.tracks))
        s = seen.calibrator.state
        error = (pose_errors(s.T_camera_base, self.T_camera_base_true)
                 if s.T_camera_base is not None and self.T_camera_base_true is not None else None)
        self.history.append((name, None if s.std is None else s.std.copy(), error))


def reprojection_residuals(T_camera_base: FloatArray, motions: Sequence[_MotionTracks],
                           intrinsics: CameraIntrinsics, min_frames: int = RefinementConfig.min_track_frames
                           ) -> FloatArray:
    """Reprojection residuals of every track at a pose, px.

    Each track's point is triangulated at ``T_camera_base`` (4, 4, metres) from its rays and the known
    turns (``solver.refinement.triangulate_tracks``), then projected at every frame through the lens
    model; tracks shorter than ``min_frames`` or that triangulate behind the camera are left out. Unlike
    the bundle adjustment's RMS, outlier tracks are included.

    Returns:
        (P,) float64, px: the distance between the projected and the tracked pixel of every observation.
    """
    kept = [[t for t in m.tracks if len(t.pixels) >= min_frames] for m in motions]
    triples = [(m.axis_base, m.point_base, [(normalized_from_pixels(t.pixels, intrinsics), t.delta) for t in ts])
               for m, ts in zip(motions, kept, strict=True) if ts]
    if not triples:
        return np.zeros(0)
    try:
        tracks = build_track_set(triples, intrinsics.focal, min_frames)
    except InsufficientMotionsError:
        return np.zeros(0)
    observed = np.concatenate([t.pixels for ts in kept for t in ts])
    points, ok = triangulate_tracks(tracks, T_camera_base)
    R, t = T_camera_base[:3, :3], T_camera_base[:3, 3]
    pivot = tracks.pivot[tracks.track]
    p_base = np.einsum("pij,pj->pi", tracks.rot, points[tracks.track] - pivot) + pivot
    p_cam = p_base @ R.T + t
    use = ok[tracks.track] & (p_cam[:, 2] > 1e-6)
    if not use.any():
        return np.zeros(0)
    predicted = pixels_from_camera_points(p_cam[use], intrinsics)
    return np.linalg.norm(predicted - observed[use], axis=1)


# -- charts (inline SVG) ------------------------------------------------------------------------------
_W, _H, _PAD = 520, 260, 64


def _svg(title: str) -> ET.Element:
    svg = ET.Element("svg", width=str(_W), height=str(_H), viewBox=f"0 0 {_W} {_H}", role="img")
    ET.SubElement(svg, "title").text = title
    ET.SubElement(svg, "rect", x="0", y="0", width=str(_W), height=str(_H), fill="white")
    return svg


def _text(parent: ET.Element, x: float, y: float, text: str, anchor: str = "middle", size: int = 11) -> None:
    ET.SubElement(parent, "text", {"x": f"{x:.1f}", "y": f"{y:.1f}", "text-anchor": anchor,
                                   "font-size": str(size), "fill": "#333"}).text = text


def _axes(svg: ET.Element, x_label: str, y_label: str, y_max: float, x_ticks: Sequence[tuple[float, str]],
          counts: bool = False) -> None:
    x0, y0, x1, y1 = _PAD, _H - _PAD, _W - 12, 14
    ET.SubElement(svg, "path", d=f"M{x0},{y1} L{x0},{y0} L{x1},{y0}", stroke="#555", fill="none")
    for k in range(5):
        v = y_max * k / 4
        y = y0 - (y0 - y1) * k / 4
        ET.SubElement(svg, "line", x1=str(x0 - 4), y1=f"{y:.1f}", x2=str(x1), y2=f"{y:.1f}", stroke="#eee")
        _text(svg, x0 - 6, y + 4, f"{v:.0f}" if counts else f"{v:.3g}", anchor="end", size=10)
    for x, label in x_ticks:
        _text(svg, x, y0 + 14, label, size=10)
    _text(svg, (x0 + x1) / 2, _H - 8, x_label)
    label = ET.SubElement(svg, "text", {"x": "12", "y": f"{(y0 + y1) / 2:.1f}", "font-size": "11", "fill": "#333",
                                        "text-anchor": "middle", "transform": f"rotate(-90 12 {(y0 + y1) / 2:.1f})"})
    label.text = y_label


def histogram_svg(values: FloatArray, max_px: float = HISTOGRAM_MAX_PX, bins: int = HISTOGRAM_BINS) -> ET.Element:
    """A histogram of residuals (P,) px as an SVG element; values >= max_px go to the last bin."""
    svg = _svg("reprojection residuals")
    counts, edges = np.histogram(np.clip(values, 0.0, np.nextafter(max_px, 0.0)), bins=bins, range=(0.0, max_px))
    top = max(int(counts.max()) if counts.size else 0, 1)
    x0, y0, x1, y1 = _PAD, _H - _PAD, _W - 12, 14
    width = (x1 - x0) / bins
    for k, c in enumerate(counts):
        h = (y0 - y1) * c / top
        bar = ET.SubElement(svg, "rect", x=f"{x0 + k * width + 1:.1f}", y=f"{y0 - h:.1f}", width=f"{width - 2:.1f}",
                            height=f"{h:.1f}", fill="#4a78c2" if k < bins - 1 else "#c2574a")
        ET.SubElement(bar, "title").text = f"{edges[k]:.1f}-{edges[k + 1]:.1f} px: {c}"
    ticks = [(x0 + (x1 - x0) * f, f"{max_px * f:g}" + ("+" if f == 1 else "")) for f in (0, 0.25, 0.5, 0.75, 1.0)]
    _axes(svg, "residual, px (last bar: this or more)", "observations", top, ticks, counts=True)
    return svg


def line_chart_svg(title: str, y_label: str, x_names: Sequence[str],
                   series: Mapping[str, tuple[Sequence[float | None], str]]) -> ET.Element:
    """Lines over motions as an SVG element: {label: (value per motion or None, colour)}."""
    svg = _svg(title)
    values = [v for ys, _ in series.values() for v in ys if v is not None and np.isfinite(v)]
    top = max(values) * 1.1 if values else 1.0
    top = top if top > 0 else 1.0
    n = len(x_names)
    x0, y0, x1, y1 = _PAD, _H - _PAD, _W - 12, 14

    def xy(i: int, v: float) -> tuple[float, float]:
        return x0 + (x1 - x0) * (i + 0.5) / max(n, 1), y0 - (y0 - y1) * min(v, top) / top

    step = max(1, n // 12)
    _axes(svg, "motion", y_label, top, [(xy(i, 0)[0], x_names[i]) for i in range(0, n, step)])
    for k, (label, (ys, colour)) in enumerate(series.items()):
        pts = [xy(i, v) for i, v in enumerate(ys) if v is not None and np.isfinite(v)]
        if len(pts) >= 2:
            ET.SubElement(svg, "polyline", points=" ".join(f"{x:.1f},{y:.1f}" for x, y in pts), fill="none",
                          stroke=colour, **{"stroke-width": "2"})
        for x, y in pts:
            ET.SubElement(svg, "circle", cx=f"{x:.1f}", cy=f"{y:.1f}", r="2.5", fill=colour)
        ET.SubElement(svg, "rect", x=str(x1 - 210), y=str(y1 + 4 + 16 * k), width="10", height="10", fill=colour)
        _text(svg, x1 - 195, y1 + 13 + 16 * k, label, anchor="start", size=10)
    return svg


# -- the document ---------------------------------------------------------------------------------------
def _table(parent: ET.Element, header: Sequence[str], rows: Sequence[tuple[Sequence[str], str]],
           text_columns: Sequence[int] = ()) -> ET.Element:
    table = ET.SubElement(parent, "table")
    tr = ET.SubElement(ET.SubElement(table, "thead"), "tr")
    for k, h in enumerate(header):
        ET.SubElement(tr, "th", {"class": "text"} if k in text_columns else {}).text = h
    body = ET.SubElement(table, "tbody")
    for cells, css in rows:
        tr = ET.SubElement(body, "tr", {"class": css} if css else {})
        for k, c in enumerate(cells):
            classes = " ".join((["text"] if k in text_columns else []) + (["status"] if header[k] == "status" else []))
            ET.SubElement(tr, "td", {"class": classes} if classes else {}).text = c
    return table


def _fmt(v: float | None, scale: float = 1.0, digits: int = 2) -> str:
    return "-" if v is None else f"{v * scale:.{digits}f}"


def report_html(run: CalibrationRun, result: Mapping[str, Any] | None, collector: ReportCollector,
                intrinsics: CameraIntrinsics, overlays: Mapping[Path, bytes] | None = None,
                T_camera_base_true: FloatArray | None = None) -> str:
    """The report of a finished calibration as one standalone HTML document.

    Args:
        run: the calibration (its diagnostics give the table).
        result: the result dict (``arc_env.robot.exports.result_dict``), or None when there is no estimate.
        collector: the tracks and 1-sigma history of the motions.
        intrinsics: the camera.
        overlays: {file: PNG bytes} images to show (the ``--overlay`` images), embedded as data URIs.
        T_camera_base_true: (4, 4) float64, metres: the true pose (simulation), or None.
    """
    s = run.calibrator.state
    html = ET.Element("html", lang="en")
    head = ET.SubElement(html, "head")
    ET.SubElement(head, "meta", charset="utf-8")
    ET.SubElement(head, "title").text = f"ARC-Calib report: {run.source}"
    ET.SubElement(head, "style").text = _CSS
    body = ET.SubElement(html, "body")
    ET.SubElement(body, "h1").text = "ARC-Calib calibration report"
    p = ET.SubElement(body, "p")
    p.text = "Source: "
    ET.SubElement(p, "code").text = run.source
    usable = bool(result is not None and result.get("usable"))
    verdict = ET.SubElement(body, "p", {"class": "verdict " + ("usable" if usable else "unusable")})
    if usable:
        verdict.text = "Usable: the result and its ROS exports were written."
    else:
        why = result.get("unusable_reason", "") if result is not None else s.message
        verdict.text = f"Not usable: {why}"

    ET.SubElement(body, "h2").text = "Estimate"
    rows: list[tuple[Sequence[str], str]] = [(("stage", s.stage), ""), (("converged", str(s.converged)), "")]
    if s.T_camera_base is not None:
        T = s.T_camera_base
        rows.append((("T_camera_base (p_camera = T p_base, OpenCV optical)",
                      "; ".join(" ".join(f"{v:+.5f}" for v in r) for r in T[:3])), ""))
        if result is not None:
            rows.append((("quaternion (x, y, z, w)", " ".join(f"{v:+.6f}" for v in result["quaternion"])), ""))
    if s.std is not None:
        rows.append((("1-sigma rotation, deg", " ".join(f"{v:.3f}" for v in np.degrees(s.std[:3]))), ""))
        rows.append((("1-sigma translation, mm", " ".join(f"{v:.2f}" for v in s.std[3:] * 1e3)), ""))
    if s.rms_px is not None:
        rows.append((("RMS reprojection (bundle adjustment, kept tracks), px", f"{s.rms_px:.3f}"), ""))
    if result is not None and result.get("time_offset_std_s") is not None:
        rows.append((("time offset t_joint - t_camera, ms",
                      f"{result['time_offset_s'] * 1e3:+.2f} (1-sigma {result['time_offset_std_s'] * 1e3:.2f})"), ""))
    if T_camera_base_true is not None and s.T_camera_base is not None:
        rot, trans = pose_errors(s.T_camera_base, T_camera_base_true)
        rows.append((("true error (simulation)", f"rotation {np.degrees(rot):.4f} deg, translation "
                                                 f"{trans * 1e3:.3f} mm"), ""))
    if result is not None:
        frames = result.get("frames") or {}
        rows.append((("TF frames", f"{frames.get('parent', '-')} -> {frames.get('child', '-')}"), ""))
    rows.append((("motions", f"{len(run.diagnostics)}, {run.n_accepted} accepted"), ""))
    rows.append((("time, s", ", ".join(f"{k} {v:.1f}" for k, v in run.seconds.items())), ""))
    _table(body, ("quantity", "value"), rows, text_columns=(0, 1))

    ET.SubElement(body, "h2").text = "Motions"
    fronts = {"rigid": "rigid", "conics": "conics", "": "none"}
    motion_rows = []
    for d in run.diagnostics:
        status = "accepted" if d.accepted else "rejected"
        motion_rows.append(((d.motion, d.joint or "-", str(d.frames), str(d.tracks), str(d.inlier_tracks),
                             fronts.get(d.front_end, d.front_end), _fmt(d.axis_error_rad, 1e3),
                             _fmt(d.plane_distance_m, 1e3), "yes" if d.linear else "no", status,
                             d.reason or d.note), status))
    _table(body, ("motion", "joint", "frames", "tracks", "tracks kept", "front end", "axis error, mrad",
                  "plane distance, mm", "linear stage", "status", "reason / note"), motion_rows,
           text_columns=(0, 1, 5, 10))

    ET.SubElement(body, "h2").text = "Residuals and uncertainty"
    charts = ET.SubElement(body, "div", {"class": "charts"})
    if s.T_camera_base is not None:
        residuals = reprojection_residuals(s.T_camera_base, collector.motions, intrinsics)
        fig = ET.SubElement(charts, "figure", id="residuals")
        fig.append(histogram_svg(residuals))
        caption = ET.SubElement(fig, "figcaption")
        caption.text = (f"Reprojection residuals at the final pose: {residuals.size} observations of every track "
                        "(each point triangulated at this pose), outlier tracks included"
                        + (f"; median {np.median(residuals):.2f} px, 95th percentile "
                           f"{np.percentile(residuals, 95):.2f} px." if residuals.size else "."))
    names = [h[0] for h in collector.history]
    rot_sigma = [None if h[1] is None else float(np.max(np.degrees(h[1][:3]))) for h in collector.history]
    trans_sigma = [None if h[1] is None else float(np.max(h[1][3:]) * 1e3) for h in collector.history]
    for key, title, unit, sigma, k, scale in (("sigma-rotation", "rotation", "deg", rot_sigma, 0, np.degrees(1.0)),
                                              ("sigma-translation", "translation", "mm", trans_sigma, 1, 1e3)):
        series: dict[str, tuple[Sequence[float | None], str]] = {f"1-sigma (largest component), {unit}":
                                                                 (sigma, "#e07b28")}
        if any(h[2] is not None for h in collector.history):
            series[f"true error, {unit}"] = ([None if h[2] is None else h[2][k] * scale for h in collector.history],
                                            "#c2574a")
        fig = ET.SubElement(charts, "figure", id=key)
        fig.append(line_chart_svg(f"{title} over motions", f"{title}, {unit}", names, series))
        ET.SubElement(fig, "figcaption").text = (f"The estimate's {title} 1-sigma after each motion (none before "
                                                 "the first refined estimate).")

    ET.SubElement(body, "h2").text = "Overlays"
    if overlays:
        for path, png in overlays.items():
            fig = ET.SubElement(body, "figure")
            ET.SubElement(fig, "img", src="data:image/png;base64," + base64.b64encode(png).decode("ascii"),
                          alt=f"overlay {Path(path).name}")
            ET.SubElement(fig, "figcaption").text = f"{Path(path).name}: the robot model drawn with the estimate."
    else:
        ET.SubElement(body, "p").text = ("None: pass --overlay DIR to draw the robot with the estimate (written for "
                                         "usable results only).")
    return "<!DOCTYPE html>\n" + ET.tostring(html, encoding="unicode", method="html") + "\n"


def fan_out(*observers: Callable[[SeenMotion], None] | None) -> Callable[[SeenMotion], None]:
    """One observer calling each of ``observers`` (None entries skipped) in turn."""
    live = [o for o in observers if o is not None]

    def observe(seen: SeenMotion) -> None:
        for o in live:
            o(seen)

    return observe
