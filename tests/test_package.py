import importlib

import pytest

import solver


@pytest.mark.parametrize("name", solver.__all__)
def test_every_public_name_imports(name):
    assert getattr(solver, name) is not None


@pytest.mark.parametrize("module", ["solver", "arc_env", "planners"])
def test_packages_import(module):
    importlib.import_module(module)
