"""Environments by versioned name: `make(name, **options)` and `registered()` (STYLE 9, X1).

* ``grid-<map>-v0`` — the grid world of the paper's §V-A (SPEC G1–G5) on a named map
  (`jaxeac.envs.grid.MAPS`: the paper's 11×11 map and its scaled copies).
* The classic tabular tasks (`jaxeac.envs.tasks`, each citing its source): FrozenLake 4×4
  and 8×8, deterministic and slippery; CliffWalking; Windy Gridworld and its stochastic
  variant; Four Rooms, deterministic and stochastic.

Options of every name: ``chances`` (C, G5; default 40 on the grid, the task's own episode
limit elsewhere) and ``slip`` (X1: with this probability a move executes a uniformly random
action). The tasks also take ``rtilde`` (X2: ``shaped`` or ``reward``). All follow the
API of `jaxeac.envs.protocol`. The bowling task's physics is configured with
`jaxeac.envs.bowling.BowlingConfig` (B1–B7). A name's behaviour never changes; a changed
environment gets a new version.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from typing import Any

from jaxeac.errors import UsageError


def _grid(map_name: str) -> Callable[..., Any]:
    def build(chances: int | None = None, slip: float = 0.0):
        from jaxeac.envs.grid import check_chances, check_slip, get_map
        from jaxeac.envs.tabular import grid_world

        chances, slip = check_chances(40 if chances is None else chances), check_slip(slip)
        return grid_world(get_map(map_name), chances, slip, name=f"grid-{map_name}-v0")

    build.__doc__ = f"The grid world on map {map_name!r} (G1–G5), `chances` per trial (G5), `slip` (X1)."
    return build


def _tasks():
    from jaxeac.envs import tasks

    return tasks


def _tabular(task: Callable[[], Any]) -> Callable[..., Any]:
    def build(chances: int | None = None, slip: float = 0.0, rtilde: str = "shaped"):
        from jaxeac.envs.grid import check_chances, check_slip
        from jaxeac.envs.tabular import TabularEnv

        chances = chances if chances is None else check_chances(chances)
        slip = check_slip(slip)
        built = task()
        if slip:
            built = _tasks().with_slip(built, slip)
        return TabularEnv(built, chances, rtilde)

    return build


#: The classic tasks: name → how `jaxeac.envs.tasks` builds its tables.
CLASSIC = {
    "FrozenLake-4x4-v1": lambda: _tasks().frozen_lake("4x4", slippery=False),
    "FrozenLake-4x4-slippery-v1": lambda: _tasks().frozen_lake("4x4", slippery=True),
    "FrozenLake-8x8-v1": lambda: _tasks().frozen_lake("8x8", slippery=False),
    "FrozenLake-8x8-slippery-v1": lambda: _tasks().frozen_lake("8x8", slippery=True),
    "CliffWalking-v1": lambda: _tasks().cliff_walking(),
    "WindyGridworld-v0": lambda: _tasks().windy_gridworld(stochastic=False),
    "WindyGridworld-stochastic-v0": lambda: _tasks().windy_gridworld(stochastic=True),
    "FourRooms-v0": lambda: _tasks().four_rooms(stochastic=False),
    "FourRooms-stochastic-v0": lambda: _tasks().four_rooms(stochastic=True),
}


def _registry() -> dict[str, Callable[..., Any]]:
    from jaxeac.envs.grid import MAPS

    return {**{f"grid-{name}-v0": _grid(name) for name in MAPS},
            **{name: _tabular(task) for name, task in CLASSIC.items()}}


def registered() -> list[str]:
    """The names `make` accepts, sorted."""
    return sorted(_registry())


def make(name: str, **options) -> Any:
    """The environment registered as `name`, built with `options` (e.g. ``chances=40``)."""
    if not isinstance(name, str):
        raise TypeError(f"name must be a string, one of registered() (got {name!r}); e.g. 'grid-paper-v0'")
    registry = _registry()
    if name not in registry:
        raise UsageError(f"unknown environment {name!r}; choose one of {', '.join(sorted(registry))}")
    build = registry[name]
    known = list(inspect.signature(build).parameters)
    unknown = sorted(set(options) - set(known))
    if unknown:
        raise UsageError(f"environment {name!r} has no option {unknown[0]!r}; "
                         f"its options are {', '.join(known)}")
    return build(**options)
