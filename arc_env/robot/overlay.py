"""The robot model drawn over camera frames with an estimated ``T_camera_base``, for a person to judge.

``RobotProjector`` fills the robot's mask without rendering (no GL context: this serves real recordings);
``draw_overlay`` tints a mask over a frame and outlines it (and, in simulation, the true mask's outline);
``mask_iou`` compares two masks.

Works for any camera, distorted or not: the robot's rendered geoms are posed by MuJoCo at the frame's
joint positions, moved into the camera frame by the estimate and projected with OpenCV
(``solver.camera.pixels_from_camera_points``, so lens distortion is applied); mesh triangles are filled,
primitive geoms (capsules, boxes, ...) are filled as the convex hull of points on their surface (their
projection is convex for a pinhole; near enough with distortion).
"""

from __future__ import annotations

from collections.abc import Collection

import cv2
import mujoco
import numpy as np
from numpy.typing import NDArray

from arc_env.robot.model import RobotModel, primitive_surface
from solver.arrays import FloatArray, ImageArray, MaskArray
from solver.camera import in_image, normalized_from_pixels, pixels_from_camera_points
from solver.observations import CameraIntrinsics

_SUBPIXEL_BITS = 4  # cv2.fillPoly's fixed-point shift
#: ``RobotProjector.mask(fast=True)``: triangles whose edges all project shorter than this (px) are drawn as dots.
FAST_DOT_PX = 2.0


class RobotProjector:
    """Projects a robot model through a camera.

    Args:
        robot: the robot (its drawn geoms: what a camera sees).
        intrinsics: the camera (K, dist) to project with.
    """

    def __init__(self, robot: RobotModel, intrinsics: CameraIntrinsics):
        self.robot = robot
        self.intrinsics = intrinsics
        m = robot.model
        self.geoms = robot.rendered_geoms()
        self._local: dict[int, tuple[FloatArray, NDArray[np.int32] | None]] = {}
        for g in self.geoms:
            if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH:
                mid = m.geom_dataid[g]
                verts = m.mesh_vert[m.mesh_vertadr[mid]:m.mesh_vertadr[mid] + m.mesh_vertnum[mid]].astype(float)
                faces = m.mesh_face[m.mesh_faceadr[mid]:m.mesh_faceadr[mid] + m.mesh_facenum[mid]].astype(np.int32)
                self._local[g] = (verts, faces)
            else:
                pts = primitive_surface(int(m.geom_type[g]), m.geom_size[g], np.random.default_rng(g), n=400)
                if pts is not None:
                    self._local[g] = (pts, None)
        # Points far outside the view can wrap around under OpenCV's distortion polynomial: keep only
        # those whose normalized coordinates are within 1.5x the image's own extent.
        w, h = intrinsics.width, intrinsics.height
        border = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1], [(w - 1) / 2, 0], [(w - 1) / 2, h - 1],
                           [0, (h - 1) / 2], [w - 1, (h - 1) / 2]], dtype=np.float64)
        self._reach = 1.5 * np.max(np.abs(normalized_from_pixels(border, intrinsics)), axis=0)

    def mask(self, q: FloatArray, T_camera_base: FloatArray, bodies: Collection[int] | None = None,
             fast: bool = False) -> MaskArray:
        """Pixels the robot covers at arm configuration q (n_joints,) rad seen from ``T_camera_base``: (H, W) bool.

        ``bodies``: only these bodies' geoms (e.g. ``RobotModel.moving_bodies(joint)``); None: the whole robot.
        ``fast``: mesh triangles whose edges all project shorter than a pixel are drawn as their corners'
        pixels instead of being filled (at most a pixel fatter along the outline; the Panda's 134k triangles
        at 320x180: 10x faster).
        """
        s, cam = self.robot, self.intrinsics
        s.set_q(q)
        d = s.data
        T_camera_world = T_camera_base @ np.linalg.inv(s.T_world_base)
        canvas = np.zeros((cam.height, cam.width), np.uint8)
        dot_layer = np.zeros_like(canvas) if fast else canvas
        polys: list[NDArray[np.int32]] = []
        for g in self.geoms:
            if g not in self._local or (bodies is not None and s.model.geom_bodyid[g] not in bodies):
                continue
            local, faces = self._local[g]
            world = local @ d.geom_xmat[g].reshape(3, 3).T + d.geom_xpos[g]
            pc = world @ T_camera_world[:3, :3].T + T_camera_world[:3, 3]
            ok = pc[:, 2] > 0.02
            uv_n = pc[:, :2] / np.where(ok, pc[:, 2], 1.0)[:, None]
            ok &= np.all(np.abs(uv_n) <= self._reach, axis=1)
            if not ok.any():
                continue
            px = np.zeros((len(pc), 2))
            px[ok] = pixels_from_camera_points(pc[ok], cam)
            fixed = np.round(px * (1 << _SUBPIXEL_BITS)).astype(np.int32)
            if faces is None:
                if ok.sum() >= 3:
                    hull = cv2.convexHull(fixed[ok].reshape(-1, 1, 2))
                    cv2.fillConvexPoly(canvas, hull, 255, lineType=cv2.LINE_8, shift=_SUBPIXEL_BITS)
                continue
            keep = ok[faces].all(axis=1)
            if fast:
                corners = px[faces[keep]]  # (n, 3, 2) px
                edges = np.abs(corners - np.roll(corners, 1, axis=1)).max(axis=(1, 2))
                tiny = edges < FAST_DOT_PX
                dots = np.round(corners[tiny].reshape(-1, 2)).astype(np.int64)
                inside = (dots[:, 0] >= 0) & (dots[:, 0] < cam.width) & (dots[:, 1] >= 0) & (dots[:, 1] < cam.height)
                dot_layer[dots[inside, 1], dots[inside, 0]] = 255
                keep[np.flatnonzero(keep)[tiny]] = False
            polys.extend(fixed[faces[keep]])
        if polys:
            cv2.fillPoly(canvas, polys, 255, lineType=cv2.LINE_8, shift=_SUBPIXEL_BITS)
        if fast:  # corners up to FAST_DOT_PX apart: closing joins them without moving the outline out
            canvas |= cv2.morphologyEx(dot_layer, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
        return canvas > 0

    def visible_fraction(self, q: FloatArray, T_camera_base: FloatArray) -> float:
        """Fraction of the robot's surface points at q that project inside the image (0 when none do)."""
        s = self.robot
        s.set_q(q)
        T_camera_world = T_camera_base @ np.linalg.inv(s.T_world_base)
        total = inside = 0
        for g in self.geoms:
            if g not in self._local:
                continue
            local = self._local[g][0]
            world = local @ s.data.geom_xmat[g].reshape(3, 3).T + s.data.geom_xpos[g]
            pc = world @ T_camera_world[:3, :3].T + T_camera_world[:3, 3]
            front = pc[:, 2] > 0.02
            total += len(pc)
            if front.any():
                inside += int(in_image(pixels_from_camera_points(pc[front], self.intrinsics), self.intrinsics).sum())
        return inside / total if total else 0.0


def mask_iou(a: MaskArray, b: MaskArray) -> float:
    """Intersection over union of two (H, W) bool masks (1.0 when both are empty)."""
    union = np.logical_or(a, b).sum()
    return float(np.logical_and(a, b).sum() / union) if union else 1.0


def _outline(image: ImageArray, mask: MaskArray, bgr: tuple[int, int, int], thickness: int) -> None:
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    cv2.drawContours(image, contours, -1, bgr, thickness)


def draw_overlay(frame: ImageArray, mask: MaskArray, caption: str, true_mask: MaskArray | None = None) -> ImageArray:
    """The frame (H, W, 3) RGB with the mask tinted red and outlined; returned as BGR for cv2.imwrite.

    ``true_mask`` (simulation: the robot's true pixels), when given, is outlined in green.
    """
    bgr = cv2.cvtColor(frame, cv2.COLOR_RGB2BGR)
    out = bgr.copy()
    out[mask] = (0.5 * out[mask] + 0.5 * np.array([40, 40, 230])).astype(np.uint8)
    _outline(out, mask, (40, 40, 255), max(1, frame.shape[1] // 960))
    if true_mask is not None:
        _outline(out, true_mask, (60, 220, 60), max(1, frame.shape[1] // 640))
    scale = frame.shape[1] / 1920
    cv2.putText(out, caption, (int(20 * scale), int(50 * scale)), cv2.FONT_HERSHEY_SIMPLEX, 1.0 * scale,
                (255, 255, 255), max(1, int(2 * scale)), cv2.LINE_AA)
    return out
