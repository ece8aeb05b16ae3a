"""The study scripts' runner: their shared command-line options, and the episodes run, kept or replayed by them.

``bench_episode.py``, ``compare_planners.py`` and ``reproduce_paper.py`` take the same ``--realism``, ``--appearance``,
``--background``, ``--workers``, ``--ray``, ``--ray-address``, ``--store``, ``--keep-captures`` and ``--replay-from``
(``add_runner_arguments``) and run their episodes through ``run_from_arguments``:
``arc_env.bench.episodes.run_episodes`` with the task that keeps each episode's capture or replays a stored one
(``arc_env.bench.capture.episode_task``).
"""

from __future__ import annotations

import argparse
import functools
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from arc_env.bench.capture import episode_task
from arc_env.bench.episodes import RAY_LOCAL, EpisodeSpec, EpisodeStore, run_episode, run_episodes
from arc_env.sim.background import BACKGROUNDS
from arc_env.sim.imaging import APPEARANCES, REALISMS
from solver.errors import InvalidInputError

__all__ = ["add_runner_arguments", "check_runner_arguments", "run_from_arguments", "study_task"]


def add_runner_arguments(parser: argparse.ArgumentParser) -> None:
    """The study scripts' ``--workers N``, ``--store DIR`` (read back by :func:`run_from_arguments`) and the look."""
    parser.add_argument("--realism", choices=REALISMS, default="clean",
                        help="camera and robot: clean renders (default) or realistic (noise, blur, H.264, shadows)")
    parser.add_argument("--appearance", choices=APPEARANCES,
                        help="the robot's surface (default: painted when clean, realistic when realistic)")
    parser.add_argument("--background", choices=BACKGROUNDS, default="floor",
                        help="what stands behind the robot: the floor alone (default) or a lab's cabinets, shelves, "
                             "posters and boxes (arc_env.sim.background)")
    parser.add_argument("--workers", type=int, default=1,
                        help="episodes run in parallel processes (default 1); with --ray, the local cluster's CPUs "
                             "(default: all)")
    ray = parser.add_mutually_exclusive_group()
    ray.add_argument("--ray", action="store_true",
                     help="run the episodes as Ray tasks on a local Ray cluster started for this run (pip install "
                          "'arc-calib[ray]')")
    ray.add_argument("--ray-address", metavar="ADDR",
                     help="run the episodes on a running Ray cluster: 'auto' (the one this machine belongs to), "
                          "HOST:PORT or ray://HOST:10001; its nodes need this project installed at the same commit")
    parser.add_argument("--store", type=Path, help="keep finished episodes here and reuse them (resumable runs, "
                        "shared by bench_episode.py, compare_planners.py and reproduce_paper.py)")
    parser.add_argument("--keep-captures", action="store_true",
                        help="also keep each tracked episode's calibrator inputs (tracks and outline frames, about "
                             "16-17 MB per realistic 720p 25-motion episode) under the store's captures/, for "
                             "--replay-from")
    parser.add_argument("--replay-from", type=Path, metavar="DIR",
                        help="a store kept with --keep-captures: its episodes are replayed through this checkout's "
                             "solver (same frames and motions, minutes -> seconds) into --store instead of rendered "
                             "again; episodes it has no capture of are run")


def study_task(store_root: Path | None, keep_captures: bool = False,
               replay_from: Path | None = None) -> Callable[[EpisodeSpec], dict[str, Any]]:
    """The task that gives a study's records (``run_episodes``' ``task``).

    Args:
        store_root: the store's directory, where the records go (None: no store).
        keep_captures: write each tracked ARC-Calib episode's capture into the store too
            (``EpisodeStore.capture_path``, ``arc_env.bench.capture``), to replay it later.
        replay_from: a store (directory) of earlier records kept with their captures: the episodes it has both of
            are replayed through this checkout's solver instead of rendered again.

    Raises:
        InvalidInputError: captures kept without a store, a ``replay_from`` that is not a directory, or replayed
            records that would go to the store they are replayed from.
    """
    if keep_captures and store_root is None:
        raise InvalidInputError("keeping captures needs a store (--store DIR)")
    if replay_from is not None:
        if not Path(replay_from).is_dir():
            raise InvalidInputError(f"no store to replay from at {replay_from}")
        if store_root is None or Path(replay_from).resolve() == Path(store_root).resolve():
            raise InvalidInputError("replayed records go to a store of their own (--store DIR, not the one replayed)")
    if not keep_captures and replay_from is None:
        return run_episode
    return functools.partial(episode_task, capture_root=Path(store_root) if keep_captures and store_root else None,
                             replay_from=None if replay_from is None else Path(replay_from))


def _args_task(args: argparse.Namespace) -> Callable[[EpisodeSpec], dict[str, Any]]:
    """``study_task`` of the options ``add_runner_arguments`` parsed."""
    return study_task(args.store, getattr(args, "keep_captures", False), getattr(args, "replay_from", None))


def check_runner_arguments(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """``parser.error`` (exit 2) when the options that ``add_runner_arguments`` parsed do not go together."""
    try:
        _args_task(args)
    except InvalidInputError as exc:
        parser.error(str(exc))


def run_from_arguments(specs: Iterable[EpisodeSpec], args: argparse.Namespace,
                       on_record: Callable[[dict[str, Any], bool], None] | None = None
                       ) -> dict[EpisodeSpec, dict[str, Any]]:
    """``run_episodes`` with the store, workers, Ray cluster and captures that ``add_runner_arguments`` parsed."""
    ray_address = RAY_LOCAL if getattr(args, "ray", False) else getattr(args, "ray_address", None)
    task = _args_task(args)
    return run_episodes(specs, EpisodeStore(args.store) if args.store else None, args.workers, on_record, ray_address,
                        task)
