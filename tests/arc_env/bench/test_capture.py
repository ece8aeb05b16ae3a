"""arc_env.bench.capture: a rendered episode's calibrator inputs, replayed through the solver alone."""

import pickle

import numpy as np
import pytest

from arc_env.bench.capture import capture_episode, load_capture, replay, save_capture
from arc_env.bench.episodes import EpisodeSpec
from solver.errors import InvalidInputError
from tests.support.scripts import load_script

#: A small clean episode with the outline stage: 4 motions at 480x270.
SPEC = EpisodeSpec("random", 1, 0, 4, 480, 270, False, "clean", None, "panda", 3)


@pytest.fixture(scope="module")
def capture():
    return capture_episode(SPEC)


def test_a_replay_gives_the_episodes_own_estimates(capture, tmp_path):
    assert len(capture.calls) == SPEC.motions and len(capture.estimates) == SPEC.motions
    assert any(len(outlines) for _, _, outlines in capture.calls)  # the outline images came along
    assert any(T is not None for T in capture.estimates)
    save_capture(capture, tmp_path / "c.pkl")
    states = replay(load_capture(tmp_path / "c.pkl"))
    for state, T in zip(states, capture.estimates, strict=True):
        assert (state.T_camera_base is None) == (T is None)
        if T is not None:
            np.testing.assert_allclose(state.T_camera_base, T, atol=1e-9)


def test_the_script_prints_each_motion_and_bad_input_is_refused(capture, tmp_path, capsys):
    save_capture(capture, tmp_path / "c.pkl")
    assert load_script("replay_solver").main(["replay", str(tmp_path / "c.pkl")]) == 0
    out = capsys.readouterr().out
    assert SPEC.key in out and sum(line.lstrip().startswith(("1 ", "2 ", "3 ", "4 ")) for line in out.splitlines()) == 4
    (tmp_path / "not.pkl").write_bytes(pickle.dumps({"a": 1}))
    with pytest.raises(InvalidInputError, match="not a capture"):
        load_capture(tmp_path / "not.pkl")
    with pytest.raises(InvalidInputError, match="tracked"):
        capture_episode(EpisodeSpec("random", 1, 0, 4, 480, 270, True))
