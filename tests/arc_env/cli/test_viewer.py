"""``--rerun-save``: a demo episode's .rrd file read back with the SDK (and ``rerun rrd verify``)."""

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from arc_env.cli import main
from arc_env.robot.rerun_log import ENTITIES, TRUTH_ENTITIES


def _entities(path: Path) -> dict[str, int]:
    from rerun.chunk import RrdReader

    rows: dict[str, int] = {}
    for chunk in RrdReader(path).stream().collect().stream():
        rows[chunk.entity_path.lstrip("/")] = rows.get(chunk.entity_path.lstrip("/"), 0) + chunk.num_rows
    return rows


def _last_scalar(path: Path, entity: str) -> float:
    from rerun.chunk import RrdReader

    values: list[tuple[int, float]] = []
    for chunk in RrdReader(path).stream().collect().stream():
        if chunk.entity_path == "/" + entity and not chunk.is_static:
            batch = chunk.to_record_batch()
            values += [(m, s[0]) for m, s in zip(batch.column("motion").to_pylist(),
                                                 batch.column("Scalars:scalars").to_pylist(), strict=True)]
    return max(values)[1]


def test_demo_writes_an_rrd_that_loads_with_the_named_entities(tmp_path, capsys):
    rrd = tmp_path / "demo.rrd"
    # the cheapest episode with a refined estimate: oracle keypoints (no rendering), 320x240, 5 motions (seed 0
    # refines at the 4th); the frames themselves ("image") are checked on calibrate's log (test_round_trip)
    code = main(["demo", "--oracle", "--width", "320", "--height", "240", "--motions", "5", "--seed", "0",
                 "--rerun-save", str(rrd)])
    out = capsys.readouterr().out
    assert code == 0, out
    assert rrd.is_file() and not list(tmp_path.glob(".*.partial"))
    rows = _entities(rrd)
    missing = [e for e in (*ENTITIES, *TRUTH_ENTITIES) if e not in rows and e != "image"]
    assert not missing, (missing, sorted(rows))
    assert "image" not in rows  # oracle keypoints: no frames
    assert any(e.startswith("world/robot/links/") and e.endswith("/mesh") for e in rows)
    n_frames = rows["image/tracks"]
    assert 5 * 5 <= n_frames <= 5 * 12 and rows["world/robot/skeleton"] == n_frames
    assert rows["log"] == 5  # one line per motion
    # the error curve ends at the error the demo printed
    printed = re.search(r"final error: rotation .* translation ([0-9.]+) mm", out)
    assert printed and abs(_last_scalar(rrd, "curves/translation_mm/error") - float(printed.group(1))) < 1e-3
    # and Rerun's own loader accepts the file
    rerun = shutil.which("rerun", path=str(Path(sys.executable).parent)) or shutil.which("rerun")
    if rerun is not None:
        verified = subprocess.run([rerun, "rrd", "verify", str(rrd)], capture_output=True, text=True, timeout=60)
        assert verified.returncode == 0, verified.stderr


def test_rerun_save_is_checked_before_any_work(tmp_path, capsys):
    assert main(["demo", "--rerun-save", str(tmp_path / "log.txt")]) == 1
    assert "must name a .rrd file" in capsys.readouterr().err
    assert main(["demo", "--synthetic", "--rerun-save", str(tmp_path / "a.rrd")]) == 2
    assert "need the MuJoCo scene" in capsys.readouterr().err


@pytest.mark.parametrize("flag", ["--rerun", "--rerun-save"])
def test_the_commands_take_the_rerun_options(flag, capsys):
    for command in ("demo", "calibrate", "run"):
        with pytest.raises(SystemExit):
            main([command, "--help"])
        assert flag in capsys.readouterr().out
