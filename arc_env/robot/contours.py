"""The robot's occluding contours from its own model file, for the outline stage (``solver.outline_fusion``).

``RobotContours`` renders the robot alone (its MJCF or URDF as ``RobotModel.load`` compiles it: the drawn geoms,
no scene) with MuJoCo's offscreen renderer, from a camera at a given ``T_camera_base`` with the recording's
focal length and principal point, and takes the occluding contour from the depth image
(``solver.outlines.contour_from_depth``). What is behind the robot is unknown on a real recording, except the
plane it stands on: the base frame's support plane (the world's z = 0, where ``RobotModel.load`` puts the
ground) is filled in analytically, so the base's foot on the floor is not taken for an outline.

A GL context is created at the first call (EGL or OSMesa: ``arc_env.robot.rendering``), on the calling thread; a
call from another thread gets a renderer of its own. Nothing is rendered at import.
"""

from __future__ import annotations

import threading

import mujoco
import numpy as np

from arc_env.robot.model import RobotModel
from arc_env.robot.rendering import Window, create_renderer, render_geoms_and_depth
from solver.arrays import FloatArray
from solver.errors import InvalidInputError
from solver.frames import check_transform
from solver.observations import CameraIntrinsics
from solver.outlines import ContourPoints, contour_from_depth

__all__ = ["COARSE_MIN_SIDE", "RobotContours"]

#: ``RobotContours.coarse`` halves an image only when both its sides stay at least this many pixels.
COARSE_MIN_SIDE = 240


class RobotContours:
    """The robot's occluding contour at a configuration, seen from a camera pose (a ``ContourRenderer``).

    Args:
        robot: the robot (its source is compiled again, alone: the caller's model and state are not touched).
        intrinsics: the camera; rendered as a pinhole with its principal point and the focal length fy (MuJoCo's
            pixels are square; the contour is a set of 3-D points, so the recording's own projection, with its fx
            and lens distortion, applies when they are paired with the image's edges).
        stride: keep every stride-th contour point of each direction.
        min_step_m: the smallest depth step that makes an occluding contour, metres.
        ground: fill the support plane in behind the robot.
    """

    def __init__(self, robot: RobotModel, intrinsics: CameraIntrinsics, stride: int = 3, min_step_m: float = 0.03,
                 ground: bool = True):
        if stride < 1 or not min_step_m > 0:
            raise InvalidInputError(f"need stride >= 1 and min_step_m > 0, got {stride}, {min_step_m}")
        self.robot = RobotModel.load(robot.source, ground=False)
        self.intrinsics = intrinsics
        self.stride = stride
        self.min_step_m = min_step_m
        self.ground = ground
        fy, cx, cy = intrinsics.K[1, 1], intrinsics.K[0, 2], intrinsics.K[1, 2]
        self.K_render = np.array([[fy, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        m = self.robot.model
        m.vis.global_.offwidth = max(int(m.vis.global_.offwidth), intrinsics.width)
        m.vis.global_.offheight = max(int(m.vis.global_.offheight), intrinsics.height)
        # No multisampling: the segmentation and depth images are the same without it (measured: identical masks,
        # depths and contours at 1080p), and resolving a multisampled buffer took half of each render's time.
        m.vis.quality.offsamples = 0
        u, v = np.meshgrid(np.arange(intrinsics.width, dtype=np.float64),
                           np.arange(intrinsics.height, dtype=np.float64))
        # each pixel's ray (x / z, y / z) in the rendered camera; float32 (the support plane's depth needs no more)
        self._rays = (((u - cx) / fy).astype(np.float32), ((v - cy) / fy).astype(np.float32))
        self._robot_geom = np.zeros(m.ngeom + 1, dtype=bool)
        self._robot_geom[:-1] = np.isin(m.geom_bodyid, self.robot.robot_bodies) & (m.geom_group <= 2)
        self._drawn = np.flatnonzero(self._robot_geom[:-1])  # the robot's geoms that are drawn
        self._local = threading.local()
        self._points_lock = threading.Lock()  # moving_points poses self.robot
        self._coarse: RobotContours | None = None
        self._coarse_lock = threading.Lock()

    def __call__(self, T_camera_base: FloatArray, q: FloatArray) -> ContourPoints:
        """The contour with the arm at q (n,) rad seen from T_camera_base (4, 4)."""
        T = check_transform(np.asarray(T_camera_base, dtype=np.float64), "T_camera_base")
        depth, mask, (u0, v0, _, _) = self._depth_and_mask_window(T, q)
        K = self.K_render.copy()
        K[0, 2] -= u0  # the window's own pinhole: its pixel (0, 0) is the image's (u0, v0)
        K[1, 2] -= v0
        return contour_from_depth(depth, mask, T, K, self.min_step_m, self.stride)

    def coarse(self) -> RobotContours:
        """The same contours rendered at half the resolution (``solver.outline_fusion.CoarseContours``).

        A quarter of the pixels to render and read (measured at 1080p: 112 -> 40 ms per Panda contour); their points
        are base-frame points like this renderer's, a pixel or two of the full image less exact. Made at the first
        call and kept (at most one level: the half's own ``coarse`` is itself).
        """
        if self.intrinsics.width < 2 * COARSE_MIN_SIDE or self.intrinsics.height < 2 * COARSE_MIN_SIDE:
            return self
        with self._coarse_lock:
            if self._coarse is None:
                K = self.intrinsics.K.copy()
                K[:2, :2] /= 2.0
                K[:2, 2] = (K[:2, 2] + 0.5) / 2.0 - 0.5  # pixel centres at integers: edges at -0.5 at both sizes
                half = CameraIntrinsics(K, self.intrinsics.dist, self.intrinsics.width // 2,
                                        self.intrinsics.height // 2, self.intrinsics.model)
                self._coarse = RobotContours(self.robot, half, self.stride, self.min_step_m, self.ground)
                self._coarse._coarse = self._coarse
            return self._coarse

    def moving_points(self, q: FloatArray, joint: int) -> FloatArray:
        """(P, 3) float64, metres, base frame: the vertices of the drawn geoms ``joint`` moves, with the arm at q (n,).

        For the calibrator's first pose from the change masks (``solver.mask_start.MovingSurface``).
        """
        with self._points_lock:
            self.robot.set_q(q)
            return self.robot.points_base(*self.robot.surface_points(joint))

    def depth_and_mask(self, T_camera_base: FloatArray, q: FloatArray) -> tuple[FloatArray, np.ndarray]:
        """The depth and the robot's pixels with the arm at q (n,) rad, the camera at T_camera_base (4, 4).

        Returns:
            (H, W) float64 depth along the optical axis, metres (behind the robot the support plane, or +inf),
            and (H, W) bool, the robot's pixels.
        """
        T = check_transform(np.asarray(T_camera_base, dtype=np.float64), "T_camera_base")
        depth, mask, _ = self._depth_and_mask_window(T, q, whole=True)
        return depth, mask

    def _depth_and_mask_window(self, T_camera_base: FloatArray, q: FloatArray, whole: bool = False
                               ) -> tuple[FloatArray, np.ndarray, Window]:
        """``depth_and_mask`` in the robot's window (``_window``; with ``whole``, the image): depth, mask, window.

        Depth (h, w) and mask (h, w) of the window. Outside the window the robot has no pixel, and the depth is the
        support plane's (or +inf).
        """
        renderer, data = self._renderer()
        data.qpos[self.robot.qpos_adr] = self.robot.check_q(q)
        mujoco.mj_kinematics(self.robot.model, data)
        T_camera_world = T_camera_base @ np.linalg.inv(self.robot.T_world_base)
        renderer.update_scene(data, mujoco.MjvCamera())
        self._place_camera(renderer, T_camera_world)
        window = (0, 0, self.intrinsics.width, self.intrinsics.height) if whole else self._window(data, T_camera_world)
        geoms, depth = render_geoms_and_depth(renderer, window)
        mask = self._robot_geom[geoms]  # -1 (none) reads the last entry: False
        if not self.ground:
            return np.where(mask, depth, np.inf), mask, window
        return np.where(mask, depth, self._plane_depth(T_camera_world, depth.shape, window)), mask, window

    def _window(self, data: mujoco.MjData, T_camera_world: FloatArray) -> Window:
        """Pixels that hold every drawn robot geom's bounding sphere (the whole image where one reaches the camera).

        A sphere lies in the box of its centre +- its radius, whose image lies between the projections of the box's
        corners (x / z and y / z are monotone along each axis where z > 0); two pixels of margin around it, so that
        ``contour_from_depth`` finds each robot pixel's neighbours as in the whole image.
        """
        w, h = self.intrinsics.width, self.intrinsics.height
        radius = self.robot.model.geom_rbound[self._drawn]
        centre = data.geom_xpos[self._drawn] @ T_camera_world[:3, :3].T + T_camera_world[:3, 3]
        near = self.robot.model.vis.map.znear * self.robot.model.stat.extent
        if len(radius) == 0 or np.any(radius <= 0) or np.any(centre[:, 2] - radius <= near):
            return 0, 0, w, h
        f, cx, cy = self.K_render[1, 1], self.K_render[0, 2], self.K_render[1, 2]
        z = np.stack([centre[:, 2] - radius, centre[:, 2] + radius], axis=1)[:, :, None]  # (G, 2, 1)
        x = np.stack([centre[:, 0] - radius, centre[:, 0] + radius], axis=1)[:, None, :]  # (G, 1, 2)
        y = np.stack([centre[:, 1] - radius, centre[:, 1] + radius], axis=1)[:, None, :]
        u, v = f * x / z + cx, f * y / z + cy
        u0, u1 = int(np.floor(u.min())) - 2, int(np.ceil(u.max())) + 3
        v0, v1 = int(np.floor(v.min())) - 2, int(np.ceil(v.max())) + 3
        u0, v0, u1, v1 = max(u0, 0), max(v0, 0), min(u1, w), min(v1, h)
        if u0 >= u1 or v0 >= v1:  # the robot is not in view: a pixel's window renders it as not there
            return 0, 0, 1, 1
        return u0, v0, u1, v1

    def _renderer(self) -> tuple[mujoco.Renderer, mujoco.MjData]:
        local = self._local
        if not hasattr(local, "renderer"):
            local.renderer = create_renderer(self.robot.model, self.intrinsics.height, self.intrinsics.width)
            local.data = mujoco.MjData(self.robot.model)
        return local.renderer, local.data

    def _place_camera(self, renderer: mujoco.Renderer, T_camera_world: FloatArray) -> None:
        """Point the scene's GL camera along the optical frame with the rendering's pinhole frustum."""
        m = self.robot.model
        near, far = m.vis.map.znear * m.stat.extent, m.vis.map.zfar * m.stat.extent  # what Renderer's depth assumes
        R_world_camera = T_camera_world[:3, :3].T
        position = -R_world_camera @ T_camera_world[:3, 3]
        f, cx, cy = self.K_render[1, 1], self.K_render[0, 2], self.K_render[1, 2]
        w, h = self.intrinsics.width, self.intrinsics.height
        for eye in renderer.scene.camera:
            eye.pos[:] = position
            eye.forward[:] = R_world_camera[:, 2]  # optical z
            eye.up[:] = -R_world_camera[:, 1]  # optical y points down
            eye.orthographic = 0
            eye.frustum_near, eye.frustum_far = near, far
            eye.frustum_center = ((w - 1) / 2 - cx) / f * near  # pixel centres at integers: edges at -0.5, W - 0.5
            eye.frustum_width = w / 2 / f * near
            eye.frustum_top = (cy + 0.5) / f * near
            eye.frustum_bottom = -(h - 0.5 - cy) / f * near

    def _plane_depth(self, T_camera_world: FloatArray, shape: tuple[int, ...], window: Window | None = None
                     ) -> FloatArray:
        """(h, w) float32 depth of the world's z = 0 plane along each pixel's ray of ``window`` (None: the image).

        +inf where the ray misses the plane.
        """
        x, y = self._rays
        if window is not None:
            u0, v0, u1, v1 = window
            x, y = x[v0:v1, u0:u1], y[v0:v1, u0:u1]
        if x.shape != tuple(shape):
            raise InvalidInputError(f"a depth image of {shape} for a camera of {x.shape}")
        R_world_camera = T_camera_world[:3, :3].T
        height = (-R_world_camera @ T_camera_world[:3, 3])[2]
        # the world z of the ray point at depth 1: r = ((u - cx) / f, (v - cy) / f, 1) in the camera frame
        dz = x * np.float32(R_world_camera[2, 0])
        dz += y * np.float32(R_world_camera[2, 1])
        dz += np.float32(R_world_camera[2, 2])
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.divide(np.float32(-height), dz, out=dz)
        z[~(z > 0)] = np.inf
        return z
