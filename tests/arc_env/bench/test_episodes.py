"""arc_env.episodes: one benchmark episode runner and its resumable store."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from arc_env.bench.episodes import EpisodeSpec, EpisodeStore, commits_used, padded_curve, run_episodes
from solver.errors import InvalidInputError

REPO = Path(__file__).resolve().parents[3]

#: A small oracle episode: no rendering of frames, a few seconds.
SPEC = EpisodeSpec("random", pose=1, seed=0, motions=3, width=480, height=270, oracle=True)


def test_spec_checks_and_key():
    assert SPEC.key == "random-oracle_480x270_m3_p1_s0"
    assert SPEC.rng_seed == 1000
    with pytest.raises(InvalidInputError, match="unknown method 'apriltag'"):
        EpisodeSpec("apriltag", 0, 0)
    with pytest.raises(InvalidInputError, match="no oracle"):
        EpisodeSpec("marker", 0, 0, oracle=True)
    with pytest.raises(InvalidInputError):
        EpisodeSpec("random", 0, 0, motions=0)


def test_the_robot_is_in_the_key_only_when_not_the_panda(tmp_path):
    assert EpisodeSpec("random", 1, 0, 3, 480, 270, oracle=True, robot="panda").key == SPEC.key
    iiwa = EpisodeSpec("random", 1, 0, 3, 480, 270, oracle=True, robot="iiwa")
    assert iiwa.key == "random-oracle_iiwa_480x270_m3_p1_s0"
    with pytest.raises(InvalidInputError, match="unknown robot 'ur5'; valid: panda, iiwa, xarm6"):
        EpisodeSpec("random", 0, 0, robot="ur5")
    with pytest.raises(InvalidInputError, match="mounts on the Panda"):
        EpisodeSpec("marker", 0, 0, robot="xarm6")
    store = EpisodeStore(tmp_path)  # a record stored before the field existed is still the Panda's
    old = {k: v for k, v in vars(SPEC).items() if k != "robot"}
    store.path(SPEC).write_text(json.dumps({"spec": old, "curve": []}))
    assert store.get(SPEC) is not None and store.get(iiwa) is None


def test_padded_curve_holds_the_last_estimate():
    record = {"curve": [None, [0.1, 0.02], [0.05, 0.01]]}
    assert padded_curve(record, 5) == [(np.inf, np.inf), (0.1, 0.02), (0.05, 0.01), (0.05, 0.01), (0.05, 0.01)]
    assert padded_curve(record, 2) == [(np.inf, np.inf), (0.1, 0.02)]
    assert padded_curve({"curve": []}, 2) == [(np.inf, np.inf)] * 2


@pytest.fixture(scope="module")
def stored(tmp_path_factory):
    store = EpisodeStore(tmp_path_factory.mktemp("episodes"))
    seen = []
    records = run_episodes([SPEC], store, on_record=lambda r, from_store: seen.append(from_store))
    return store, records[SPEC], seen


def test_a_run_is_recorded_and_stored(stored):
    store, record, seen = stored
    assert seen == [False]
    assert record["spec"]["method"] == "random" and record["in_collision"] == 0
    assert len(record["curve"]) == SPEC.motions and len(record["planning"]) >= SPEC.motions
    assert record["seconds"]["total"] > 0
    # the conics run for the front-end count alone are timed apart from the solver (which keeps the rest)
    assert record["seconds"]["report"] >= 0.0 and record["seconds"]["solver"] > 0.0
    assert len(record["std_curve"]) == SPEC.motions and record["false_convergence"] == 0
    assert all(s is None or (len(s) == 2 and min(s) > 0) for s in record["std_curve"])
    # a chi-square wherever there is a 1-sigma (the same covariance), and only there
    assert [c is None for c in record["chi2_curve"]] == [s is None for s in record["std_curve"]]
    assert any(c is not None for c in record["chi2_curve"]) and all(c is None or c >= 0 for c in record["chi2_curve"])
    # the error and covariance curves give the chi-square again (an independent computation of it)
    for xi, cov, c in zip(record["error_curve"], record["covariance_curve"], record["chi2_curve"], strict=True):
        if c is not None:
            xi, cov = np.asarray(xi), np.asarray(cov)
            assert xi.shape == (6,) and cov.shape == (6, 6)
            assert np.isclose(xi @ np.linalg.solve(cov, xi), c, rtol=1e-6)
    # Each motion with an axis got it from the rigid front end or the conics (or both gave one).
    assert record["axes_rigid"] <= record["axes"] <= record["axes_conics"] + record["axes_rigid"]
    assert record["axes"] <= SPEC.motions
    assert json.loads(store.path(SPEC).read_text()) == json.loads(json.dumps(record))


def test_a_stored_run_is_reused_not_rerun(stored):
    store, record, _ = stored
    seen = []
    again = run_episodes([SPEC], store, on_record=lambda r, from_store: seen.append(from_store))
    assert seen == [True]
    assert again[SPEC] == json.loads(json.dumps(record))
    assert commits_used(again.values()).endswith("(1 runs)")


def test_a_foreign_or_broken_file_is_not_reused(stored, tmp_path):
    store = EpisodeStore(tmp_path)
    other = EpisodeSpec("random", pose=1, seed=0, motions=3, width=480, height=270, oracle=True)
    store.path(other).write_text("{not json")
    assert store.get(other) is None
    _, record, _ = stored
    foreign = dict(record, spec=dict(record["spec"], seed=7))
    store.path(other).write_text(json.dumps(foreign))
    assert store.get(other) is None


def test_same_spec_same_record_fields(stored):
    """Episodes are deterministic: a rerun gives the same errors (timings differ)."""
    _, record, _ = stored
    rerun = run_episodes([SPEC])[SPEC]
    assert rerun["curve"] == json.loads(json.dumps(record))["curve"]


def test_each_realistic_episode_marks_its_robot_with_its_own_seed():
    from arc_env.bench.episodes import make_env

    marks = []
    for seed in (0, 1):
        spec = EpisodeSpec("random", 0, seed, motions=1, width=64, height=48, realism="realistic")
        env, _ = make_env(spec)
        try:
            assert env.scene.config.appearance_seed == spec.rng_seed
            marks.append((env.scene.marks.patterns, [label.pos.tolist() for label in env.scene.marks.labels]))
        finally:
            env.close()
    assert marks[0] != marks[1]


#: Record fields that are wall time, not results: they differ between any two runs.
TIMINGS = ("seconds", "planning")


def _results(record):
    return {k: v for k, v in json.loads(json.dumps(record)).items() if k not in TIMINGS}


def test_ray_runs_give_the_records_of_one_process(stored, tmp_path):
    """Two episodes as tasks on a local Ray cluster: the same figures as workers=1, stored and resumable."""
    pytest.importorskip("ray", reason="Ray is optional (pip install 'arc-calib[ray]'); the CI installs it")
    from arc_env.bench.episodes import RAY_LOCAL

    _, record, _ = stored
    other = EpisodeSpec("random", pose=2, seed=0, motions=3, width=480, height=270, oracle=True)
    in_process = {SPEC: record, other: run_episodes([other])[other]}
    store = EpisodeStore(tmp_path)
    seen = []
    on_ray = run_episodes([SPEC, other], store, workers=2, ray_address=RAY_LOCAL,
                          on_record=lambda r, from_store: seen.append(from_store))
    assert seen == [False, False]
    for spec, expected in in_process.items():
        assert _results(on_ray[spec]) == _results(expected)
        assert _results(store.get(spec)) == _results(expected)
    assert any(e is not None for e in on_ray[SPEC]["curve"])  # the comparison holds an estimate
    again = run_episodes([SPEC, other], store, ray_address=RAY_LOCAL)  # all stored: no cluster is started
    assert all(_results(again[s]) == _results(in_process[s]) for s in in_process)


def test_ray_without_ray_installed_says_how_to_get_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray now raises ImportError
    with pytest.raises(InvalidInputError, match=r"pip install 'arc-calib\[ray\]'"):
        run_episodes([SPEC], ray_address="local")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
def test_pool_workers_end_when_their_parent_is_terminated(tmp_path):
    # A study stopped by SIGTERM to its parent alone must not leave its workers rendering for nothing.
    script = tmp_path / "parent.py"
    script.write_text(
        "import os, time\n"
        "from arc_env.bench.episodes import worker_pool\n"
        "if __name__ == '__main__':\n"  # spawned workers import this file too
        "    with worker_pool(2) as pool:\n"
        "        pids = {pool.submit(os.getpid).result() for _ in range(4)}\n"
        "        busy = [pool.submit(time.sleep, 120) for _ in range(2)]\n"
        "        print(' '.join(map(str, sorted(pids))), flush=True)\n"
        "        time.sleep(120)\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    parent = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True, env=env)
    try:
        workers = [int(p) for p in parent.stdout.readline().split()]
        assert workers and all(_alive(p) for p in workers)
        parent.send_signal(signal.SIGTERM)
        parent.wait(timeout=30)
        deadline = time.monotonic() + 30
        while any(_alive(p) for p in workers) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not any(_alive(p) for p in workers)
    finally:
        parent.kill()
        parent.wait()


def test_a_worker_whose_parent_is_gone_ends_at_once():
    # die_with_parent's race: re-parented before the request took effect -> it ends itself.
    child = subprocess.Popen([sys.executable, "-c",
                              "import sys, time; sys.path.insert(0, sys.argv[1])\n"
                              "from arc_env.bench.episodes import die_with_parent\n"
                              "die_with_parent(-1)\n"  # no process's pid: as if the parent had died
                              "time.sleep(60)\n", str(REPO)])
    assert child.wait(timeout=30) == -signal.SIGTERM


def _alive(pid: int) -> bool:
    """Whether process ``pid`` exists and is not a zombie."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def test_outline_frames_mark_the_key_and_need_tracked_arc_calib():
    assert EpisodeSpec("random", 3, 1).key == "random_1920x1080_m25_p3_s1"
    assert EpisodeSpec("random", 3, 1, outline_frames=3).key == "random_1920x1080_m25_o3_p3_s1"
    for bad in ({"oracle": True}, {"method": "marker"}, {"outline_frames": -1}):
        with pytest.raises(InvalidInputError):
            EpisodeSpec(**{"method": "random", "pose": 0, "seed": 0, "outline_frames": 3, **bad})
