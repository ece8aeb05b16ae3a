"""ARC-Calib's robot side, simulator, benchmarks and command line; importing it registers ``ArcCalib-v0``.

The subpackages, one way down (``solver <- planners <- arc_env.robot <- arc_env.sim <- arc_env.bench,
arc_env.cli``):

* ``arc_env.robot``: what a real robot needs (its model as kinematics, tracking, recordings, the one
  calibration loop, drivers, exports, overlays); never gymnasium, never a GL context.
* ``arc_env.sim``: the MuJoCo scene, rendering, the simulated driver and the Gymnasium env.
* ``arc_env.bench``: episode runner and store, marker baseline, benchmark camera poses.
* ``arc_env.cli``: the ``arc-calib`` command.

Importing this package writes no environment variable and imports neither MuJoCo nor gymnasium (the
real-robot side must not pay for, or depend on, the simulator). ``ArcCalib-v0`` is registered with
gymnasium's registry as soon as both are imported, in either order: now if gymnasium already is, else
right after gymnasium's own import finishes (a one-shot import hook). ``gymnasium.make("ArcCalib-v0")``
then works after ``import arc_env``, and ``gymnasium.make("arc_env:ArcCalib-v0")`` on its own.
"""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import importlib.util
import sys
from types import ModuleType
from typing import Any

ENV_ID = "ArcCalib-v0"
ENTRY_POINT = "arc_env.sim.env:ArcCalibEnv"


def register(gymnasium: ModuleType) -> None:
    """Register ``ArcCalib-v0`` in ``gymnasium``'s registry (once)."""
    if ENV_ID not in gymnasium.envs.registration.registry:
        gymnasium.register(id=ENV_ID, entry_point=ENTRY_POINT)


class _RegisteringLoader(importlib.abc.Loader):
    """Runs gymnasium's own loader, then registers the env."""

    def __init__(self, loader: importlib.abc.Loader):
        self._loader = loader

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType | None:
        return self._loader.create_module(spec)

    def exec_module(self, module: ModuleType) -> None:
        self._loader.exec_module(module)
        register(module)

    def __getattr__(self, name: str) -> Any:  # resource readers, is_package, ...: gymnasium's loader answers
        return getattr(self._loader, name)


class _RegisterWhenImported(importlib.abc.MetaPathFinder):
    """One-shot: wraps gymnasium's loader the first time gymnasium is imported."""

    def find_spec(self, fullname: str, path: Any = None, target: ModuleType | None = None
                  ) -> importlib.machinery.ModuleSpec | None:
        if fullname != "gymnasium":
            return None
        if self in sys.meta_path:
            sys.meta_path.remove(self)
        spec = importlib.util.find_spec(fullname)
        if spec is not None and spec.loader is not None:
            spec.loader = _RegisteringLoader(spec.loader)
        return spec


if "gymnasium" in sys.modules:
    register(sys.modules["gymnasium"])
elif not any(isinstance(f, _RegisterWhenImported) for f in sys.meta_path):
    sys.meta_path.insert(0, _RegisterWhenImported())
