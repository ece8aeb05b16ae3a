"""scripts/compare_planners.py: the episodes it asks for (the runner stood in for)."""

import pytest

from tests.support.scripts import SCRIPTS, load_script


class _Stop(Exception):
    pass


@pytest.mark.parametrize(("argv", "frames"), [([], 0), (["--outline-frames", "3"], 3)])
def test_the_outline_stage_reaches_every_episode(monkeypatch, argv, frames):
    monkeypatch.syspath_prepend(str(SCRIPTS))  # it imports reproduce_paper, beside it, as when run as a script
    script = load_script("compare_planners")
    asked = []

    def runner(specs, args, on_record=None):
        asked.extend(specs)
        raise _Stop

    monkeypatch.setattr(script, "run_from_arguments", runner)
    with pytest.raises(_Stop):
        script.main(["--poses", "2", "--seeds", "1", "--motions", "5", *argv])
    assert sorted({s.method for s in asked}) == ["informed", "random"] and len(asked) == 4
    assert {s.outline_frames for s in asked} == {frames}
