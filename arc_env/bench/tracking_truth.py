"""How far the tracker's points are from the surface points they started on, in rendered episodes.

Simulation only: each track's first pixel is cast onto the robot (``Scene.surface_point_at``, at the
frame's true configuration), and that body-fixed point is projected with the true camera at each of the
track's frames. The difference is the tracker's error alone (the rendering is exact). Per motion:

- ``tracks``: tracks handed to the calibrator; ``on_links``: those that start on a link the joint moves;
- ``end_error_px``: median distance from the truth at each such track's last frame;
- ``within_1px``: the fraction of them that never leave the truth by more than 1 px;
- ``chord_scale``: median of (tracked chord / true chord) - 1 along the true chord (first to last frame),
  over tracks within 3 px of the truth that travel 5 px or more: a negative value means tracks lag (a
  turn that looks shorter than it was, which the bundle adjustment reads as a camera farther away).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from arc_env.robot.session import SeenMotion
from planners.random_planner import RandomPlanner
from solver.arrays import FloatArray
from solver.errors import ArcCalibError
from solver.observations import KeypointTrack

#: Tracks nearer the truth than this count towards ``chord_scale``; px.
CHORD_MAX_ERROR_PX = 3.0
#: ... and only if their true chord is at least this long; px.
CHORD_MIN_PX = 5.0


@dataclass(frozen=True)
class MotionTruth:
    """One motion's tracker errors against the simulator's truth (module doc)."""

    joint: int
    tracks: int
    on_links: int
    end_error_px: float | None
    within_1px: float | None
    chord_scale: float | None


def true_pixels(scene: Any, q_start: FloatArray, joint: int, deltas: FloatArray,  # noqa: ANN401 (sim Scene)
                track: KeypointTrack) -> FloatArray | None:
    """(M, 2) px: where the surface point under the track's first pixel is at each of its frames, or None.

    ``deltas`` (F,) rad are the sweep's frames' true turns; each track value is matched to its frame.
    None when the first pixel does not fall on a link the joint moves. Leaves the arm at the track's
    last frame.
    """
    robot = scene.robot
    moved = np.unique(robot.surface_points(joint)[0])
    frames = np.abs(np.asarray(deltas)[None, :] - track.delta[:, None]).argmin(axis=1)
    robot.set_swept(q_start, joint, float(deltas[frames[0]]))
    hit = scene.surface_point_at(track.pixels[0])
    if hit is None or hit[0] not in moved:
        return None
    body, local = np.array([hit[0]]), hit[1][None, :]
    pixels = np.empty((len(frames), 2))
    for i, k in enumerate(frames):
        robot.set_swept(q_start, joint, float(deltas[k]))
        pixels[i] = robot.project_points(body, local, scene.T_camera_base, scene.intrinsics, 0.0)[0][0]
    return pixels


def motion_truth(scene: Any, seen: SeenMotion) -> MotionTruth:  # noqa: ANN401 (sim Scene)
    """Score one seen motion's tracks (module doc); the arm is put back at the sweep's end."""
    ends, within, chords = [], [], []
    for track in seen.tracks:
        truth = true_pixels(scene, seen.q_start, seen.joint, seen.deltas, track)
        if truth is None:
            continue
        error = np.linalg.norm(track.pixels - truth, axis=1)
        ends.append(error[-1])
        within.append(error.max() <= 1.0)
        chord = truth[-1] - truth[0]
        length = float(np.linalg.norm(chord))
        if error.max() <= CHORD_MAX_ERROR_PX and length >= CHORD_MIN_PX:
            chords.append((track.pixels[-1] - track.pixels[0]) @ chord / length**2 - 1.0)
    scene.robot.set_swept(seen.q_start, seen.joint, float(seen.deltas[-1]))
    return MotionTruth(seen.joint, len(seen.tracks), len(ends), float(np.median(ends)) if ends else None,
                       float(np.mean(within)) if within else None,
                       float(np.median(chords)) if chords else None)


def summary(motions: list[MotionTruth]) -> dict[str, Any]:
    """Medians over motions (None where no motion had a value) and the per-motion rows."""
    def median(name: str) -> float | None:
        values = [getattr(m, name) for m in motions if getattr(m, name) is not None]
        return float(np.median(values)) if values else None

    return {"motions": len(motions), "tracks_median": median("tracks"), "on_links_median": median("on_links"),
            "end_error_px_median": median("end_error_px"), "within_1px_median": median("within_1px"),
            "chord_scale_median": median("chord_scale"), "per_motion": [asdict(m) for m in motions]}


def rendered_motions(env: Any, obs: Any, spec: Any) -> list[SeenMotion]:  # noqa: ANN401 (sim env, EpisodeSpec)
    """Run ``spec``'s episode in ``env`` (reset, first observation ``obs``) with its tracker: the seen motions."""
    seen: list[SeenMotion] = []
    env.session.observer = lambda motion: seen.append(motion) if motion.frames is not None else None
    planner = RandomPlanner(env.session, np.random.default_rng(spec.rng_seed))
    while len(seen) < spec.motions:
        try:
            action = planner.plan(obs)
        except ArcCalibError:
            break
        obs, _, _, truncated, info = env.step(action)
        if info["refused"] and truncated:
            break
    return seen
