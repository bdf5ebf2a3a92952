"""One figure style for every figure of the package: a colour per algorithm, its display name,
and the colour scales of heatmaps.

The palette is Okabe & Ito's (2008) set of eight colours that stay apart under the common
colour-vision deficiencies, with black swapped for a mid grey (so that black stays free for
axes, outlines and text) and its yellow kept off white backgrounds (it marks the grid's goal
instead). Each algorithm has its own colour in every figure; EAC is always vermillion and
AC always blue. Pure Python and Matplotlib's colour helpers only: a base module that the
figures of `jaxeac.plots` and of `jaxeac.stats` both import.
"""

from __future__ import annotations

#: Okabe-Ito colours by name.
BLUE, VERMILLION, ORANGE, REDDISH_PURPLE = "#0072B2", "#D55E00", "#E69F00", "#CC79A7"
BLUISH_GREEN, SKY_BLUE, YELLOW, BLACK, GREY = "#009E73", "#56B4E9", "#F0E442", "#000000", "#7F7F7F"

#: One colour per algorithm, the same in every figure.
PALETTE: dict[str, str] = {
    "ac": BLUE,
    "eac": VERMILLION,
    "eac_success_only": ORANGE,
    "eac_failure_only": REDDISH_PURPLE,
    "eac_learn_on_memory": BLUISH_GREEN,
    "eac_within_trial": SKY_BLUE,
    "q_learning": BLACK,
    "sarsa": GREY,
}

#: Names in legends: AC and EAC as the paper writes them; the ablations and baselines by the
#: names the command line, the tables and the reports use.
LABELS: dict[str, str] = {"ac": "AC", "eac": "EAC"}

#: Colours of marks that are not algorithms.
NEUTRAL = "0.35"  # arrows, reference lines, differences between two algorithms
GOAL = YELLOW
OBSTACLE = "0.25"

#: Colour maps: sequential for one-signed values, diverging (centred at 0) for differences
#: that take both signs. Both are colour-blind safe and readable in grey.
SEQUENTIAL = "viridis"
DIVERGING = "RdBu_r"


def color(algo: str) -> str:
    """The algorithm's colour; an unknown name gets a neutral grey rather than a borrowed colour."""
    return PALETTE.get(algo, GREY)


def label(algo: str) -> str:
    """The algorithm's display name (its own name when not one of the package's)."""
    return LABELS.get(algo, algo)


def scale(values, *, difference: bool) -> dict:
    """imshow's ``cmap``, ``vmin`` and ``vmax`` for `values` (NaNs ignored).

    A difference that takes both signs gets the diverging map, symmetric about 0; one that
    takes one sign gets the sequential map from 0 to its extreme (so the colour still says
    how far from "no difference" a cell is); other values the sequential map over their range."""
    finite = [float(v) for v in _flat(values) if v == v and abs(float(v)) != float("inf")]
    if not finite:
        return {"cmap": SEQUENTIAL, "vmin": 0.0, "vmax": 1.0}
    lo, hi = min(finite), max(finite)
    if difference and lo < 0 < hi:
        m = max(-lo, hi)
        return {"cmap": DIVERGING, "vmin": -m, "vmax": m}
    if difference:
        lo, hi = min(lo, 0.0), max(hi, 0.0)
    if lo == hi:
        lo, hi = lo - 0.5, hi + 0.5
    return {"cmap": SEQUENTIAL, "vmin": lo, "vmax": hi}


def text_color(rgba) -> str:
    """Black or white, whichever reads better on a cell of colour `rgba` (relative luminance)."""
    def linear(c: float) -> float:
        return c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4

    r, g, b = (linear(float(c)) for c in tuple(rgba)[:3])
    return "black" if 0.2126 * r + 0.7152 * g + 0.0722 * b > 0.179 else "white"


def _flat(values):
    for v in values:
        if hasattr(v, "__iter__") and not isinstance(v, str):
            yield from _flat(v)
        else:
            yield v
