"""Numbers as reports and the command line print them: fixed, compact, signed, CIs, p-values.

The `jaxeac reproduce` report, the `jaxeac compare` report and the CLI have always printed
numbers in their own styles; each call site passes its digits and style explicitly, so
one implementation serves all three without changing a byte of their output.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable


def number(x, digits: int = 2, *, sign: bool = False, missing: str = "n/a") -> str:
    """`x` with `digits` decimals (`sign`: always a sign); None, NaN and ±inf print as `missing`."""
    if x is None:
        return missing
    x = float(x)
    if not math.isfinite(x):
        return missing
    return f"{x:{'+' if sign else ''}.{digits}f}"


def compact(x, digits: int = 3, *, sign: bool = False, missing: str = "—") -> str:
    """As `number`, but integers as they are and 0 < |x| < 1e-3 or |x| ≥ 1e5 as x.xxe±yy."""
    if x is None:
        return missing
    if isinstance(x, numbers.Integral):
        return f"{int(x):{'+' if sign else ''}d}"
    x = float(x)
    if not math.isfinite(x):
        return missing
    if x != 0 and (abs(x) < 1e-3 or abs(x) >= 1e5):
        return f"{x:{'+' if sign else ''}.2e}"
    return number(x, digits, sign=sign, missing=missing)


def interval(pair, digits: int = 2, *, sign: bool = False, form: Callable[..., str] = number) -> str:
    """"[lo, hi]", each bound printed by `form` (`number` or `compact`)."""
    return f"[{form(pair[0], digits, sign=sign)}, {form(pair[1], digits, sign=sign)}]"


def compact_interval(pair, digits: int = 3) -> str:
    """"[lo, hi]" with `compact` bounds."""
    return interval(pair, digits, form=compact)


def p_value(x, digits: int = 3, *, floor: str = "1e-16", sci_below: float | None = 1e-3,
            general: bool = False, missing: str = "n/a") -> str:
    """A p-value: "< floor" below `floor`; x.xxe−yy below `sci_below`; else `digits` decimals
    (`general`: `digits` significant figures, format ``g``); None and NaN print as `missing`."""
    if x is None or not math.isfinite(float(x)):
        return missing
    if x < float(floor):
        return f"< {floor}"
    if sci_below is not None and x < sci_below:
        return f"{x:.2e}"
    return f"{x:.{digits}{'g' if general else 'f'}}"


def p_sig(x, digits: int = 3, *, missing: str = "—") -> str:
    """A p-value in `digits` significant figures: "0.0139", "0.500", below 0.01 "1.39e-03"; exact
    zeros (a degenerate test) print as "0"; None and NaN as `missing`."""
    if x is None or not math.isfinite(float(x)):
        return missing
    x = float(x)
    if x == 0:
        return "0"
    if x < 0.01:
        return f"{x:.{digits - 1}e}"
    return f"{x:#.{digits}g}"


def p_is(x, floor: str = "1e-4") -> str:
    """"p = 0.0139" in plain words, or "p < 1e-4" below `floor` (for a sentence; tables print
    `p_sig`)."""
    if x is not None and math.isfinite(float(x)) and float(x) < float(floor):
        return f"p < {floor}"
    return f"p = {p_sig(x)}"


def percent(level: float) -> str:
    """A confidence level as printed: 0.95 -> '95%', 0.999 -> '99.9%'."""
    return f"{100 * level:.6g}%"


def size_word(g: float, words: tuple[str, str, str, str] = ("negligible", "small", "medium", "large")) -> str:
    """Cohen's name for the size of a standardised effect: |g| < 0.2, < 0.5, < 0.8, else."""
    g = abs(g)
    return words[0] if g < 0.2 else words[1] if g < 0.5 else words[2] if g < 0.8 else words[3]


def sequential_look(look: dict, effect: float, unit: str) -> str:
    """One line per look of a sequential comparison (`jaxeac.stats.sequential.look`)."""
    lo, hi = look["rci"]
    return (f"look at {look['seeds']} seeds per method: EAC − AC {look['diff']:+.2f} {unit}, repeated CI "
            f"[{lo:+.2f}, {hi:+.2f}] (z boundary {look['boundary_z']:.3f}, effect ±{effect:g}): "
            f"{look['decision']}")
