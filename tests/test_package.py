import importlib

import pytest

import solver


@pytest.mark.parametrize("name", solver.__all__)
def test_every_public_name_imports(name):
    assert getattr(solver, name) is not None


@pytest.mark.parametrize("module", ["solver", "arc_env", "planners"])
def test_packages_import(module):
    importlib.import_module(module)


def test_solver_never_imports_mujoco():
    import subprocess
    import sys

    code = "import sys, solver, solver.pipeline; print('mujoco' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
