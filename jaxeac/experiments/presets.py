"""Named experiment presets (a registry, `make(name)`), each pinned by the SPEC."""

from __future__ import annotations

import dataclasses

from jaxeac import paper
from jaxeac.errors import UsageError


@dataclasses.dataclass(frozen=True)
class GridPreset:
    """Grid-world settings; G6 pins the `paper` preset (the paper gives no numbers)."""

    map: str = "paper"
    trials: int = 200
    chances: int = 40
    alpha: float = 0.1
    beta: float = 0.3
    gamma: float = 0.9
    temperature: float = 1.0
    #: The paper's single-run results (Fig. 3), for figures and reports.
    paper_successes: dict[str, int] | None = None


GRID_PRESETS: dict[str, GridPreset] = {
    # G6: makes plain AC succeed about as often as the paper's AC (56 of 200).
    "paper": GridPreset(paper_successes=dict(paper.GRID_SUCCESSES)),
    # The paper's layout at other sizes (jaxeac.envs.grid.paper_like_map), other settings as G6.
    **{f"paper{n}": GridPreset(map=f"paper{n}") for n in (7, 9, 13, 15, 21)},
}


def make(name: str) -> GridPreset:
    """The grid preset called `name`; an unknown name is a `UsageError`."""
    if name not in GRID_PRESETS:
        raise UsageError(f"unknown preset {name!r}; choose one of {sorted(GRID_PRESETS)}")
    return GRID_PRESETS[name]
