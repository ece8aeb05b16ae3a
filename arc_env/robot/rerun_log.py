"""A calibration episode logged to Rerun (``rerun-sdk``): ``--rerun`` opens a viewer, ``--rerun-save FILE.rrd`` a file.

``RerunLog`` is a ``CalibrationSession`` observer (``arc_env.robot.session.SeenMotion``): after each motion
the calibrator took it logs, on two timelines (``motion``: the motion's index; ``frame``: a running count
of the logged frames), these entities (``ENTITIES``; names are the contract the tests check):

* ``image``: the camera's frames (JPEG, at most ``RerunLogConfig.frames_per_motion`` per motion) with
  ``image/tracks`` (each keypoint track up to that frame), ``image/ellipses`` (an ellipse fitted to each
  track, in normalized coordinates, drawn through the lens model), ``image/axis`` (stage one's rotation
  axis: the image of the plane through the camera centre that holds it, ``MotionGeometry.plane_normal``)
  and ``image/axis_estimate`` (the joint's axis from the kinematics, projected with the current estimate);
* ``world`` (the robot's base frame, metres): ``world/robot/links/<body>`` (each link's pose per logged
  frame, with its visual meshes, static, below it), ``world/robot/skeleton`` (the link origins joined
  parent to child), ``world/robot/joint_axes`` (every joint's axis) and ``world/robot/motion_axis`` (the
  turning one); ``world/camera`` (the estimate, ``T_camera_base``, from the first estimate on) with
  ``world/camera/frustum`` (its Pinhole) and ``world/camera/sigma`` (the 1-sigma ellipsoid of the camera
  centre, labelled with the 1-sigma of rotation and translation); ``world/camera_true`` (the true camera
  and its frustum, when the simulator knows it);
* scalars over motions: ``curves/rotation_deg/sigma`` and ``curves/translation_mm/sigma`` (the largest
  1-sigma component), with ``curves/rotation_deg/error`` and ``curves/translation_mm/error`` beside them
  only where the truth is known (simulation), ``curves/rms_px`` (reprojection) and ``curves/accepted``;
* ``log``: one line per motion (accepted or why not); ``estimate``: the current estimate as text.

The log carries a default layout (``blueprint``): the image, the 3-D scene, the curves, the text.

Frames: the camera is OpenCV optical (``RDF``); the base frame is drawn Z up. The Pinhole carries K only:
lens distortion is applied where this module projects (axes, ellipses), not by the viewer.

This module serves real robots: it never imports the simulator; callers pass ground truth when they have it.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from arc_env.robot.model import RobotModel
from arc_env.robot.session import SeenMotion
from solver.arrays import FloatArray, evenly_spaced
from solver.camera import normalized_from_pixels, pixels_from_camera_points
from solver.conics import fit_ellipse_direct
from solver.errors import ArcCalibError, InvalidInputError
from solver.frames import pose_errors, quaternion_xyzw_from_matrix, skew
from solver.observations import CameraIntrinsics, KeypointTrack
from solver.pipeline import CalibrationState, Calibrator

#: The entities a log holds (``world/robot/links/<body>`` per link besides).
ENTITIES = (
    "image", "image/tracks", "image/ellipses", "image/axis", "image/axis_estimate",
    "world/robot/skeleton", "world/robot/joint_axes", "world/robot/motion_axis",
    "world/camera", "world/camera/frustum", "world/camera/sigma",
    "curves/rotation_deg/sigma", "curves/translation_mm/sigma", "curves/rms_px", "curves/accepted",
    "log", "estimate",
)
#: Entities logged only with a known true pose (simulation).
TRUTH_ENTITIES = ("world/camera_true", "world/camera_true/frustum", "curves/rotation_deg/error",
                  "curves/translation_mm/error")


@dataclass(frozen=True)
class RerunLogConfig:
    """What a ``RerunLog`` logs.

    Attributes:
        frames_per_motion: most frames logged per motion (evenly spaced; images, tracks, robot pose).
        jpeg_quality: JPEG quality of the logged frames, 1-100.
        max_ellipses: most tracks per motion given an ellipse (the longest ones).
        meshes: log the robot's visual meshes (static, once) below its links.
        frustum_m: m, the drawn distance of the camera frustum's image plane.
    """

    frames_per_motion: int = 12
    jpeg_quality: int = 80
    max_ellipses: int = 30
    meshes: bool = True
    frustum_m: float = 0.15

    def __post_init__(self) -> None:
        if self.frames_per_motion < 1 or not 1 <= self.jpeg_quality <= 100 or self.max_ellipses < 0:
            raise InvalidInputError("need frames_per_motion >= 1, 1 <= jpeg_quality <= 100 and max_ellipses >= 0, "
                                    f"got {self.frames_per_motion}, {self.jpeg_quality}, {self.max_ellipses}")


def ellipse_points(Q: FloatArray, n: int = 64) -> FloatArray | None:
    """Points around the ellipse of conic matrix Q (3, 3) (``solver.conics``): (n + 1, 2), closed, Q's units.

    Returns None when Q is not a real ellipse.
    """
    A, b, c = Q[:2, :2], Q[:2, 2], Q[2, 2]
    try:
        centre = -np.linalg.solve(A, b)
    except np.linalg.LinAlgError:
        return None
    k = float(centre @ A @ centre - c)  # (x - centre)^T A (x - centre) = k
    eigval, eigvec = np.linalg.eigh(A)
    if k == 0 or not np.all(eigval * k > 0):
        return None
    t = np.linspace(0.0, 2 * np.pi, n + 1)
    unit = np.stack([np.cos(t), np.sin(t)], axis=1)
    return centre + (unit * np.sqrt(k / eigval)) @ eigvec.T


def _normalized_bounds(intrinsics: CameraIntrinsics) -> tuple[FloatArray, FloatArray]:
    w, h = intrinsics.width, intrinsics.height
    border = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1], [(w - 1) / 2, 0], [(w - 1) / 2, h - 1],
                       [0, (h - 1) / 2], [w - 1, (h - 1) / 2]], dtype=np.float64)
    uv = normalized_from_pixels(border, intrinsics)
    return uv.min(axis=0), uv.max(axis=0)


def _to_pixels(uv: FloatArray, intrinsics: CameraIntrinsics) -> FloatArray:
    return pixels_from_camera_points(np.column_stack([uv, np.ones(len(uv))]), intrinsics)


def axis_image_line(plane_normal: FloatArray, intrinsics: CameraIntrinsics, n: int = 50) -> FloatArray | None:
    """The image of a line through space whose plane with the camera centre has normal ``plane_normal``.

    Args:
        plane_normal: (3,) float64, unitless: rho, camera frame (``MotionGeometry.plane_normal``).
        intrinsics: the camera (distortion applied).
        n: points along the line.

    Returns:
        (n, 2) float64, pixels: the line {(u, v): rho . (u, v, 1) = 0} across the image's extent, or None
        when it misses the image.
    """
    lo, hi = _normalized_bounds(intrinsics)
    normal = np.asarray(plane_normal, dtype=np.float64)
    g = normal[:2]
    if np.linalg.norm(g) < 1e-12:
        return None
    p0 = -normal[2] * g / (g @ g)
    d = np.array([g[1], -g[0]]) / np.linalg.norm(g)
    t0, t1 = -np.inf, np.inf  # Liang-Barsky clip of p0 + t d to the box [lo, hi]
    for k in range(2):
        if abs(d[k]) < 1e-12:
            if not lo[k] <= p0[k] <= hi[k]:
                return None
            continue
        a, b = sorted(((lo[k] - p0[k]) / d[k], (hi[k] - p0[k]) / d[k]))
        t0, t1 = max(t0, a), min(t1, b)
    if not t0 < t1:
        return None
    return _to_pixels(p0 + np.linspace(t0, t1, n)[:, None] * d, intrinsics)


def segment_pixels(a_cam: FloatArray, b_cam: FloatArray, intrinsics: CameraIntrinsics, n: int = 50,
                   min_depth_m: float = 0.02) -> FloatArray | None:
    """A 3-D segment a_cam -> b_cam ((3,) each, metres, camera frame) as (m, 2) pixels, the part in front of the camera.

    Returns None when less than two of its n sample points are in front (depth > ``min_depth_m``).
    """
    pts = a_cam + np.linspace(0.0, 1.0, n)[:, None] * (b_cam - a_cam)
    pts = pts[pts[:, 2] > min_depth_m]
    return pixels_from_camera_points(pts, intrinsics) if len(pts) >= 2 else None


def camera_centre_covariance(T_camera_base: FloatArray, covariance: FloatArray) -> FloatArray:
    """Covariance of the camera centre, (3, 3) m^2 in the camera frame, from the pose's (6, 6) one.

    The pose is perturbed as R = Exp(omega) R_hat, t = t_hat + tau (``solver.refinement``); the centre
    c = -R^T t then moves by R_hat dc = -([t_hat]x omega + tau) to first order.

    Args:
        T_camera_base: (4, 4) float64, metres: the estimate.
        covariance: (6, 6) float64: of (omega rad, tau m).
    """
    M = -np.hstack([skew(T_camera_base[:3, 3]), np.eye(3)])
    return M @ covariance @ M.T


def frame_indices(track: KeypointTrack, deltas: FloatArray) -> FloatArray:
    """The frame of each point of ``track``: the index of the nearest of the motion's deltas (F,) rad, (M,) int."""
    return np.argmin(np.abs(track.delta[:, None] - deltas[None, :]), axis=1)


def _rgba(rgb: Sequence[int], a: int = 255) -> list[int]:
    return [*rgb, a]


def blueprint() -> rrb.Blueprint:
    """The default layout: the image and the 3-D scene on top; curves, the estimate and the log below."""
    return rrb.Blueprint(rrb.Vertical(
        rrb.Horizontal(rrb.Spatial2DView(origin="image", name="camera image"),
                       rrb.Spatial3DView(origin="world", name="robot base frame")),
        rrb.Horizontal(rrb.TimeSeriesView(origin="curves/rotation_deg", name="rotation, deg"),
                       rrb.TimeSeriesView(origin="curves/translation_mm", name="translation, mm"),
                       rrb.Vertical(rrb.TimeSeriesView(origin="curves/rms_px", name="RMS reprojection, px"),
                                    rrb.TimeSeriesView(origin="curves/accepted", name="motions accepted")),
                       rrb.TextDocumentView(origin="estimate", name="estimate"),
                       rrb.TextLogView(origin="log", name="motions")),
        row_shares=[3, 2]), collapse_panels=True)


class RerunLog:
    """An episode's Rerun log: a ``CalibrationSession`` observer (call it with each ``SeenMotion``).

    Use as a context manager, or call ``close`` at the end: with ``save`` the file is written under a
    temporary name and renamed to ``save`` there (a run that dies leaves no half file under that name).

    Args:
        robot: the robot model (kinematics and meshes; a private MuJoCo state is used, never ``robot.data``).
        intrinsics: the camera.
        save: the .rrd file to write, or None.
        spawn: open (or connect to) a Rerun viewer.
        name: the recording's name in the viewer.
        T_camera_base_true: (4, 4) float64, metres: the true pose (simulation), or None.
        config: what to log.

    Raises:
        InvalidInputError: neither ``save`` nor ``spawn``, or ``save`` does not end in .rrd.
    """

    def __init__(self, robot: RobotModel, intrinsics: CameraIntrinsics, save: Path | None = None,
                 spawn: bool = False, name: str = "arc-calib", T_camera_base_true: FloatArray | None = None,
                 config: RerunLogConfig | None = None):
        if save is None and not spawn:
            raise InvalidInputError("RerunLog needs a file to save to, a viewer to spawn, or both")
        if save is not None and Path(save).suffix != ".rrd":
            raise InvalidInputError(f"--rerun-save must name a .rrd file, got {save}")
        self.robot = robot
        self.intrinsics = intrinsics
        self.config = config or RerunLogConfig()
        self.save = Path(save) if save is not None else None
        self._partial = self.save.with_name(f".{self.save.name}.partial") if self.save is not None else None
        self.rec = rr.RecordingStream("arc_calib")
        self.rec.send_recording_name(name)
        if spawn:
            self.rec.spawn(connect=self._partial is None, default_blueprint=blueprint())
        if self._partial is not None:
            sinks: list[rr.GrpcSink | rr.FileSink] = [rr.FileSink(str(self._partial))]
            if spawn:
                sinks.insert(0, rr.GrpcSink())
            self.rec.set_sinks(*sinks, default_blueprint=blueprint())
        self._data = mujoco.MjData(robot.model)
        self._T_base_world = np.linalg.inv(robot.T_world_base)
        self._bodies = [b for b in robot.robot_bodies if b != robot.base_body]
        m = robot.model
        self._names = {b: rr.escape_entity_path_part(m.body(b).name or f"body{b}") for b in robot.robot_bodies}
        self._frame = 0
        self._last_index = -1
        self._pass = 1
        self._frustum = False
        self.T_camera_base_true: FloatArray | None = None
        self._log_static()
        if T_camera_base_true is not None:
            self.set_truth(T_camera_base_true)

    # -- set-up -----------------------------------------------------------------------------------
    def _log_static(self) -> None:
        rec = self.rec
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        for path, color, name in (("curves/rotation_deg/sigma", (230, 120, 40), "1-sigma rotation, deg (largest)"),
                                  ("curves/translation_mm/sigma", (230, 120, 40), "1-sigma translation, mm (largest)"),
                                  ("curves/rotation_deg/error", (200, 40, 40), "true rotation error, deg"),
                                  ("curves/translation_mm/error", (200, 40, 40), "true translation error, mm"),
                                  ("curves/rms_px", (120, 120, 120), "RMS reprojection, px"),
                                  ("curves/accepted", (40, 160, 40), "motions accepted")):
            rec.log(path, rr.SeriesLines(colors=[_rgba(color)], names=[name]), static=True)
        if self.config.meshes:
            self._log_meshes()

    def _log_meshes(self) -> None:
        """Each link's drawn mesh geoms, in the link's frame, static (primitive geoms are left out)."""
        m = self.robot.model
        per_body: dict[int, tuple[list[FloatArray], list[FloatArray]]] = {}
        for g in self.robot.rendered_geoms():
            if m.geom_type[g] != mujoco.mjtGeom.mjGEOM_MESH:
                continue
            mid = m.geom_dataid[g]
            verts = m.mesh_vert[m.mesh_vertadr[mid]:m.mesh_vertadr[mid] + m.mesh_vertnum[mid]].astype(np.float64)
            faces = m.mesh_face[m.mesh_faceadr[mid]:m.mesh_faceadr[mid] + m.mesh_facenum[mid]].astype(np.int64)
            R = np.zeros(9)
            mujoco.mju_quat2Mat(R, m.geom_quat[g])
            verts = verts @ R.reshape(3, 3).T + m.geom_pos[g]
            vs, fs = per_body.setdefault(int(m.geom_bodyid[g]), ([], []))
            fs.append(faces + sum(len(v) for v in vs))
            vs.append(verts)
        for b, (vs, fs) in per_body.items():
            if b not in self._names:
                continue
            self.rec.log(f"world/robot/links/{self._names[b]}/mesh",
                         rr.Mesh3D(vertex_positions=np.concatenate(vs), triangle_indices=np.concatenate(fs),
                                   albedo_factor=_rgba((200, 200, 210), 200)), static=True)

    def set_truth(self, T_camera_base_true: FloatArray) -> None:
        """Log the true camera (simulation): ``world/camera_true``; the error curves follow from here on."""
        self.T_camera_base_true = np.asarray(T_camera_base_true, dtype=np.float64)
        cam = self.intrinsics
        T = self.T_camera_base_true
        self.rec.log("world/camera_true", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3],
                                                         relation=rr.TransformRelation.ChildFromParent), static=True)
        self.rec.log("world/camera_true/frustum",
                     rr.Pinhole(image_from_camera=cam.K, resolution=[cam.width, cam.height],
                                camera_xyz=rr.ViewCoordinates.RDF, color=_rgba((60, 200, 60)),
                                image_plane_distance=self.config.frustum_m), static=True)

    # -- per motion -------------------------------------------------------------------------------
    def _time(self, motion: int) -> None:
        self.rec.set_time("motion", sequence=motion)
        self.rec.set_time("frame", sequence=self._frame)

    def __call__(self, seen: SeenMotion) -> None:
        """Log one motion: its frames with tracks and the posed robot, its geometry, then the estimate."""
        if seen.index <= self._last_index:  # calibrate reads the recording again (time offset): a new pass
            self._pass += 1
            self._time(seen.index)
            self.rec.log("log", rr.TextLog(f"pass {self._pass}: the motions again, joints read at the corrected "
                                           "time offset", level="INFO"))
        self._last_index = seen.index
        cfg = self.config
        deltas = np.asarray(seen.deltas, dtype=np.float64)
        n_frames = len(deltas)
        frame_of = [frame_indices(t, deltas) for t in seen.tracks]
        for k in evenly_spaced(n_frames, cfg.frames_per_motion):
            self._time(seen.index)
            if seen.frames is not None and k < len(seen.frames):
                self.rec.log("image", rr.Image(np.ascontiguousarray(seen.frames[k])).compress(cfg.jpeg_quality))
            strips = [t.pixels[f <= k] for t, f in zip(seen.tracks, frame_of, strict=True)]
            strips = [s for s in strips if len(s) >= 2]
            self.rec.log("image/tracks", rr.LineStrips2D(strips, colors=[_rgba((255, 200, 0))], radii=1.0))
            q = np.asarray(seen.q_start, dtype=np.float64).copy()
            q[seen.joint] += deltas[k]
            self._log_robot(q, seen.joint)
            self._frame += 1
        self._frame -= 1  # the motion's geometry and estimate at its last logged frame
        self._time(seen.index)
        self._log_geometry(seen)
        self.log_estimate(seen.calibrator, seen.index, seen)
        self._frame += 1

    def _log_robot(self, q: FloatArray, joint: int) -> None:
        """The links at q (n,) rad: their poses, the skeleton of their origins, the joint axes."""
        m, d, robot = self.robot.model, self._data, self.robot
        d.qpos[robot.qpos_adr] = q
        mujoco.mj_kinematics(m, d)
        R_bw, p_bw = self._T_base_world[:3, :3], self._T_base_world[:3, 3]
        origins: dict[int, FloatArray] = {}
        for b in robot.robot_bodies:
            p = R_bw @ d.xpos[b] + p_bw
            origins[b] = p
            if b in self._bodies:
                self.rec.log(f"world/robot/links/{self._names[b]}",
                             rr.Transform3D(translation=p, mat3x3=R_bw @ d.xmat[b].reshape(3, 3)),
                             rr.TransformAxes3D(0.05))
        segments = [np.stack([origins[int(m.body_parentid[b])], origins[b]]) for b in self._bodies
                    if int(m.body_parentid[b]) in origins]
        self.rec.log("world/robot/skeleton", rr.LineStrips3D(segments, colors=[_rgba((90, 90, 90))], radii=0.006))
        anchors = np.array([R_bw @ d.xanchor[j] + p_bw for j in robot.arm_joints])
        axes = np.array([R_bw @ d.xaxis[j] for j in robot.arm_joints])
        colors = [_rgba((230, 60, 60)) if i == joint else _rgba((150, 150, 230)) for i in range(robot.n_joints)]
        self.rec.log("world/robot/joint_axes", rr.Arrows3D(origins=anchors - 0.08 * axes, vectors=0.16 * axes,
                                                           colors=colors, radii=0.004))

    def _log_geometry(self, seen: SeenMotion) -> None:
        """Ellipses fitted to the tracks, stage one's axis in the image, the kinematic axis (base and image)."""
        cam, cfg = self.intrinsics, self.config
        longest = sorted(range(len(seen.tracks)), key=lambda i: -len(seen.tracks[i].pixels))[:cfg.max_ellipses]
        ellipses = []
        for i in longest:
            uv = normalized_from_pixels(seen.tracks[i].pixels, cam)
            fit = fit_ellipse_direct(uv)
            pts = ellipse_points(fit.matrix) if fit.matrix is not None else None
            if pts is not None:
                ellipses.append(_to_pixels(pts, cam))
        self.rec.log("image/ellipses", rr.LineStrips2D(ellipses, colors=[_rgba((0, 220, 255))], radii=1.0))
        report = seen.outcome.report
        geometry = seen.calibrator.motion_geometry(report.index) if report is not None else None
        line = axis_image_line(geometry.plane_normal, cam) if geometry is not None else None
        label = (f"motion {seen.name or seen.index}: stage-one axis ({report.front_end or 'no'} front end)"
                 if report is not None else "")
        self.rec.log("image/axis", rr.LineStrips2D([line] if line is not None else [], colors=[_rgba((255, 0, 255))],
                                                   radii=2.0, labels=[label] if line is not None else None))
        try:
            axis, point = self.robot.axis_and_point(np.asarray(seen.q_start, dtype=np.float64), seen.joint)
        except ArcCalibError:  # the model rejected the motion (its outcome says why): no axis to draw
            return
        self.rec.log("world/robot/motion_axis", rr.Arrows3D(origins=[point - 0.3 * axis], vectors=[0.6 * axis],
                                                            colors=[_rgba((230, 60, 60))], radii=0.006))
        T = seen.calibrator.state.T_camera_base
        seg = None
        if T is not None:
            a, b = (T[:3, :3] @ (point + s * axis) + T[:3, 3] for s in (-0.3, 0.3))
            seg = segment_pixels(a, b, cam)
        self.rec.log("image/axis_estimate", rr.LineStrips2D([seg] if seg is not None else [],
                                                            colors=[_rgba((60, 220, 60))], radii=2.0))

    def log_estimate(self, calibrator: Calibrator, index: int, seen: SeenMotion | None = None) -> None:
        """The estimate after motion ``index``: the camera, its 1-sigma, the curves, the log line, the text."""
        s = calibrator.state
        self._time(index)
        if seen is not None:
            o = seen.outcome
            what = "accepted" if o.accepted else f"rejected: {o.reason or o.stage_one}"
            self.rec.log("log", rr.TextLog(f"motion {seen.name or index} (joint {seen.joint + 1}): "
                                           f"{len(seen.tracks)} tracks, {what}",
                                           level="INFO" if o.accepted else "WARN"))
        self.rec.log("curves/accepted", rr.Scalars(float(s.n_accepted)))
        self.rec.log("estimate", rr.TextDocument(_estimate_text(s, self.T_camera_base_true),
                                                 media_type=rr.MediaType.MARKDOWN))
        T = s.T_camera_base
        if T is None:
            return
        self.rec.log("world/camera", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3],
                                                    relation=rr.TransformRelation.ChildFromParent))
        if not self._frustum:  # from the first estimate on (before it, the camera is nowhere)
            cam = self.intrinsics
            self.rec.log("world/camera/frustum",
                         rr.Pinhole(image_from_camera=cam.K, resolution=[cam.width, cam.height],
                                    camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=self.config.frustum_m))
            self._frustum = True
        if s.rms_px is not None:
            self.rec.log("curves/rms_px", rr.Scalars(float(s.rms_px)))
        if s.std is not None and s.covariance is not None:
            std_deg, std_mm = np.degrees(s.std[:3]), s.std[3:] * 1e3
            self.rec.log("curves/rotation_deg/sigma", rr.Scalars(float(np.max(std_deg))))
            self.rec.log("curves/translation_mm/sigma", rr.Scalars(float(np.max(std_mm))))
            eigval, eigvec = np.linalg.eigh(camera_centre_covariance(T, s.covariance))
            if np.linalg.det(eigvec) < 0:
                eigvec[:, 0] *= -1
            label = (f"1-sigma: rotation {np.round(std_deg, 3).tolist()} deg, translation "
                     f"{np.round(std_mm, 2).tolist()} mm")
            self.rec.log("world/camera/sigma", rr.Ellipsoids3D(
                half_sizes=[np.sqrt(np.clip(eigval, 0.0, None))], centers=[[0.0, 0.0, 0.0]],
                quaternions=[rr.Quaternion(xyzw=quaternion_xyzw_from_matrix(eigvec))],
                colors=[_rgba((255, 140, 0), 160)], labels=[label]))
        if self.T_camera_base_true is not None:
            rot, trans = pose_errors(T, self.T_camera_base_true)
            self.rec.log("curves/rotation_deg/error", rr.Scalars(float(np.degrees(rot))))
            self.rec.log("curves/translation_mm/error", rr.Scalars(float(trans * 1e3)))

    def finish(self, calibrator: Calibrator) -> None:
        """Log the final estimate (after the last update) one motion past the last."""
        self.log_estimate(calibrator, self._last_index + 1)

    def close(self) -> None:
        """Flush; with ``save``, rename the finished file into place."""
        self.rec.flush()
        self.rec.disconnect()
        if self._partial is not None and self.save is not None and self._partial.exists():
            os.replace(self._partial, self.save)

    def abort(self) -> None:
        """Stop logging and remove the unfinished file."""
        self.rec.disconnect()
        if self._partial is not None:
            self._partial.unlink(missing_ok=True)

    def __enter__(self) -> RerunLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _estimate_text(s: CalibrationState, truth: FloatArray | None) -> str:
    """The estimate as Markdown: stage, pose, 1-sigma, the true error when known."""
    if s.T_camera_base is None:
        return f"**No estimate yet**: {s.message}"
    T = s.T_camera_base
    lines = [f"**{s.stage} estimate**, {s.n_accepted} motions accepted, {s.n_rejected} rejected"
             + (", **converged**" if s.converged else ""), "",
             f"T_camera_base translation (m): {np.round(T[:3, 3], 4).tolist()}",
             f"quaternion (x, y, z, w): {np.round(quaternion_xyzw_from_matrix(T[:3, :3]), 5).tolist()}"]
    if s.std is not None:
        lines.append(f"1-sigma: rotation {np.round(np.degrees(s.std[:3]), 3).tolist()} deg, translation "
                     f"{np.round(s.std[3:] * 1e3, 2).tolist()} mm")
    if s.rms_px is not None:
        lines.append(f"RMS reprojection {s.rms_px:.3f} px")
    if truth is not None:
        rot, trans = pose_errors(T, truth)
        lines.append(f"true error: rotation {np.degrees(rot):.4f} deg, translation {trans * 1e3:.2f} mm")
    return "\n\n".join(lines)
