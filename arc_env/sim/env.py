"""``ArcCalib-v0``: a simulated robot calibrates a simulated camera from rendered pixels."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from arc_env.robot.session import OUTLINE_FRAMES, Acquisition, CalibrationSession, SessionConfig, StepResult
from arc_env.robot.tracking import TrackerConfig
from arc_env.sim.scene import Scene, SceneConfig, SceneRenderer
from planners.context import observation_from_estimate
from planners.transit import TransitConfig
from solver.arrays import FloatArray, ImageArray
from solver.errors import InvalidInputError
from solver.frames import check_transform, pose_errors
from solver.observations import KeypointTrack
from solver.pipeline import CalibrationState, CalibratorConfig
from solver.synthetic import sample_camera_pose

#: The paper's reported accuracy (rad, m): the reward's unit of error.
PAPER_ROTATION_RAD = 0.0042
PAPER_TRANSLATION_M = 0.0065


@dataclass(frozen=True)
class EnvConfig:
    """Settings of ``ArcCalibEnv`` (see its docstring for what they do to an episode).

    Attributes:
        scene: the robot, camera resolution and rendering.
        max_motions: executed motions after which the episode is truncated.
        max_refusals: refused actions after which the episode is truncated.
        min_delta: rad; smallest |Delta| accepted.
        max_delta: rad; largest |Delta| (the action space's bound).
        joint_speed: rad/s of the sweeping joint; with ``fps`` it sets the frames per motion.
        fps: camera frame rate, Hz.
        frames_per_motion: fixed number of frames per sweep (None: from joint_speed and fps).
        joint_latency_s: s, the joint log is stamped this late against the camera (d = t_joint - t_camera,
            ``arc_env.robot.timing``; within +-0.1 s). Not 0: the deltas handed on with a sweep's frames
            are the log's at each exposure, read without knowing d -- delta(t - d) of the sweep at
            ``joint_speed``, resting before and after -- with the log's velocity there, so the bundle
            adjustment estimates d as it does for a recording (``arc-calib record --joint-latency-ms``).
            0 (default): the exact deltas and no velocities.
        collision_step_m: m; a sweep is checked at steps that move no point by more than this.
        camera_target: (3,) m, base frame: where sampled cameras look.
        camera_distance: (min, max) m from the target for sampled cameras.
        camera_max_roll: rad, roll about the optical axis for sampled cameras.
        oracle_keypoints: replace rendering and tracking by projected mesh points (simulation
            floor: separates tracking error from geometry error).
        oracle_points: keypoints per motion in oracle mode.
        oracle_noise_px: standard deviation of the oracle's pixel noise.
        step_cost: reward charged per executed motion.
        terminate_on_convergence: end the episode (``terminated``) when the calibration converges;
            off, episodes run to the motion budget (benchmarks measuring every checkpoint).
        refusal_penalty: reward of a refused action.
        calibrator: solver settings (default: every track and frame goes to the bundle adjustment).
        tracker: tracking settings.
        transit: how the arm gets from where it is to Q (straight if free, else OMPL RRTConnect).
        overlap: render each motion while a worker thread tracks and calibrates the previous one
            (``SessionConfig.overlap``); ``step`` then reports the previous motion (see "Overlap" in
            ``ArcCalibEnv``'s docstring). Off (default): each step reports its own motion.
        outline_frames: images per motion for the outline stage (``SessionConfig.outline_frames``; default 3); 0: off.
    """

    scene: SceneConfig = field(default_factory=SceneConfig)
    max_motions: int = 25
    max_refusals: int = 200
    min_delta: float = 0.2
    max_delta: float = 1.5
    joint_speed: float = 1.0
    fps: float = 30.0
    frames_per_motion: int | None = None
    joint_latency_s: float = 0.0
    collision_step_m: float = 0.005
    camera_target: tuple[float, float, float] = (0.3, 0.0, 0.45)
    camera_distance: tuple[float, float] = (1.0, 2.5)
    camera_max_roll: float = 0.3
    oracle_keypoints: bool = False
    oracle_points: int = 80
    oracle_noise_px: float = 0.5
    step_cost: float = 0.02
    terminate_on_convergence: bool = True
    refusal_penalty: float = 0.1
    calibrator: CalibratorConfig = field(default_factory=CalibratorConfig)
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    transit: TransitConfig = field(default_factory=TransitConfig)
    overlap: bool = False
    outline_frames: int = OUTLINE_FRAMES

    def __post_init__(self) -> None:
        if self.max_motions < 1 or self.max_refusals < 1:
            raise InvalidInputError("max_motions and max_refusals must be >= 1")
        self.session  # noqa: B018  (validates the session's part)
        if self.joint_speed <= 0 or self.fps <= 0:
            raise InvalidInputError("joint_speed and fps must be > 0")
        if self.frames_per_motion is not None and self.frames_per_motion < 3:
            raise InvalidInputError("frames_per_motion must be >= 3")
        if not abs(self.joint_latency_s) <= 0.1:
            raise InvalidInputError(f"joint_latency_s must be within +-0.1 s, got {self.joint_latency_s}")
        if not 0 < self.camera_distance[0] <= self.camera_distance[1]:
            raise InvalidInputError("camera_distance must be (min, max) with 0 < min <= max")

    @property
    def session(self) -> SessionConfig:
        """The calibration session's part of these settings."""
        return SessionConfig(min_delta=self.min_delta, max_delta=self.max_delta,
                             collision_step_m=self.collision_step_m, calibrator=self.calibrator,
                             tracker=self.tracker, transit=self.transit, overlap=self.overlap,
                             outline_frames=self.outline_frames)


class ArcCalibEnv(gym.Env):
    """Camera-to-robot calibration by exploratory motions, as a Gymnasium environment.

    ## Description
    A robot (default: the Franka Panda of gymnasium-robotics) stands on a floor; a 1920x1080
    camera with D415-like intrinsics (fx = fy = 1380 px) looks at it from an unknown pose. Each
    step the agent chooses an exploratory motion: a start configuration Q, a joint J and a turn
    Delta. The environment checks it (joint limits, |Delta|, collisions over the whole sweep),
    moves the arm to Q, turns joint J by Delta while rendering frames at ``fps`` (at
    ``joint_speed``), tracks corners with OpenCV (Shi-Tomasi + pyramidal Lucas-Kanade with a
    forward-backward check, in the pixels that move) and hands the tracks, with the joint offset
    delta of every frame, to ARC-Calib's solver. The observation is the calibration state: the
    current estimate of ``T_camera_base`` (``p_camera = T_camera_base @ p_base``, OpenCV optical
    frame) and how settled and certain it is. No ground truth reaches the solver; it appears only
    in ``info`` and the reward.

    ## Action Space
    ``Dict``:

    | key   | space                                   | meaning                                  |
    |-------|-----------------------------------------|------------------------------------------|
    | Q     | Box(lower, upper, (n_joints,), float64) | start configuration, rad (joint limits)  |
    | J     | Discrete(n_joints)                      | the joint that turns (0-based)           |
    | delta | Box(-max_delta, max_delta, (1,), f64)   | the turn, rad; |delta| >= min_delta      |

    An action is refused (the robot does not move, ``info["refused"]`` says why, the refusal is
    counted) when Q is outside the limits or not finite, Q[J] + delta leaves the limits, |delta|
    < min_delta, the arm collides with itself, the floor, the camera mount or an obstacle at Q
    or anywhere along the sweep, or no collision-free transit from the current configuration to
    Q is found. The transit is the straight joint-space segment when it is free, else a path
    planned by OMPL's RRTConnect (``planners.transit``); it is executed without rendering.

    ## Observation Space
    ``Dict``:

    | key          | space                         | meaning                                         |
    |--------------|-------------------------------|-------------------------------------------------|
    | translation  | Box(-inf, inf, (3,), float64) | estimated t of T_camera_base, m (0 if none)     |
    | rotation     | Box(-pi, pi, (3,), float64)   | estimated R of T_camera_base, rotation vector   |
    | gamma        | Box(-1, inf, (6,), float64)   | range of (rotvec rad, t m) over the monitor's   |
    |              |                               | window (§V-D); -1 until the window is full      |
    | std          | Box(-1, inf, (6,), float64)   | 1-sigma of (omega rad, tau m) from the bundle   |
    |              |                               | adjustment; -1 when unavailable                 |
    | has_estimate | Discrete(2)                   | 1 when translation/rotation hold an estimate    |
    | n_accepted   | Discrete(max_motions + 1)     | motions informing the estimate                  |
    | n_rejected   | Discrete(max_motions + 1)     | executed motions pruned (reasons in info)       |
    | converged    | Discrete(2)                   | convergence fired and std is within it          |

    ## Rewards
    With e = log10(1 + rot_err / 0.0042 + trans_err / 0.0065) (errors in units of the paper's
    accuracy, true errors of the current estimate; e = log10(101) without an estimate), an
    executed motion earns e_before - e_after - ``step_cost``; a refused action earns
    -``refusal_penalty``. The sum over an episode is e_0 - e_final minus the costs. The reward uses
    ground truth: simulation only.

    ## Starting State
    ``reset(seed)`` samples the camera pose: ``camera_distance`` metres from ``camera_target``,
    at a random azimuth and an elevation between 3 and 50 degrees, looking at the target with up to
    ``camera_max_roll`` of roll (or takes ``options["camera_pose"]``, a 4x4 ``T_camera_base``).
    The arm starts at its home configuration; the calibrator is empty.

    ## Episode End
    ``terminated`` when the calibration converges (§V-D: the window's range is under the
    thresholds and so is the 1-sigma uncertainty). ``truncated`` after ``max_motions`` executed
    motions or ``max_refusals`` refused actions.

    ## Info
    Every step: ``rot_error_rad``, ``trans_error_m`` (None without an estimate), ``T_camera_base``
    (estimate or None), ``stage``, ``refused`` ("" or why), ``n_refused``, ``n_motions``; after an
    executed motion also ``motion`` (joint, tracks, accepted, reason), ``n_frames``,
    ``transit_rad`` (joint-space length of the transit path to Q) and ``transit_planned`` (True
    when the straight segment was blocked and OMPL planned around it). ``env.session`` is the
    calibration in progress (``arc_env.robot.session.CalibrationSession``: the executed motions, the
    last transit's waypoints, the calibrator, the collision checker) and the context a planner is
    given (``planners.context.PlanningContext``; it holds no ground truth): ``RandomPlanner(env.session)``.
    Wall times are in ``env.last_seconds`` (transit, render, tracking, solver), not in ``info``,
    which same-seed episodes reproduce exactly.

    ## Overlap
    With ``EnvConfig(overlap=True)`` the robot never waits for the computer: each step renders its
    motion while a worker thread tracks the previous step's motion and adds it to the calibrator
    (``CalibrationSession.step``). The step returns once the calibrator has taken that previous motion,
    completely and in order, so observations are deterministic for a seed; they lag one motion behind:

    | step returns             | overlap off               | overlap on                                    |
    |--------------------------|---------------------------|-----------------------------------------------|
    | observation              | after this step's motion  | after the previous executed motion            |
    | ``info["motion"]``       | this motion's             | the previous one's; None on the first         |
    |                          |                           | executed step (nothing processed yet)         |
    | ``info["motion_index"]`` | (absent)                  | which executed motion (0-based) ``motion``,   |
    |                          |                           | ``n_frames`` and ``transit_*`` describe; None |
    | ``n_frames``,            | this motion's             | the processed motion's (absent while          |
    | ``transit_*``            |                           | ``motion`` is None)                           |
    | reward                   | e_before - e_after - cost | the same, e after what the step processed     |
    | ``env.last_seconds``     | this motion's parts       | the processed motion's parts, plus "waited":  |
    |                          |                           | s the step stayed blocked on the worker after |
    |                          |                           | its own rendering (the robot idle), and on    |
    |                          |                           | the final step "flush": s spent on ``flush``  |

    When the episode ends (either flag, judged on the processed motions), the env first processes the
    last executed motion (``CalibrationSession.flush``): the final observation, ``info`` and the flags
    include every executed motion, and ``info["flushed_motion"]`` (``motion``'s keys plus ``index``,
    ``n_frames``) describes it. Should that motion undo a convergence, the episode goes on. A refused
    action leaves the pending motion pending (unless refusals truncate the episode). The sum of rewards
    over an episode still telescopes to e_0 - e_final minus the costs.

    ## Arguments
    ``gymnasium.make("ArcCalib-v0", config=EnvConfig(...), render_mode="rgb_array")``; see
    ``EnvConfig`` for every setting (robot file, resolution, oracle keypoints, budgets).

    ## Version History
    * v0: first version; later the ``overlap`` option (default off).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(self, config: EnvConfig | None = None, render_mode: str | None = None):
        self.config = config or EnvConfig()
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise InvalidInputError(f"render_mode must be one of {self.metadata['render_modes']}, got {render_mode!r}")
        self.render_mode = render_mode
        self.scene = Scene(self.config.scene)
        self.intrinsics = self.scene.intrinsics
        robot = self.scene.robot
        n = robot.n_joints
        c = self.config
        #: the calibration in progress, and what planners read (no ground truth).
        self.session = CalibrationSession(robot, self.intrinsics, self, c.session, SceneRenderer(self.scene))
        self.action_space = spaces.Dict({
            "Q": spaces.Box(robot.lower, robot.upper, (n,), np.float64),
            "J": spaces.Discrete(n),
            "delta": spaces.Box(-c.max_delta, c.max_delta, (1,), np.float64),
        })
        self.observation_space = spaces.Dict({
            "translation": spaces.Box(-np.inf, np.inf, (3,), np.float64),
            "rotation": spaces.Box(-np.pi, np.pi, (3,), np.float64),
            "gamma": spaces.Box(-1.0, np.inf, (6,), np.float64),
            "std": spaces.Box(-1.0, np.inf, (6,), np.float64),
            "has_estimate": spaces.Discrete(2),
            "n_accepted": spaces.Discrete(c.max_motions + 1),
            "n_rejected": spaces.Discrete(c.max_motions + 1),
            "converged": spaces.Discrete(2),
        })
        #: the true camera pose of the episode (simulation only: never in the session).
        self.T_camera_base_true: FloatArray = np.eye(4)
        self._error_score = self._score(None)
        #: wall time of the last executed motion: {"render", "tracking", "transit", "solver"} seconds
        #: (kept out of ``info`` so that same-seed episodes give identical infos).
        self.last_seconds: dict[str, float] = {}

    # -- gymnasium API -------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[dict[str, Any], dict[str, Any]]:
        """Start an episode: a camera pose (sampled or ``options["camera_pose"]``), the arm at home."""
        super().reset(seed=seed)
        c = self.config
        options = options or {}
        if options.get("camera_pose") is not None:
            T_camera_base = check_transform(options["camera_pose"], "options['camera_pose']")
        else:
            T_camera_base = sample_camera_pose(self.np_random, target=np.asarray(c.camera_target),
                                               distance=c.camera_distance, max_roll=c.camera_max_roll)
        self.T_camera_base_true = T_camera_base
        self.scene.set_camera(T_camera_base)
        self.session.reset(self.np_random)
        self._error_score = self._score(None)
        return self._observation(), self._info("")

    def step(self, action: dict[str, Any]) -> tuple[dict[str, Any], float, bool, bool, dict[str, Any]]:
        """Execute one exploratory motion (or refuse it); see the class docstring."""
        if self.session.calibrator is None:
            raise gym.error.ResetNeeded("call reset() before step()")
        c = self.config
        try:
            q, joint, delta = self._parse(action)
        except InvalidInputError as exc:
            result = self.session.refuse(str(exc))
        else:
            result = self.session.step(q, joint, delta)
        if c.overlap:
            return self._overlapped_step(result)
        if result.refused:
            info = self._info(result.refused)
            return (self._observation(), -c.refusal_penalty, False, self.session.n_refused >= c.max_refusals, info)
        assert result.motion is not None and result.transit is not None
        state = self.session.calibrator.state
        score = self._score(state)
        reward = self._error_score - score - c.step_cost
        self._error_score = score
        info = self._info("")
        info.update(motion=result.motion.as_info(), n_frames=result.n_frames, transit_rad=result.transit.length_rad,
                    transit_planned=result.transit.planned)
        self.last_seconds = result.seconds
        terminated = bool(state.converged) and c.terminate_on_convergence
        truncated = self.session.n_motions >= c.max_motions and not terminated
        return self._observation(), float(reward), terminated, truncated, info

    def _overlapped_step(self, result: StepResult) -> tuple[dict[str, Any], float, bool, bool, dict[str, Any]]:
        """``step``'s outcome with overlap: ``result`` describes the processed motion (or is pending or refused)."""
        c = self.config
        session = self.session
        assert session.calibrator is not None
        if not result.refused:
            self.last_seconds = result.seconds
        flushed = None
        if session.pending and self._ends(session.calibrator.state):
            flushed = session.flush()  # the episode ends: the final observation holds every executed motion
        state = session.calibrator.state
        score = self._score(state)
        cost = c.refusal_penalty if result.refused else c.step_cost
        reward = self._error_score - score - cost
        self._error_score = score
        info = self._info(result.refused)
        if not result.refused:
            info.update(motion=None, motion_index=None)
        if result.motion is not None and result.transit is not None:
            info.update(motion=result.motion.as_info(), motion_index=result.index, n_frames=result.n_frames,
                        transit_rad=result.transit.length_rad, transit_planned=result.transit.planned)
        if flushed is not None:
            assert flushed.motion is not None
            info["flushed_motion"] = {**flushed.motion.as_info(), "index": flushed.index,
                                      "n_frames": flushed.n_frames}
            self.last_seconds = {**self.last_seconds, "flush": flushed.seconds["waited"]}
        terminated = bool(state.converged) and c.terminate_on_convergence
        truncated = (session.n_motions >= c.max_motions or session.n_refused >= c.max_refusals) and not terminated
        return self._observation(), float(reward), terminated, truncated, info

    def _ends(self, state: CalibrationState) -> bool:
        """The episode ends with this state (converged, or a budget spent)."""
        c = self.config
        return ((bool(state.converged) and c.terminate_on_convergence) or self.session.n_motions >= c.max_motions
                or self.session.n_refused >= c.max_refusals)

    def render(self) -> ImageArray | None:
        """The camera's current image, (H, W, 3) uint8 (``render_mode="rgb_array"``)."""
        if self.render_mode != "rgb_array":
            return None
        return self.scene.render()

    def close(self) -> None:
        """Release the renderer."""
        self.scene.close()

    # -- motions -------------------------------------------------------------------------------
    def _parse(self, action: dict[str, Any]) -> tuple[FloatArray, int, float]:
        if not isinstance(action, dict) or not {"Q", "J", "delta"} <= set(action):
            raise InvalidInputError("action must be a dict with keys 'Q', 'J', 'delta'")
        q = self.scene.robot.check_q(action["Q"])
        joint_arr = np.asarray(action["J"])
        if joint_arr.size != 1 or not np.issubdtype(joint_arr.dtype, np.integer):
            raise InvalidInputError(f"J must be one integer, got {action['J']!r}")
        delta_arr = np.asarray(action["delta"], dtype=np.float64).reshape(-1)
        if delta_arr.size != 1 or not np.isfinite(delta_arr[0]):
            raise InvalidInputError(f"delta must be one finite number, got {action['delta']!r}")
        return q, int(joint_arr.reshape(-1)[0]), float(delta_arr[0])

    def sweep_deltas(self, delta: float) -> FloatArray:
        """The joint offsets of the rendered frames of a sweep by delta rad: (F,) rad, from 0 to delta."""
        c = self.config
        n = c.frames_per_motion or max(3, int(np.ceil(abs(delta) / c.joint_speed * c.fps)) + 1)
        return np.linspace(0.0, delta, n)

    def logged_deltas(self, deltas: FloatArray) -> tuple[FloatArray, FloatArray | None]:
        """What a joint log stamped ``joint_latency_s`` late gives at a sweep's frames: deltas and velocities.

        The sweep turns at ``joint_speed`` from 0 to ``deltas[-1]`` (deltas (F,) rad, evenly spaced), so frame
        k is exposed at t_k = |deltas[k]| / joint_speed; read at t_k, a log stamped d late gives the turn at
        t_k - d (0 before the start, ``deltas[-1]`` after the end) and the velocity there (0 at rest).
        Returns ((F,) rad, (F,) rad/s), or (deltas, None) without a latency.
        """
        d = self.config.joint_latency_s
        if d == 0.0:
            return deltas, None
        speed = self.config.joint_speed * np.sign(deltas[-1])
        duration = abs(deltas[-1]) / self.config.joint_speed
        t = np.abs(deltas) / self.config.joint_speed - d
        moving = (t > 0.0) & (t < duration)
        return speed * np.clip(t, 0.0, duration), np.where(moving, speed, 0.0)

    def execute(self, q: FloatArray, joint: int, delta: float) -> Acquisition:
        """The session's ``MotionExecutor``: render the sweep (or project the oracle's mesh points).

        Frames show the true turns; the deltas handed on are the joint log's (``logged_deltas``).
        """
        deltas = self.sweep_deltas(delta)
        logged, velocities = self.logged_deltas(deltas)
        q_end = q.copy()
        q_end[joint] += delta
        if self.config.oracle_keypoints:
            t0 = time.perf_counter()
            tracks = self._oracle_tracks(q, joint, deltas, logged, velocities)
            return Acquisition(q, q_end, logged, tracks=tracks,
                               seconds={"render": 0.0, "tracking": time.perf_counter() - t0})
        t0 = time.perf_counter()
        frames = self.scene.render_sweep(q, joint, deltas, self.config.joint_speed, self.np_random)
        return Acquisition(q, q_end, logged, frames=frames, seconds={"render": time.perf_counter() - t0},
                           velocities=velocities)

    def _oracle_tracks(self, q: FloatArray, joint: int, deltas: FloatArray, logged: FloatArray,
                       velocities: FloatArray | None) -> list[KeypointTrack]:
        """Mesh points of the moving links projected with the true camera, plus Gaussian noise.

        Points are projected at the true turns ``deltas`` (F,) rad and labelled with the log's ``logged``
        (F,) rad and ``velocities`` (F,) rad/s (``logged_deltas``).

        Points are drawn from the vertices of the rendered geoms that the joint moves; occlusion is
        ignored (the oracle is a floor for the geometry, not a renderer). A point is kept over the
        frames where it is in front of the camera and inside the image.
        """
        c = self.config
        robot = self.scene.robot
        body, local = robot.surface_points(joint)
        if len(body) == 0:
            return []
        pick = self.np_random.choice(len(body), size=min(c.oracle_points, len(body)), replace=False)
        body, local = body[pick], local[pick]
        pix = np.empty((len(deltas), len(body), 2))
        ok = np.empty((len(deltas), len(body)), dtype=bool)
        for k, d in enumerate(deltas):
            robot.set_swept(q, joint, d)
            uv, ok[k] = self.scene.project_points(body, local, min_depth=0.05)
            pix[k] = uv + self.np_random.normal(0.0, c.oracle_noise_px, uv.shape)
        tracks = []
        for p in range(len(body)):
            frames = np.nonzero(ok[:, p])[0]
            if len(frames) >= 3:
                tracks.append(KeypointTrack(pix[frames, p], logged[frames],
                                            None if velocities is None else velocities[frames]))
        return tracks

    # -- observation, reward, info -------------------------------------------------------------
    @staticmethod
    def _score_errors(rot: float, trans: float) -> float:
        return float(np.log10(1.0 + rot / PAPER_ROTATION_RAD + trans / PAPER_TRANSLATION_M))

    def _score(self, state: CalibrationState | None) -> float:
        if state is None or state.T_camera_base is None:
            return float(np.log10(101.0))
        return self._score_errors(*pose_errors(state.T_camera_base, self.T_camera_base_true))

    def _observation(self) -> dict[str, Any]:
        n_max = self.config.max_motions
        obs: dict[str, Any] = {
            "translation": np.zeros(3), "rotation": np.zeros(3), "gamma": -np.ones(6), "std": -np.ones(6),
            "has_estimate": 0, "n_accepted": 0, "n_rejected": 0, "converged": 0,
        }
        if self.session.calibrator is None:
            return obs
        s = self.session.calibrator.state
        obs.update(observation_from_estimate(s.T_camera_base))
        if s.gamma is not None:
            obs["gamma"] = np.asarray(s.gamma, dtype=np.float64).copy()
        if s.std is not None:
            obs["std"] = np.asarray(s.std, dtype=np.float64).copy()
        obs["n_accepted"] = min(int(s.n_accepted), n_max)
        obs["n_rejected"] = min(int(s.n_rejected), n_max)
        obs["converged"] = int(s.converged)
        return obs

    def _info(self, refused: str) -> dict[str, Any]:
        s = self.session.calibrator.state if self.session.calibrator is not None else None
        if s is not None and s.T_camera_base is not None:
            rot, trans = pose_errors(s.T_camera_base, self.T_camera_base_true)
            T_estimate = s.T_camera_base.copy()
        else:
            rot, trans, T_estimate = None, None, None
        return {"rot_error_rad": rot, "trans_error_m": trans, "T_camera_base": T_estimate,
                "stage": s.stage if s is not None else "none", "refused": refused,
                "n_refused": self.session.n_refused, "n_motions": self.session.n_motions,
                "message": s.message if s is not None else ""}
