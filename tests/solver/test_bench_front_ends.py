"""scripts/bench_front_ends.py: both front ends measured on synthetic motions, short tracks as realistic images give."""

from __future__ import annotations

import numpy as np

from solver import PANDA, SyntheticConfig, SyntheticScene, d415_intrinsics, sample_camera_pose
from tests.support.scripts import load_script


def test_short_tracks_keep_one_window_of_each_track():
    bench = load_script("bench_front_ends")
    rng = np.random.default_rng(0)
    K = d415_intrinsics()
    obs = SyntheticScene(PANDA, K, sample_camera_pose(rng), SyntheticConfig(), rng).random_motion(rng).observation
    short = bench._shorten(obs, np.random.default_rng(1))
    assert len(short.tracks) == len(obs.tracks)
    for full, cut in zip(obs.tracks, short.tracks, strict=True):
        n, m = len(full.delta), len(cut.delta)
        assert max(6, round(0.3 * n)) <= m <= max(6, round(0.6 * n))
        start = int(np.flatnonzero(full.delta == cut.delta[0])[0])  # one contiguous window of the same frames
        np.testing.assert_array_equal(full.pixels[start:start + m], cut.pixels)


def test_the_rigid_front_end_keeps_its_axis_on_short_tracks():
    bench = load_script("bench_front_ends")
    row = bench.measure("short", 0.5, 4, seed=11)
    assert set(row) == {"conics", "rigid"}
    for r in row.values():
        assert r["motions"] == 4 and 0 <= r["within_3deg"] <= r["with_axis"] <= 4
    assert row["rigid"]["within_3deg"] >= 3
    assert row["rigid"]["median_err_rad"] < np.radians(2.0)
