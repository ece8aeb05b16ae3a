"""arc_env.bench.capture: a rendered episode's calibrator inputs, replayed through the solver alone."""

import copy
import pickle

import numpy as np
import pytest

from arc_env.bench.capture import (
    CapturedOutline,
    _outlines,
    capture_episode,
    load_capture,
    replay,
    rescore,
    save_capture,
)
from arc_env.bench.episodes import EpisodeSpec, EpisodeStore, code_version, run_episodes
from arc_env.bench.runner import study_task
from solver.errors import InvalidInputError
from solver.mask_start import change_mask
from tests.support.scripts import load_script

#: A small clean episode with the outline stage: 4 motions at 480x270.
SPEC = EpisodeSpec("random", 1, 0, 4, 480, 270, False, "clean", None, "panda", 3)


#: The record's fields that a replay computes again (``arc_env.bench.episodes.note_state``, ``note_calibrator``).
SOLVER_FIELDS = ("curve", "std_curve", "chi2_curve", "error_curve", "covariance_curve", "false_convergence",
                 "outline_curve", "outline_note", "converged_at", "T_camera_base", "axes", "axes_conics",
                 "axes_rigid", "usable")


@pytest.fixture(scope="module")
def kept(tmp_path_factory):
    """A store holding SPEC's record and, from the same run, its capture."""
    store = EpisodeStore(tmp_path_factory.mktemp("kept"))
    run_episodes([SPEC], store, task=study_task(store.root, keep_captures=True))
    return store


@pytest.fixture(scope="module")
def capture(kept):
    return load_capture(kept.capture_path(SPEC))


def _assert_same(a, b):
    """Two JSON-able values equal, numbers within 1e-9 (relative 1e-6)."""
    if isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b)
        for x, y in zip(a, b, strict=True):
            _assert_same(x, y)
    elif isinstance(a, float) and not isinstance(b, bool):
        assert b == pytest.approx(a, rel=1e-6, abs=1e-9)
    else:
        assert a == b


def test_a_replay_gives_the_episodes_own_estimates(capture, tmp_path):
    assert len(capture.calls) == SPEC.motions and len(capture.estimates) == SPEC.motions
    outlines = [o for _, _, images in capture.calls for o in images]
    assert outlines and all(isinstance(o, CapturedOutline) for o in outlines)  # the grey frames came along
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
    assert load_script("replay_solver").main(["replay", str(tmp_path / "missing.pkl")]) == 2
    assert "not a readable capture" in capsys.readouterr().err
    with pytest.raises(InvalidInputError, match="tracked"):
        capture_episode(EpisodeSpec("random", 1, 0, 4, 480, 270, True))


def test_a_replayed_study_rewrites_the_solvers_fields_of_the_same_record(kept, tmp_path):
    original = kept.get(SPEC)
    assert original is not None and kept.capture_path(SPEC).is_file()
    seen = []
    dest = EpisodeStore(tmp_path / "replayed")
    replayed = run_episodes([SPEC], dest, on_record=lambda r, s: seen.append(s),
                            task=study_task(dest.root, replay_from=kept.root))[SPEC]
    assert seen == [False] and dest.get(SPEC) == replayed
    for name in SOLVER_FIELDS:  # the solver has not changed: its fields come out the same
        _assert_same(original[name], replayed[name])
    for name in ("tracks", "full_tracks", "frames", "planning", "refused", "in_collision", "note"):
        assert replayed[name] == original[name]  # the episode's own (not rendered again)
    assert replayed["commit"] == code_version()
    assert replayed["replayed_from"] == {"commit": original["commit"], "seconds": original["seconds"]}
    assert replayed["seconds"]["solver"] > 0 and replayed["seconds"]["render"] == original["seconds"]["render"]
    assert not (tmp_path / "replayed" / "captures").exists()  # a replay keeps none unless asked


def test_a_replay_refuses_what_does_not_belong_together(kept, capture, tmp_path):
    original = kept.get(SPEC)
    with pytest.raises(InvalidInputError, match="own"):
        study_task(kept.root, replay_from=kept.root)
    with pytest.raises(InvalidInputError, match="no store"):
        study_task(tmp_path / "d", replay_from=tmp_path / "missing")
    with pytest.raises(InvalidInputError, match="needs a store"):
        study_task(None, keep_captures=True)
    other = copy.deepcopy(original)
    other["spec"]["pose"] = 2
    with pytest.raises(InvalidInputError, match="capture is of"):
        rescore(other, capture)
    short = copy.deepcopy(original)
    short["curve"] = short["curve"][:-1]
    with pytest.raises(InvalidInputError, match="holds 4 motions"):
        rescore(short, capture)
    (tmp_path / "bad.pkl").write_bytes(b"not a pickle")
    with pytest.raises(InvalidInputError, match="not a readable capture"):
        load_capture(tmp_path / "bad.pkl")


def test_a_replay_finds_the_change_masks_the_episode_had(capture):
    """The session gives each motion's outline images after the first where they differ from it
    (``OutlineImage.changed``); a replay finds them again from the captured grey frames."""
    _, _, images = capture.calls[0]
    replayed = _outlines(images)
    assert replayed[0].changed is None and all(image.changed is not None for image in replayed[1:])
    greys = [image.grey() for image in images]
    for grey, image in zip(greys[1:], replayed[1:], strict=True):
        expected = change_mask([greys[0], grey])
        assert image.changed.cell_px == expected.cell_px
        np.testing.assert_array_equal(image.changed.cells, expected.cells)
    assert any(image.changed.cells.any() for image in replayed[1:])  # the arm moved
