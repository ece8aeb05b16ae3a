"""The bundle adjustment of ``solver.refinement`` on Ceres, through COLMAP's rig model (optional backend).

The problem is COLMAP's rig bundle adjustment: the camera is a non-reference sensor of one rig whose
``cam_from_rig`` is T_camera_base (unknown, shared by every frame); each frame's ``rig_from_world``
is known from the kinematics and held constant: for an observation of a track of a motion about the
axis (a_b, d_b) at turn delta, the rig frame is the base frame at that configuration and
rig_from_world maps the start configuration's base frame into it, x -> Rot_k x + (d_b - Rot_k d_b)
(``TrackSet.rot`` is Rot_k). Each track's point3D is p0 (base frame, start configuration), and the
camera is a PINHOLE one with the focal lengths and a zero principal point, observing uv * focal: the
residual is the pixel error of ``solver.refinement._Problem``, and COLMAP's
``RigReprojErrorCostFunctor`` (automatic derivatives) evaluates it. A reference camera with no
images anchors the rig (COLMAP's reference sensor has the identity pose).

``refine_ceres`` runs ``refine``'s passes on it: a Cauchy pass (scale ``cauchy_scale_px``), the same
removal of tracks whose RMS error is far above the noise, a plain least-squares pass, then the
same covariance (``_pose_covariances`` and ``conservative_covariance`` of ``solver.refinement``,
evaluated in numpy at the Ceres solution). Ceres applies the loss per residual block, the 2-vector
of one observation (rho(r_u^2 + r_v^2)), where scipy's ``least_squares`` applies it per coordinate;
the robust pass only classifies tracks, and the final pass has no loss, so the estimates agree to
the solvers' tolerances. Solved with Levenberg-Marquardt and the dense Schur complement (the points
eliminated), on one thread. The time offset is not modelled here.

Needs ``pycolmap`` (COLMAP's bindings, which carry their own Ceres); not a required dependency:
``pip install arc-calib[ceres]``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from solver.arrays import FloatArray
from solver.errors import InsufficientMotionsError, InvalidInputError
from solver.refinement import (
    RefinementConfig,
    RefinementResult,
    TrackSet,
    _pose_covariances,
    _Problem,
    _subset,
    agreeing_tracks,
    conservative_covariance,
    kept_points,
    split_agreeing_tracks,
    start_points,
)
from solver.schur import robust_sigma

#: COLMAP ids of the rig, its reference camera (no images) and the observing camera.
_RIG_ID, _REF_CAMERA_ID, _CAMERA_ID = 1, 1, 2


def ceres_available() -> bool:
    """Whether ``pycolmap`` (and so this backend) can be imported."""
    try:
        import pycolmap  # noqa: F401
    except ImportError:
        return False
    return True


def _pycolmap() -> Any:
    try:
        import pycolmap
    except ImportError as exc:
        raise ImportError("the Ceres backend needs pycolmap: pip install pycolmap "
                          "(or the package's 'ceres' extra)") from exc
    return pycolmap


@dataclass(frozen=True)
class CeresOptions:
    """Solver settings of the Ceres passes.

    Attributes:
        num_threads: Ceres threads (1: one core, as the benchmarks measure).
        gradient_tolerance: Ceres' gradient tolerance (max-norm of the projected gradient, relative).
        parameter_tolerance: Ceres' relative step size at which a pass ends.
        final_ftol: relative cost change that ends the final (plain) pass; the robust pass uses
            ``RefinementConfig.robust_ftol``, as ``refine`` does.
    """

    num_threads: int = 1
    gradient_tolerance: float = 1e-10
    parameter_tolerance: float = 1e-10
    final_ftol: float = 1e-9

    def __post_init__(self) -> None:
        if self.num_threads < 1:
            raise InvalidInputError(f"num_threads must be >= 1, got {self.num_threads}")


class _RigModel:
    """A pycolmap Reconstruction holding the tracks as COLMAP's rig model, for repeated Ceres passes.

    One frame (rig_from_world, constant) and one image per distinct (motion, turn); one point3D per
    track, observed in the images of its frames.
    """

    def __init__(self, tracks: TrackSet, T_camera_base: FloatArray, points_base: FloatArray):
        pycolmap = _pycolmap()
        self.pycolmap = pycolmap
        P = tracks.uv.shape[0]
        keys = np.concatenate([tracks.motion[tracks.track][:, None].astype(np.float64),
                               tracks.pivot[tracks.track], tracks.rot.reshape(P, 9)], axis=1)
        _, first, frame = np.unique(keys, axis=0, return_index=True, return_inverse=True)
        frame = frame.ravel()
        order = np.argsort(frame, kind="stable")
        starts = np.searchsorted(frame[order], np.arange(first.size + 1))
        slot = np.empty(P, dtype=np.int64)  # each observation's point2D index in its frame's image
        slot[order] = np.arange(P) - starts[frame[order]]

        rec = pycolmap.Reconstruction()
        fx, fy = (float(f) for f in tracks.focal)
        for camera_id in (_REF_CAMERA_ID, _CAMERA_ID):
            rec.add_camera(pycolmap.Camera(camera_id=camera_id, model="PINHOLE", width=2, height=2,
                                           params=[fx, fy, 0.0, 0.0]))
        self.sensor = rec.camera(_CAMERA_ID).sensor_id
        rig = pycolmap.Rig(rig_id=_RIG_ID)
        rig.add_ref_sensor(rec.camera(_REF_CAMERA_ID).sensor_id)
        rig.add_sensor(self.sensor, pycolmap.Rigid3d(T_camera_base[:3, :4]))
        rec.add_rig(rig)
        pixels = tracks.uv * tracks.focal
        for f, obs in enumerate(first):
            rot, pivot = tracks.rot[obs], tracks.pivot[tracks.track[obs]]
            rig_from_world = pycolmap.Rigid3d(np.column_stack([rot, pivot - rot @ pivot]))
            fr = pycolmap.Frame(frame_id=f + 1, rig_id=_RIG_ID, rig_from_world=rig_from_world)
            fr.add_data_id(pycolmap.data_t(self.sensor, f + 1))
            rec.add_frame(fr)
            image = pycolmap.Image(name=str(f), keypoints=pixels[order[starts[f]:starts[f + 1]]],
                                   camera_id=_CAMERA_ID, image_id=f + 1)
            image.frame_id = f + 1
            rec.add_image(image)
            rec.register_frame(f + 1)
        # COLMAP holds a rig's sensor_from_rig constant unless its reference sensor is in the problem
        # (its gauge rule for structure from motion). So the reference camera observes one constant
        # point, exactly, from two frames of its own: a residual of zero that fixes nothing.
        self.n_frames = int(first.size)
        ref_sensor = rec.camera(_REF_CAMERA_ID).sensor_id
        for k in (1, 2):
            fid = self.n_frames + k
            fr = pycolmap.Frame(frame_id=fid, rig_id=_RIG_ID, rig_from_world=pycolmap.Rigid3d())
            fr.add_data_id(pycolmap.data_t(ref_sensor, fid))
            rec.add_frame(fr)
            image = pycolmap.Image(name=f"ref{k}", keypoints=np.zeros((1, 2)), camera_id=_REF_CAMERA_ID, image_id=fid)
            image.frame_id = fid
            rec.add_image(image)
            rec.register_frame(fid)
        anchor = pycolmap.Track([pycolmap.TrackElement(self.n_frames + k, 0) for k in (1, 2)])
        self.anchor_id = rec.add_point3D(np.array([0.0, 0.0, 1.0]), anchor)
        by_track = np.argsort(tracks.track, kind="stable")
        track_starts = np.searchsorted(tracks.track[by_track], np.arange(tracks.n_tracks + 1))
        image_ids, slots = (frame[by_track] + 1).tolist(), slot[by_track].tolist()
        element = pycolmap.TrackElement
        self.point_ids = []
        for t in range(tracks.n_tracks):
            a, b = int(track_starts[t]), int(track_starts[t + 1])
            track = pycolmap.Track([element(i, j) for i, j in zip(image_ids[a:b], slots[a:b], strict=True)])
            self.point_ids.append(rec.add_point3D(points_base[t], track))
        self.rec = rec

    def solve(self, loss: str, scale: float, max_iterations: int, ftol: float, options: CeresOptions) -> Any:
        """One Ceres pass over the pose and the remaining points ("cauchy" or "linear" loss); its summary."""
        pycolmap = self.pycolmap
        ba = pycolmap.BundleAdjustmentOptions()
        ba.refine_focal_length = ba.refine_principal_point = ba.refine_extra_params = False
        ba.refine_rig_from_world = False  # the kinematics fix every frame
        ba.refine_sensor_from_rig = True
        ba.refine_points3D = True
        ba.print_summary = False
        ceres = ba.ceres
        ceres.loss_function_type = (pycolmap.LossFunctionType.CAUCHY if loss == "cauchy"
                                    else pycolmap.LossFunctionType.TRIVIAL)
        ceres.loss_function_scale = scale
        ceres.auto_select_solver_type = False
        so = ceres.solver_options
        so.linear_solver_type = type(so.linear_solver_type).DENSE_SCHUR  # pycolmap's own enum
        so.num_threads = options.num_threads
        so.max_num_iterations = max_iterations
        so.function_tolerance = ftol
        so.gradient_tolerance = options.gradient_tolerance
        so.parameter_tolerance = options.parameter_tolerance
        config = pycolmap.BundleAdjustmentConfig()
        for image_id in range(1, self.n_frames + 3):
            config.add_image(image_id)
        config.set_constant_cam_intrinsics(_CAMERA_ID)
        config.set_constant_cam_intrinsics(_REF_CAMERA_ID)
        config.add_constant_point(self.anchor_id)
        return pycolmap.create_default_ceres_bundle_adjuster(ba, config, self.rec).solve()

    def drop(self, keep: np.ndarray) -> None:
        """Delete the points of the tracks where ``keep`` (T,) bool is False; keep the rest in order."""
        for pid, k in zip(self.point_ids, keep, strict=True):
            if not k:
                self.rec.delete_point3D(pid)
        self.point_ids = [pid for pid, k in zip(self.point_ids, keep, strict=True) if k]

    def pose(self) -> FloatArray:
        """T_camera_base (4, 4) now."""
        T = np.eye(4)
        T[:3, :4] = self.rec.rig(_RIG_ID).sensor_from_rig(self.sensor).matrix()
        return T

    def points(self) -> FloatArray:
        """(T, 3) m: the remaining tracks' points p0 now (base frame, start configuration)."""
        return np.array([self.rec.point3D(pid).xyz for pid in self.point_ids], dtype=np.float64).reshape(-1, 3)


def _numpy_residuals(tracks: TrackSet, T: FloatArray, points: FloatArray) -> tuple[_Problem, FloatArray, FloatArray]:
    """``_Problem`` about pose T, its parameters x at (T, points) and the residuals there (2P,) px."""
    problem = _Problem(tracks, T)
    q = points @ T[:3, :3].T + T[:3, 3]
    x = np.concatenate([np.zeros(6), q.ravel()])
    return problem, x, problem.residuals(x)


def refine_ceres(tracks: TrackSet, T_init: FloatArray, config: RefinementConfig | None = None,
                 points_init: FloatArray | None = None, options: CeresOptions | None = None) -> RefinementResult:
    """``solver.refinement.refine`` on Ceres: bundle-adjust T_camera_base and the track points.

    The same passes, outlier rule and covariance as ``refine`` (module doc); ``max_nfev`` bounds
    each pass's Ceres iterations. Without the time offset.

    Args:
        tracks: the observations (``build_track_set``).
        T_init: (4, 4) float64: starting pose, e.g. the linear calibration.
        config: settings; defaults to ``RefinementConfig()``. ``estimate_time_offset`` must not be
            True (None is taken as off here, whatever the tracks carry); ``track_weights`` is ignored (unweighted).
        points_init: (T, 3) float64, m: starting points; triangulated from ``T_init`` if None (rows
            with NaN too).
        options: Ceres settings; defaults to ``CeresOptions()``.

    Raises:
        InsufficientMotionsError: fewer than two tracks survive triangulation or outlier removal.
        InvalidInputError: the time offset is requested, or T_init is not a finite (4, 4) array.
        ImportError: pycolmap is not installed.
    """
    config = config or RefinementConfig()
    options = options or CeresOptions()
    T_init = np.asarray(T_init, dtype=np.float64)
    if T_init.shape != (4, 4) or not np.all(np.isfinite(T_init)):
        raise InvalidInputError(f"T_init must be a finite (4, 4) transform, got shape {T_init.shape}")
    if config.track_weights:  # the Ceres trial solves the unweighted problem only
        config = replace(config, track_weights=False)
    if config.estimate_time_offset:
        raise InvalidInputError("the Ceres backend does not estimate the time offset: set "
                                "RefinementConfig.estimate_time_offset to False or None, or use refine()")
    points, keep = start_points(tracks, T_init, points_init)
    sub = _subset(tracks, keep)
    model = _RigModel(sub, T_init, points[keep])
    model.solve("cauchy", config.cauchy_scale_px, config.max_nfev, config.robust_ftol, options)
    T, pts = model.pose(), model.points()
    res = _numpy_residuals(sub, T, pts)[2].reshape(-1, 2)
    good = agreeing_tracks(sub, res, robust_sigma(res), config) & split_agreeing_tracks(sub, T, config)
    if good.sum() < 2:
        raise InsufficientMotionsError("fewer than two tracks agree with the refined pose")
    sub2 = _subset(sub, good)
    model.drop(good)
    model.solve("linear", 1.0, config.max_nfev, options.final_ftol, options)
    T, pts2 = model.pose(), model.points()
    problem, x, fun = _numpy_residuals(sub2, T, pts2)
    m, n = fun.size, x.size
    sigma2 = float(np.sum(fun**2) / max(m - n, 1))
    cov = conservative_covariance(*_pose_covariances(problem, x, sigma2, fun))
    inliers, all_points = kept_points(tracks.n_tracks, keep, good, pts2)
    return RefinementResult(T, cov, all_points, inliers, float(np.sqrt(np.mean(fun**2))), float(np.sqrt(sigma2)))
