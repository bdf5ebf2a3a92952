"""Environments by versioned name: `make(name, **options)` and `registered()` (STYLE 9).

``grid-<map>-v0`` is the grid world of the paper's §V-A (SPEC G1–G5) on a named map
(`jaxeac.envs.grid.MAPS`: the paper's 11×11 map and its scaled copies), with
``chances`` (G5, default 40) as an option. The bowling task's physics is configured
with `jaxeac.envs.bowling.BowlingConfig` (B1–B7). A name's behaviour never changes;
a changed environment gets a new version.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from jaxeac.errors import UsageError


def _grid(map_name: str) -> Callable[..., Any]:
    def build(chances: int = 40):
        from jaxeac.envs.grid import GridWorld, get_map

        return GridWorld(get_map(map_name), chances)

    build.__doc__ = f"The grid world on map {map_name!r} (G1–G5), `chances` per trial (G5)."
    return build


def _registry() -> dict[str, Callable[..., Any]]:
    from jaxeac.envs.grid import MAPS

    return {f"grid-{name}-v0": _grid(name) for name in MAPS}


def registered() -> list[str]:
    """The names `make` accepts, sorted."""
    return sorted(_registry())


def make(name: str, **options) -> Any:
    """The environment registered as `name`, built with `options` (e.g. ``chances=40``)."""
    registry = _registry()
    if name not in registry:
        raise UsageError(f"unknown environment {name!r}; choose one of {', '.join(sorted(registry))}")
    return registry[name](**options)
