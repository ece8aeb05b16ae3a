"""Tests of arc_env/bench/dense_flow.py: DIS flow chained into tracks, against the tracker tests' synthetic sweeps.

The sweeps (``tests.arc_env.robot.test_tracking``: a textured plate turning over a static textured background, in
the image plane or on a tilted plane in perspective) are built independently of the code under test; the truth
maps a track's first pixel through the known turn at each of its deltas.
"""

from __future__ import annotations

import numpy as np
import pytest

from arc_env.bench.dense_flow import DenseFlowConfig, dense_flow_tracks
from solver.errors import InvalidInputError
from tests.arc_env.robot.test_tracking import PLATE_RADIUS, SWEEPS, Sweep, track_errors

#: Tracks starting this far inside the plate's edge (plate units) see texture all round: there the flow is the
#: plate's own motion.
INSIDE = PLATE_RADIUS - 15.0
#: Their error against the truth: median over every frame of every such track, and median at each track's last
#: frame; px. DIS flow chained over the 40 frames drifts (measured with the defaults: 0.39 / 0.91 px in the image
#: plane, 0.63 / 1.41 px in perspective; the corner tracker's test holds 0.2 px at every frame's median): the
#: tolerances take twice that with room, and a flow sampled at the wrong place or sign misses by tens of pixels.
MEDIAN_TOL_PX = 1.0
END_TOL_PX = 2.5


@pytest.fixture(scope="module", params=list(SWEEPS), ids=list(SWEEPS))
def sweep(request) -> Sweep:
    return SWEEPS[request.param](np.random.default_rng(7))


def test_tracks_inside_the_plate_follow_it(sweep):
    tracks = dense_flow_tracks(sweep.frames, sweep.delta)
    inside = [t for t in tracks if sweep.plate_distance(t.pixels[0], t.delta[0]) < INSIDE]
    assert len(inside) >= 50
    errors = [track_errors(t, sweep) for t in inside]
    assert np.median(np.concatenate(errors)) < MEDIAN_TOL_PX
    assert np.median([e[-1] for e in errors]) < END_TOL_PX
    assert np.median([len(t.delta) for t in inside]) == len(sweep.delta)  # textured: they span the sweep
    for t in tracks:  # the deltas are the frames' own, in order
        np.testing.assert_array_equal(t.delta, sweep.delta[:len(t.delta)])


def test_nothing_moving_gives_no_tracks(sweep):
    still = [sweep.frames[0]] * 6
    assert dense_flow_tracks(still, np.linspace(0.0, 0.1, 6)) == []


def test_a_texture_floor_seeds_fewer_points(sweep):
    every = dense_flow_tracks(sweep.frames, sweep.delta, DenseFlowConfig(grid_px=6))
    textured = dense_flow_tracks(sweep.frames, sweep.delta, DenseFlowConfig(grid_px=6, min_eigenvalue=1e9))
    assert len(every) > 0 and textured == []


def test_bad_input_is_refused(sweep):
    with pytest.raises(InvalidInputError, match="at least 2 frames"):
        dense_flow_tracks(sweep.frames[:1], sweep.delta[:1])
    with pytest.raises(InvalidInputError, match="delta"):
        dense_flow_tracks(sweep.frames, sweep.delta[:-1])
    with pytest.raises(InvalidInputError, match="delta"):
        dense_flow_tracks(sweep.frames, np.full(len(sweep.frames), np.nan))
    with pytest.raises(InvalidInputError, match="preset"):
        DenseFlowConfig(preset="slow")
    with pytest.raises(InvalidInputError, match="fb_max_px"):
        DenseFlowConfig(fb_max_px=0.0)
