"""Observations refuse what no camera or robot produces: absurd pixels, non-integer joints."""

import numpy as np
import pytest

from solver.errors import InvalidInputError
from solver.observations import MAX_PIXEL_MAGNITUDE, KeypointTrack, MotionObservation


def _track(scale=1.0):
    return KeypointTrack(np.array([[100.0, 200.0], [101.0, 201.0], [102.0, 203.0]]) * scale, np.array([0, 0.1, 0.2]))


def test_absurd_pixels_are_refused_with_their_magnitude():
    with pytest.raises(InvalidInputError, match=r"track pixels reach 2\.03e\+302 px: beyond any image"):
        _track(1e300)
    assert len(_track(MAX_PIXEL_MAGNITUDE / 300)) == 3  # far outside the image, still a number of pixels


@pytest.mark.parametrize("joint", [1.7, 2.0, "2", True, None], ids=["float", "integral-float", "str", "bool", "none"])
def test_a_joint_must_be_an_integer_index(joint):
    with pytest.raises(InvalidInputError, match="joint must be an integer index"):
        MotionObservation(q_start=np.zeros(7), joint=joint, tracks=(_track(),))


def test_numpy_integer_joints_are_indices():
    assert MotionObservation(q_start=np.zeros(7), joint=np.int64(3), tracks=(_track(),)).joint == 3


def test_track_velocity_is_optional_and_checked_like_delta():
    pixels, delta = _track().pixels, _track().delta
    assert _track().velocity is None
    track = KeypointTrack(pixels, delta, [0.5, 1.0, 0.5])
    assert track.velocity.dtype == np.float64 and track.velocity.shape == (3,)
    with pytest.raises(InvalidInputError, match="3 pixel rows but 2 velocity values"):
        KeypointTrack(pixels, delta, [0.5, 1.0])
    with pytest.raises(InvalidInputError, match="track velocity contains NaN"):
        KeypointTrack(pixels, delta, [0.5, np.nan, 0.5])
