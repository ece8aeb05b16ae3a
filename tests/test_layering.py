"""The one-way arrows: ``solver <- planners <- arc_env.robot <- arc_env.sim <- arc_env.bench, arc_env.cli``.

Two checks. Fresh interpreters (subprocesses) import the packages a real robot needs and report which
modules got loaded and whether ``MUJOCO_GL`` was set. And every ``import`` statement of every module,
lazy ones inside functions included, is read with ``ast`` and checked against the layers.
"""

from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Layer of each package: a module may import its own layer and those below, never above.
LAYERS = {"solver": 0, "planners": 1, "arc_env.robot": 2, "arc_env.sim": 3, "arc_env.bench": 4, "arc_env.cli": 4}


def _loaded_after(imports: str) -> dict:
    code = (f"import json, os, sys\n{imports}\n"
            "print(json.dumps({'modules': sorted(sys.modules), 'MUJOCO_GL': os.environ.get('MUJOCO_GL')}))")
    env = {k: v for k, v in os.environ.items() if k != "MUJOCO_GL"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, env=env, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_planners_load_no_arc_env_module():
    loaded = _loaded_after("import planners, planners.random_planner, planners.informed, planners.transit")
    assert "planners.informed.planner" in loaded["modules"]  # the imports happened
    assert [m for m in loaded["modules"] if m == "arc_env" or m.startswith("arc_env.")] == []


def test_the_real_robot_side_loads_neither_gymnasium_nor_the_simulator_and_sets_no_gl():
    loaded = _loaded_after("import arc_env.robot.recording, arc_env.robot.session, arc_env.robot.tracking, "
                           "arc_env.robot.exports, arc_env.robot.overlay, arc_env.robot.driver, arc_env.robot.library, "
                           "arc_env.robot.bag, arc_env.robot.segmentation, arc_env.robot.timing, arc_env.robot.verify, "
                           "arc_env.robot.motion_script, arc_env.robot.obstacles, arc_env.robot.report, "
                           "arc_env.robot.rerun_log, arc_env.cli.plan")
    modules = loaded["modules"]
    assert "arc_env.robot.session" in modules and "mujoco" in modules  # MuJoCo as kinematics is allowed
    assert [m for m in modules if m == "gymnasium" or m.startswith("gymnasium.")] == []
    assert [m for m in modules if m.startswith(("arc_env.sim", "arc_env.bench", "arc_env.cli"))] == [
        "arc_env.cli", "arc_env.cli.plan"]  # plan reads and writes for a real robot: no simulator behind it
    assert loaded["MUJOCO_GL"] is None


def test_importing_arc_env_alone_is_light_and_registers_the_env_with_gymnasium():
    loaded = _loaded_after("import arc_env")
    assert not {"mujoco", "gymnasium", "cv2"} & set(loaded["modules"]) and loaded["MUJOCO_GL"] is None
    loaded = _loaded_after("import arc_env, gymnasium\n"
                           "assert 'ArcCalib-v0' in gymnasium.envs.registration.registry")
    assert "gymnasium" in loaded["modules"]


def test_solver_loads_no_mujoco():
    loaded = _loaded_after("import solver, solver.pipeline, solver.refinement")
    assert "solver.pipeline" in loaded["modules"] and "mujoco" not in loaded["modules"]


def _layer(module: str) -> tuple[str, int] | None:
    for package, rank in sorted(LAYERS.items(), key=lambda kv: -len(kv[0])):
        if module == package or module.startswith(package + "."):
            return package, rank
    return None


def _imports(path: Path) -> list[tuple[int, str]]:
    tree = ast.parse(path.read_text(), filename=str(path))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.append((node.lineno, node.module))
    return found


def _modules() -> list[tuple[str, Path]]:
    out = []
    for package in ("solver", "planners", "arc_env"):
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            out.append((".".join(parts[:-1] if parts[-1] == "__init__" else parts), path))
    return out


@pytest.mark.parametrize("module,path", _modules(), ids=[m for m, _ in _modules()])
def test_every_import_points_down_the_layers(module, path):
    own = _layer(module)
    if own is None:  # arc_env/__init__.py: registers the env, imports nothing of ours
        assert all(_layer(target) is None for _, target in _imports(path)), module
        return
    own_package, own_rank = own
    for line, target in _imports(path):
        theirs = _layer(target)
        if theirs is None:
            continue
        package, rank = theirs
        upward = rank > own_rank or (rank == own_rank and package != own_package)
        assert not upward, f"{path.relative_to(ROOT)}:{line} imports {target} ({package} is not below {own_package})"
