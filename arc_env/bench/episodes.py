"""Benchmark episodes: one runner for every study script, and a store that makes long studies resumable.

``scripts/bench_episode.py`` (tracked and oracle runs of random motions), ``scripts/compare_planners.py``
(random against informed) and ``scripts/reproduce_paper.py`` (random, informed and the marker
baseline) all run the same kind of episode: the benchmarks' fixed camera pose ``pose``, the env
seeded with ``1000 * pose + seed`` and the planner's generator with the same number, a budget of
``motions`` executed motions. An :class:`EpisodeSpec` names one; :func:`run_episode` runs it and
returns a plain JSON-able record; :func:`run_episodes` runs many, in worker processes or as Ray tasks
(a local Ray cluster, or a running one: ``--ray``, ``--ray-address``) if asked, and
with an :class:`EpisodeStore` keeps every finished record on disk so that a study interrupted after
hours continues where it stopped, and so that the three scripts share runs they have in common (the
random tracked run at 1080p is the same episode in all three).

A record (``dict``):

* ``spec``: the :class:`EpisodeSpec` as a dict; ``commit``: the code it ran on (``git describe``,
  "-dirty" when the tree had changes), so mixed-version results can be seen;
* ``curve``: per executed motion (or, for ``marker``, per board pose) ``[rot_rad, trans_m]`` true
  error of the estimate after it, ``null`` while there is no estimate;
* ``planning``: seconds of every planning call; ``seconds``: totals of ``render``, ``tracking``,
  ``solver``, ``transit``, ``planning`` and the whole episode (``total``); ``frames``: rendered frames;
* ``converged_at``: first motion (1-based) after which the convergence monitor fired, or ``null``;
* ``refused``: actions the env refused; ``in_collision``: executed sweeps and transits that a 2 mm
  re-check finds colliding (must be 0);
* ``T_camera_base``: the final estimate (4x4 nested lists) or ``null``; ``note``: why it stopped early;
* ``tracks``, ``full_tracks``: per executed motion, the tracks handed to the solver and those spanning the
  sweep; ``axes``: executed motions to which stage one gave an axis (at the end); ``usable``: whether
  the final estimate passes ``calibrate``'s usability check (``arc_env.robot.session.UsableCriteria``);
* ``axes_conics``, ``axes_rigid``: executed motions to which each front end gave an axis (at the end,
  :func:`front_end_axes`; a motion rejected as "nothing moved" has neither, and one may have both);
* ``std_curve``: per executed motion ``[max rotation 1-sigma rad, max translation 1-sigma m]`` of the
  calibration state after it (the largest of the three entries of ``CalibrationState.std``), ``null``
  while the state has no 1-sigma;
* ``chi2_curve``: per executed motion the truth's chi-square in the state's covariance (:func:`truth_chi2`: 6
  degrees of freedom; under 12.59 when the 95 % region holds the truth), ``null`` without a covariance;
* ``error_curve``: per executed motion the estimate's error ``pose_difference(estimate, truth)`` (6,) (omega rad, tau
  m), ``null`` without an estimate; ``covariance_curve``: the state's 6x6 covariance (nested lists), ``null``
  without one: together they say which direction a miss of the 95 % region lies in;
* ``false_convergence``: executed motions after which the state said it had converged while its true
  error was over 3 times its reported 1-sigma (:func:`falsely_converged`: rotation error > 3 x the norm
  of the three rotation 1-sigmas, or translation error > 3 x the norm of the three translation ones);
* ``replayed_from`` (only in a record replayed from a capture, ``arc_env.bench.capture.rescore``): the original
  record's ``commit`` and ``seconds``; the solver's fields and times are then the replay's, the rest the original's.

Records stored before a field existed lack it; the study scripts leave such records out of that figure.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from arc_env.robot.exports import write_files_atomic
from arc_env.robot.library import DEFAULT_ROBOT, ROBOT_NAMES, library_robot
from arc_env.robot.session import UsableCriteria, state_unusable_reason
from arc_env.sim.background import BACKGROUNDS
from arc_env.sim.imaging import realism_settings
from solver.arrays import FloatArray
from solver.errors import ArcCalibError, InvalidInputError
from solver.frames import pose_difference, pose_errors
from solver.pipeline import CalibrationState, Calibrator, CalibratorConfig, MotionReport

#: Selection methods an episode can use: ARC-Calib with either planner, or the marker baseline.
METHODS = ("random", "informed", "marker")
#: Re-check resolution for executed sweeps and transits, m (finer than the env's own check).
RECHECK_STEP_M = 0.002
#: A converged state is false when its true error exceeds this many times its reported 1-sigma norm.
FALSE_CONVERGENCE_SIGMAS = 3.0


@dataclass(frozen=True)
class EpisodeSpec:
    """One benchmark episode.

    Attributes:
        method: "random", "informed" (ARC-Calib with that planner) or "marker" (the baseline).
        pose: index of the benchmarks' fixed camera pose (``arc_env.bench.poses.benchmark_camera_pose``).
        seed: run index at that pose; the env and planner are seeded with ``1000 * pose + seed``.
        motions: executed motions (board poses for "marker") in the episode.
        width: image width, px.
        height: image height, px.
        oracle: projected mesh points instead of rendering and tracking (ARC-Calib methods only).
        realism: "clean" (today's renders) or "realistic" camera and robot (``arc_env.sim.imaging``); the
            realistic robot's labels, screws, seams and cables are placed with the episode's seed
            (``SceneConfig.appearance_seed = rng_seed``), so each episode's robot looks different.
        appearance: the robot's surface; None: the realism's default ("painted" clean, "realistic" realistic).
        robot: the robot, a name of ``arc_env.robot.library.ROBOT_NAMES``; the cameras are the benchmark
            poses scaled to it (``arc_env.bench.poses.benchmark_view``). Part of ``key`` only when not
            the default Panda, so stores written before this field existed stay valid.
        outline_frames: images per motion for the outline stage (``EnvConfig.outline_frames``); 0 (off) keeps
            ``key`` as it was.
        background: what stands behind the robot (``SceneConfig.background``: "floor" or "lab", the lab drawn with
            the episode's seed); "floor" keeps ``key`` as it was.
    """

    method: str
    pose: int
    seed: int
    motions: int = 25
    width: int = 1920
    height: int = 1080
    oracle: bool = False
    realism: str = "clean"
    appearance: str | None = None
    robot: str = DEFAULT_ROBOT
    outline_frames: int = 0
    background: str = "floor"

    def __post_init__(self) -> None:
        """Check the fields."""
        realism_settings(self.realism, self.appearance)  # InvalidInputError names the valid choices
        if self.method not in METHODS:
            raise InvalidInputError(f"unknown method {self.method!r}; valid: {', '.join(METHODS)}")
        if self.oracle and self.method == "marker":
            raise InvalidInputError("the marker baseline has no oracle mode")
        if self.background not in BACKGROUNDS:
            raise InvalidInputError(f"unknown background {self.background!r}; valid: {', '.join(BACKGROUNDS)}")
        if self.robot not in ROBOT_NAMES:
            raise InvalidInputError(f"unknown robot {self.robot!r}; valid: {', '.join(ROBOT_NAMES)}")
        if self.method == "marker" and self.robot != DEFAULT_ROBOT:
            raise InvalidInputError(f"the marker baseline's board mounts on the Panda's flange, not on {self.robot!r}")
        if (self.pose < 0 or self.seed < 0 or self.motions < 1 or self.width < 1 or self.height < 1
                or self.outline_frames < 0 or (self.outline_frames and (self.oracle or self.method == "marker"))):
            raise InvalidInputError(f"invalid episode {self}")

    @property
    def key(self) -> str:
        """File-name-safe identity, e.g. ``random_1920x1080_m25_p3_s1`` (``random_iiwa_1920x1080_...`` on the iiwa)."""
        mode = "-oracle" if self.oracle else ""
        robot = "" if self.robot == DEFAULT_ROBOT else f"_{self.robot}"
        default_look = (self.realism, self.appearance) == ("clean", None)
        look = "" if default_look else f"_{self.realism}-{self.appearance or 'default'}"
        outlines = f"_o{self.outline_frames}" if self.outline_frames else ""
        background = "" if self.background == "floor" else f"_{self.background}"
        return (f"{self.method}{mode}{robot}{look}{background}_{self.width}x{self.height}_m{self.motions}{outlines}"
                f"_p{self.pose}_s{self.seed}")

    @property
    def rng_seed(self) -> int:
        """The number both the env and the planner are seeded with."""
        return 1000 * self.pose + self.seed


def code_version() -> str:
    """``git describe --always --dirty`` of this checkout, or "unknown" outside git."""
    try:
        out = subprocess.run(["git", "describe", "--always", "--dirty"], cwd=Path(__file__).resolve().parent,
                             capture_output=True, text=True, timeout=10, check=True)
        return out.stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def _error_pair(rot: float | None, trans: float | None) -> list[float] | None:
    return None if rot is None or trans is None else [float(rot), float(trans)]


def front_end_axes(reports: Iterable[MotionReport]) -> tuple[int, int]:
    """Motions to which the conic and the rigid front end gave an axis: (conics, rigid).

    The conics gave one when the motion reached the front ends (``front_end`` is set: a motion
    rejected as "nothing moved" never does, and its empty ``conics`` says nothing) and ``conics``
    holds no reason (nor ``solver.pipeline.CONICS_NOT_RUN``: they were not needed); the rigid front end
    when ``front_end == "rigid"`` (its axis is then the one used).
    """
    conics = rigid = 0
    for r in reports:
        conics += r.front_end != "" and r.conics == ""
        rigid += r.front_end == "rigid"
    return conics, rigid


def std_maxima(std: FloatArray | None) -> list[float] | None:
    """``[max rotation 1-sigma rad, max translation 1-sigma m]`` of a state's std (6,), or None without one."""
    if std is None:
        return None
    return [float(np.max(std[:3])), float(np.max(std[3:]))]


def falsely_converged(state: CalibrationState, rot_error: float | None, trans_error: float | None) -> bool:
    """Whether ``state`` says it converged while its true error is beyond its reported uncertainty.

    True when ``state.converged`` and the true rotation error exceeds ``FALSE_CONVERGENCE_SIGMAS`` times
    the norm of the three rotation 1-sigmas (``std[:3]``, rad), or the translation error that many times
    the norm of the translation ones (``std[3:]``, m). Both are in the parameterization of
    ``solver.frames.pose_difference`` (the norm of the 1-sigmas is the RMS length of an error drawn
    from the covariance's diagonal). A converged state without a 1-sigma (the linear method alone) or
    without an estimate cannot be checked and counts as not false.

    Args:
        state: the calibration after a motion.
        rot_error: rad, true rotation error of ``state.T_camera_base`` (None without an estimate).
        trans_error: m, true translation error (None without an estimate).
    """
    if not state.converged or state.std is None or rot_error is None or trans_error is None:
        return False
    std = np.asarray(state.std, dtype=np.float64)
    k = FALSE_CONVERGENCE_SIGMAS
    return bool(rot_error > k * np.linalg.norm(std[:3]) or trans_error > k * np.linalg.norm(std[3:]))


def truth_chi2(state: CalibrationState, T_true: FloatArray) -> float | None:
    """xi^T C^-1 xi of the true pose T_true (4, 4) in the state's covariance C, xi = pose_difference(estimate, T_true).

    Chi-square with 6 degrees of freedom when the covariance is honest. None without an estimate or a covariance,
    or with a covariance that is not positive definite.
    """
    if state.T_camera_base is None or state.covariance is None:
        return None
    xi = pose_difference(state.T_camera_base, T_true)
    try:
        chol = np.linalg.cholesky(np.asarray(state.covariance, dtype=np.float64))
    except np.linalg.LinAlgError:
        return None
    z = np.linalg.solve(chol, xi)
    return float(z @ z)


def run_episode(spec: EpisodeSpec) -> dict[str, Any]:
    """Run one episode and return its record (see the module doc)."""
    if spec.method == "marker":
        return _run_marker(spec)
    return run_arc_episode(spec)


def capturable(spec: EpisodeSpec) -> bool:
    """Whether ``spec``'s episode has a calibrator's inputs to capture: tracked ARC-Calib (not oracle, not marker)."""
    return spec.method in ("random", "informed") and not spec.oracle


def make_env(spec: EpisodeSpec, board: bool = False):  # noqa: ANN202  (ArcCalibEnv; imported lazily)
    """The spec's environment, reset to its benchmark camera pose: (env, first observation)."""
    from arc_env.bench.poses import benchmark_camera_pose, benchmark_view
    from arc_env.sim.env import ArcCalibEnv, EnvConfig
    from arc_env.sim.marker_board import MarkerBoard
    from arc_env.sim.scene import SceneConfig

    config = EnvConfig(scene=SceneConfig(robot=library_robot(spec.robot), width=spec.width, height=spec.height,
                                         marker_board=MarkerBoard() if board else None,
                                         appearance_seed=spec.rng_seed, background=spec.background,
                                         background_seed=spec.rng_seed,
                                         **realism_settings(spec.realism, spec.appearance)),
                       max_motions=spec.motions, oracle_keypoints=spec.oracle, terminate_on_convergence=False,
                       outline_frames=spec.outline_frames,
                       calibrator=bench_calibrator_config())
    env = ArcCalibEnv(config)
    target, scale = benchmark_view(env.scene.robot)
    obs, _ = env.reset(seed=spec.rng_seed,
                       options={"camera_pose": benchmark_camera_pose(spec.pose, target, scale)})
    return env, obs


def episode_planner(env: Any, spec: EpisodeSpec) -> Any:  # (ArcCalibEnv) -> Planner; both imported lazily
    """The planner of ``spec``'s episode on ``env`` (``make_env``): random or informed, seeded by ``spec.rng_seed``."""
    from planners.informed import InformedPlanner
    from planners.random_planner import RandomPlanner

    planner_cls = RandomPlanner if spec.method == "random" else InformedPlanner
    return planner_cls(env.session, np.random.default_rng(spec.rng_seed))


def bench_calibrator_config() -> CalibratorConfig:
    """The benchmark's calibrator settings: the defaults, with the paper's conics on every motion.

    ``conics_always``: so ``axes_conics`` counts them on every motion (the estimate is the same; the solver's time
    for them is reported apart, as "report").
    """
    return CalibratorConfig(conics_always=True)


def fresh_solver_fields() -> dict[str, Any]:
    """A record's per-motion solver fields before its first motion (``note_state`` adds to them)."""
    return {"curve": [], "std_curve": [], "chi2_curve": [], "error_curve": [], "covariance_curve": [],
            "false_convergence": 0, "outline_curve": [], "outline_note": "", "converged_at": None,
            "T_camera_base": None}


def note_state(record: dict[str, Any], state: CalibrationState, T_true: FloatArray) -> None:
    """Add the calibration ``state`` after an episode's next motion to ``record``'s per-motion solver fields.

    ``curve`` (true errors), ``std_curve``, ``chi2_curve``, ``error_curve``, ``covariance_curve``,
    ``false_convergence``, ``outline_curve`` and ``outline_note``, ``converged_at`` and ``T_camera_base``; T_true
    (4, 4) is the true pose.
    """
    rot, trans = (None, None) if state.T_camera_base is None else pose_errors(state.T_camera_base, T_true)
    record["curve"].append(_error_pair(rot, trans))
    record["std_curve"].append(std_maxima(state.std))
    record["chi2_curve"].append(truth_chi2(state, T_true))
    record["error_curve"].append(None if state.T_camera_base is None else
                                 pose_difference(state.T_camera_base, T_true).tolist())
    record["covariance_curve"].append(None if state.covariance is None else
                                      np.asarray(state.covariance, dtype=np.float64).tolist())
    record["false_convergence"] += falsely_converged(state, rot, trans)
    record["outline_curve"].append(state.outline is not None)
    record["outline_note"] = state.outline_note
    if state.converged and record["converged_at"] is None:
        record["converged_at"] = len(record["curve"])
    if state.T_camera_base is not None:
        record["T_camera_base"] = np.asarray(state.T_camera_base, dtype=np.float64).tolist()


def note_calibrator(record: dict[str, Any], calibrator: Calibrator) -> None:
    """Add an episode's end of ``calibrator`` to ``record``: ``axes``, ``axes_conics``, ``axes_rigid``, ``usable``."""
    record["axes"] = sum(calibrator.motion_geometry(i) is not None for i in range(len(calibrator.reports)))
    record["axes_conics"], record["axes_rigid"] = front_end_axes(calibrator.reports)
    record["usable"] = not state_unusable_reason(calibrator.state, calibrator.state.n_accepted, UsableCriteria())


def run_arc_episode(spec: EpisodeSpec, watch: Callable[[Any], Callable[[], None]] | None = None) -> dict[str, Any]:
    """Run an ARC-Calib episode and return its record.

    ``watch``, when given, is called with the env once it is reset and returns what to call when the episode has
    ended, before the env closes (``arc_env.bench.capture`` keeps the calibrator's inputs so).
    """
    started = time.perf_counter()
    # "report": the solver's time on the conic front end for the benchmark's report alone (``conics_always``),
    # moved out of "solver", which is then what the default settings spend
    seconds = dict.fromkeys(("render", "tracking", "solver", "transit", "planning", "report"), 0.0)
    record: dict[str, Any] = {"spec": asdict(spec), "commit": code_version(), "planning": [], "frames": 0,
                              "refused": 0, "in_collision": 0, "note": "", "tracks": [], "full_tracks": [],
                              **fresh_solver_fields()}
    env, obs = make_env(spec)
    try:
        ended = watch(env) if watch is not None else None
        planner = episode_planner(env, spec)
        while len(record["curve"]) < spec.motions:
            t0 = time.perf_counter()
            try:
                action = planner.plan(obs)
            except ArcCalibError as exc:
                record["note"] = f"planner stopped after {len(record['curve'])} motions: {exc}"
                break
            record["planning"].append(time.perf_counter() - t0)
            report_before = _report_seconds(env)
            obs, _, _, truncated, info = env.step(action)
            if info["refused"]:
                record["refused"] += 1
                if truncated:
                    record["note"] = f"{info['n_refused']} refused actions"
                    break
                continue
            for part, value in env.last_seconds.items():
                seconds[part] = seconds.get(part, 0.0) + value
            report = _report_seconds(env) - report_before
            seconds["solver"] -= report
            seconds["report"] += report
            record["frames"] += int(info.get("n_frames", 0))
            session = env.session
            q, joint, delta = session.executed[-1]
            assert session.last_transit is not None
            free, _ = session.checker.sweep_free(q, joint, delta, RECHECK_STEP_M)
            path = session.last_transit.waypoints
            free = free and all(session.checker.path_free(a, b, RECHECK_STEP_M)[0]
                                for a, b in zip(path[:-1], path[1:], strict=True))
            record["in_collision"] += int(not free)
            record["tracks"].append(int(info["motion"]["n_tracks"]))
            record["full_tracks"].append(int(info["motion"]["n_full_tracks"]))
            note_state(record, session.calibrator.state, env.T_camera_base_true)
        calibrator = env.session.calibrator
        assert calibrator is not None
        note_calibrator(record, calibrator)
        if ended is not None:
            ended()
    finally:
        env.close()
    seconds["planning"] = float(sum(record["planning"]))
    seconds["total"] = time.perf_counter() - started
    record["seconds"] = seconds
    return record


def _report_seconds(env: Any) -> float:
    """Seconds the env's calibrator has spent on the conic front end for its report alone (0 without one)."""
    calibrator = env.session.calibrator
    return 0.0 if calibrator is None else float(calibrator.report_seconds)


def _run_marker(spec: EpisodeSpec) -> dict[str, Any]:
    from arc_env.bench.marker_baseline import MarkerBaseline

    started = time.perf_counter()
    env, _ = make_env(spec, board=True)
    try:
        baseline = MarkerBaseline(env, np.random.default_rng(spec.rng_seed))
        run = baseline.run(spec.motions)
        curve = [None if e is None else _error_pair(*e) for e in baseline.errors(run)]
        note = (f"{len(run.views)} views, {run.rejected} rejected"
                if run.rejected or len(curve) < spec.motions else "")
        T_camera_base = run.T_camera_base
    finally:
        env.close()
    return {"spec": asdict(spec), "commit": code_version(), "curve": curve, "planning": [], "frames": 0,
            "converged_at": None, "refused": 0, "in_collision": 0,
            "T_camera_base": None if T_camera_base is None else np.asarray(T_camera_base).tolist(), "note": note,
            "seconds": {"total": time.perf_counter() - started}}


def padded_curve(record: dict[str, Any], n: int) -> list[tuple[float, float]]:
    """The record's errors after 1..n motions; no estimate is (inf, inf); after the last motion it stays."""
    curve = [(np.inf, np.inf) if e is None else (float(e[0]), float(e[1])) for e in record["curve"][:n]]
    last = curve[-1] if curve else (np.inf, np.inf)
    return curve + [last] * (n - len(curve))


def commits_used(records: Iterable[dict[str, Any]]) -> str:
    """Which code versions the records came from, e.g. "abc1234 (50 runs)"; more than one is worth a look."""
    counts: dict[str, int] = {}
    for r in records:
        counts[r["commit"]] = counts.get(r["commit"], 0) + 1
    return ", ".join(f"{c} ({n} runs)" for c, n in sorted(counts.items()))


class EpisodeStore:
    """Finished episode records as one JSON file per :attr:`EpisodeSpec.key` under ``root``."""

    def __init__(self, root: Path | str) -> None:
        """Use (and create) the directory ``root``."""
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)

    def path(self, spec: EpisodeSpec) -> Path:
        """Where ``spec``'s record lives."""
        return self.root / f"{spec.key}.json"

    def get(self, spec: EpisodeSpec) -> dict[str, Any] | None:
        """The stored record of ``spec``, or None (also for an unreadable or foreign file)."""
        path = self.path(spec)
        try:
            record = json.loads(path.read_text())
        except (OSError, ValueError):
            return None
        if not isinstance(record, dict) or not isinstance(record.get("spec"), dict):
            return None
        # stored before these fields existed
        defaults = {"realism": "clean", "appearance": None, "robot": DEFAULT_ROBOT, "outline_frames": 0,
                    "background": "floor"}
        return record if {**defaults, **record["spec"]} == asdict(spec) else None

    def capture_path(self, spec: EpisodeSpec) -> Path:
        """Where ``spec``'s capture lives (``arc_env.bench.capture``; kept with ``--keep-captures``)."""
        return self.root / "captures" / f"{spec.key}.pkl"

    def put(self, record: dict[str, Any]) -> None:
        """Store a record (atomically: a temporary file renamed into place)."""
        write_files_atomic({self.path(EpisodeSpec(**record["spec"])): json.dumps(record)})


#: Threads per worker process (renderer and BLAS) when episodes run in parallel.
_WORKER_THREADS = {"LP_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
                   "MKL_NUM_THREADS": "1"}


def worker_pool(workers: int) -> ProcessPoolExecutor:
    """A pool of ``workers`` spawned processes that end with this one (``die_with_parent``).

    Without it, a study stopped by SIGTERM to its parent alone (``kill``, ``pkill -f``) left its workers
    rendering the episodes they had, for nothing: only the parent stores records.
    """
    return ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                               initializer=die_with_parent, initargs=(os.getpid(),))


def die_with_parent(parent_pid: int) -> None:
    """Ask the kernel to send this process SIGTERM when its parent ends (Linux ``PR_SET_PDEATHSIG``).

    ``parent_pid`` is the parent's pid as the parent saw it: when it has already ended (this process
    was re-parented before the request), this process ends at once. Elsewhere than on Linux a no-op.
    """
    if not sys.platform.startswith("linux"):
        return
    import ctypes

    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0) != 0:
        return  # not granted: the worker lives on as before
    if os.getppid() != parent_pid:
        os.kill(os.getpid(), signal.SIGTERM)


#: prctl's option number that sets the signal sent on the parent's death (linux/prctl.h).
_PR_SET_PDEATHSIG = 1


def run_episodes(specs: Iterable[EpisodeSpec], store: EpisodeStore | None = None, workers: int = 1,
                 on_record: Callable[[dict[str, Any], bool], None] | None = None,
                 ray_address: str | None = None,
                 task: Callable[[EpisodeSpec], dict[str, Any]] = run_episode) -> dict[EpisodeSpec, dict[str, Any]]:
    """Run every spec not already in ``store``; returns all records by spec.

    Args:
        specs: the episodes.
        store: where finished records are kept and looked up; None runs everything.
        workers: processes running episodes at once (1: in this process). With more than one, each
            worker's renderer and BLAS use one thread. With Ray and a local cluster: the cluster's CPUs
            (1: all of this machine's).
        on_record: called as ``on_record(record, from_store)`` as each record becomes available
            (stored ones first, then in order of completion).
        ray_address: run the episodes as Ray tasks (``_run_on_ray``): ``RAY_LOCAL`` starts a local
            cluster for this call, anything else is the address of a running one (``ray.init(address=...)``:
            ``auto``, ``HOST:PORT``, ``ray://HOST:10001``). None: no Ray.
        task: what gives a spec's record (default ``run_episode``; a picklable callable, e.g. a
            ``functools.partial`` of a module function: ``arc_env.bench.capture.episode_task`` keeps or replays
            captures).
    """
    if workers < 1:
        raise InvalidInputError(f"workers must be >= 1, got {workers}")
    specs = list(dict.fromkeys(specs))
    records: dict[EpisodeSpec, dict[str, Any]] = {}
    todo = []
    for spec in specs:
        found = store.get(spec) if store is not None else None
        if found is None:
            todo.append(spec)
            continue
        records[spec] = found
        if on_record:
            on_record(found, True)

    def finish(record: dict[str, Any]) -> None:
        records[EpisodeSpec(**record["spec"])] = record
        if store is not None:
            store.put(record)
        if on_record:
            on_record(record, False)

    if ray_address is not None:
        if todo:
            _run_on_ray(todo, ray_address, workers, finish, task)
    elif workers == 1 or len(todo) <= 1:
        for spec in todo:
            finish(task(spec))
    else:
        saved = {k: os.environ.get(k) for k in _WORKER_THREADS}
        os.environ.update(_WORKER_THREADS)  # inherited by the spawned workers
        try:
            with worker_pool(workers) as pool:
                futures = [pool.submit(task, spec) for spec in todo]
                for future in as_completed(futures):
                    finish(future.result())
        finally:
            for k, v in saved.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
    return {spec: records[spec] for spec in specs}


#: ``run_episodes``'s ``ray_address`` that starts a local Ray cluster (``--ray``).
RAY_LOCAL = "local"
#: A local Ray cluster's object store, bytes: records are a few kB each, so Ray's default (30 % of the
#: memory, reserved in /dev/shm) would only take memory from the episodes.
RAY_OBJECT_STORE_BYTES = 200 * 1024**2


def _run_task(task: Callable[[EpisodeSpec], dict[str, Any]], spec: EpisodeSpec) -> dict[str, Any]:
    """``task(spec)`` (what a Ray task runs: Ray wants a plain function)."""
    return task(spec)


def _run_on_ray(todo: list[EpisodeSpec], address: str, workers: int, finish: Callable[[dict[str, Any]], None],
                task: Callable[[EpisodeSpec], dict[str, Any]]) -> None:
    """Run ``todo`` as Ray tasks of ``task`` (one CPU and one renderer and BLAS thread each).

    ``finish`` is called on each record.

    Records are finished (stored) in order of completion, as with the process pool, so an interrupted study
    resumes from the store. A local cluster (``RAY_LOCAL``) is started with ``workers`` CPUs (1: all of
    this machine's) and stopped at the end; from a running cluster only this driver disconnects.

    Raises:
        InvalidInputError: Ray is not installed, or the cluster cannot be reached.
    """
    try:
        import ray
    except ImportError as exc:
        raise InvalidInputError("--ray / --ray-address need Ray: pip install 'arc-calib[ray]' "
                                "(or pip install ray)") from exc
    local = address == RAY_LOCAL
    options: dict[str, Any] = {"runtime_env": {"env_vars": dict(_WORKER_THREADS)}, "logging_level": "WARNING"}
    if local:
        options.update(address="local", num_cpus=workers if workers > 1 else os.cpu_count(),
                       object_store_memory=RAY_OBJECT_STORE_BYTES, include_dashboard=False)
    else:
        options.update(address=address)
    try:
        ray.init(**options)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        what = "start a local Ray cluster" if local else f"reach the Ray cluster at {address!r}"
        raise InvalidInputError(f"cannot {what}: {exc}") from exc
    try:
        remote = ray.remote(num_cpus=1, max_retries=0)(_run_task)
        pending = [remote.remote(task, spec) for spec in todo]
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            finish(ray.get(done[0]))
    finally:
        ray.shutdown()


def add_study_outline_argument(parser: argparse.ArgumentParser, default: int) -> None:
    """The study scripts' ``--outline-frames N`` (>= 0), defaulting to ``default``.

    Not ``arc_env.cli.calibrate.add_outline_argument``: the commands' default depends on whether an offscreen GL
    context can be made, while a study's episodes name their count in their records.
    """
    def frames(text: str) -> int:
        try:
            n = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
        if n < 0:
            raise argparse.ArgumentTypeError(f"must be >= 0, got {n}")
        return n

    parser.add_argument("--outline-frames", type=frames, default=default,
                        help="images per motion for the outline stage (the robot's outlines adjusted with the "
                             f"tracks; tracked ARC-Calib runs only); default {default}; 0: the tracks alone")


def write_figures(path: Path, figures: dict[str, Any]) -> None:
    """Write a study's ``--json`` document; infinite or NaN figures become null."""
    def clean(x: Any) -> Any:
        if isinstance(x, dict):
            return {k: clean(v) for k, v in x.items()}
        if isinstance(x, float):
            return x if np.isfinite(x) else None
        return x

    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(clean(figures), indent=2))
