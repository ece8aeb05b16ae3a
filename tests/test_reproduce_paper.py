"""scripts/reproduce_paper.py: a tiny run of the marker method writes the table, plots and JSON keys."""

import json

import pytest

from tests.support.scripts import load_script


@pytest.fixture(scope="module")
def script():
    return load_script("reproduce_paper")


def test_tiny_marker_run_writes_the_figures(script, tmp_path):
    out = tmp_path / "figures.json"
    code = script.main(["--methods", "marker", "--poses", "1", "--seeds", "1", "--motions", "3",
                        "--width", "960", "--height", "540", "--iou-configs", "1", "--out", str(tmp_path),
                        "--json", str(out), "--outline-frames", "3"])  # the marker has no outline stage: ignored
    assert code == 0
    figures = json.loads(out.read_text())
    assert list(figures) == ["methods"] and list(figures["methods"]) == ["marker"]
    marker = figures["methods"]["marker"]
    assert set(marker) == {"errors", "iou_mean"} and list(marker["errors"]) == ["3", "10", "25"]
    assert marker["errors"]["3"]["rot_median_rad"] is not None  # three board poses give an estimate
    assert marker["errors"]["25"] == {"rot_median_rad": None, "trans_median_m": None}  # beyond --motions
    assert 0.0 <= marker["iou_mean"] <= 1.0
    for name in ("errors.png", "iou.png", "results.md"):
        assert (tmp_path / name).stat().st_size > 0


def test_no_iou_study_shows_as_a_dash_not_inf(script):
    """--iou-configs 0: each run's IoU is NaN; the table says "-" (inf means no estimate), the mean is NaN."""
    summary = {"marker": {"rot": [1e-3] * 25, "trans": [1e-3] * 25}}
    table = script.markdown_table(summary, {"marker": script._finite_mean([float("nan")] * 3)}, 25, "header")
    row = next(line for line in table.splitlines() if line.startswith("| marker"))
    assert row.endswith("| - |") and "inf" not in row
    assert script._finite_mean([0.5, float("nan"), 0.7]) == pytest.approx(0.6)


def test_unknown_method_is_an_error(script):
    with pytest.raises(SystemExit):
        script.main(["--methods", "apriltag"])


@pytest.mark.parametrize("frames", ["-1", "three"])
def test_bad_outline_frames_are_an_error(script, frames, capsys):
    with pytest.raises(SystemExit):
        script.main(["--methods", "marker", "--outline-frames", frames])
    assert "--outline-frames" in capsys.readouterr().err
