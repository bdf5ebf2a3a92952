"""User-facing errors, and the argument checks that raise them at a public function's entry.

`UsageError` marks bad input (a malformed map, a negative rate, an unwritable
output folder, ...). It subclasses ``ValueError``: the CLI turns it into a one-line
``error: ...`` on stderr and exit code 2, and library users catch an ordinary ``ValueError``.
An argument of the wrong type is a plain ``TypeError``. Every message names the argument,
the value given and the fix.
"""

from __future__ import annotations

import math
import numbers

import numpy as np


class UsageError(ValueError):
    """Bad input: the message names the problem and how to fix it, on one line."""


#: Counters the device holds as int32 (trials, chances, lanes).
INT32_MAX = (1 << 31) - 1
#: Root keys are 32-bit (R1): ``jax.random.key(k)`` keeps only k mod 2^32, so a larger key would
#: silently give another key's results while the run records the larger one.
KEY_LIMIT = 1 << 32
#: float32's normal range: the runs compute in float32, where a smaller nonzero magnitude becomes 0
#: (or a subnormal) and a larger one inf.
F32_TINY, F32_MAX = float(np.finfo(np.float32).tiny), float(np.finfo(np.float32).max)


def is_integer(value) -> bool:
    """A Python or NumPy integer, not a bool."""
    return isinstance(value, numbers.Integral) and not isinstance(value, bool | np.bool_)


def check_int(name: str, value, *, low: int = 1, high: int = INT32_MAX, fix: str = "") -> int:
    """`value` as an int in [low, high]. A number that is no such integer (0, −3, 2.5, 2.0, NaN) is a
    `UsageError` (a ValueError); a value that is no number at all (a string, None, a bool) a
    TypeError. `fix` ends the message."""
    fix = f"; {fix}" if fix else ""
    kind = "a positive integer" if low == 1 else f"an integer >= {low}"
    if not is_integer(value):
        if isinstance(value, numbers.Real) and not isinstance(value, bool | np.bool_):
            raise UsageError(f"{name} must be {kind} (got {value!r}){fix}")
        raise TypeError(f"{name} must be {kind} (got {value!r} of type {type(value).__name__}){fix}")
    if value < low:
        raise UsageError(f"{name} must be {kind} (got {value!r}){fix}")
    if value > high:
        raise UsageError(f"{name} {value!r} is too large: {name} must be at most {high:,}{fix}")
    return int(value)


def is_plain_number(value) -> bool:
    """A Python or NumPy real scalar (a 0-d NumPy array too), not a bool: what `check_number` checks."""
    if isinstance(value, bool | np.bool_):
        return False
    if isinstance(value, numbers.Real):
        return True
    return isinstance(value, np.ndarray) and value.shape == () and np.issubdtype(value.dtype, np.number) \
        and not np.issubdtype(value.dtype, np.complexfloating)


def check_number(name: str, value, *, low: float = 0.0, high: float | None = None, positive: bool = False,
                 fix: str = "") -> float:
    """A finite real in [low, high] (> low if `positive`) that float32, the type the runs compute in,
    holds without becoming 0 or inf (the CLI's `check_rate` limits). TypeError if it is no number,
    UsageError (a ValueError) otherwise."""
    fix = f"; {fix}" if fix else ""
    if not is_plain_number(value):
        raise TypeError(f"{name} must be a number (got {value!r} of type {type(value).__name__}){fix}")
    x = float(value)
    if not math.isfinite(x):
        raise UsageError(f"{name} must be a finite number (got {value!r}){fix}")
    span = f"[{low:g}, {high:g}]" if high is not None else (f"> {low:g}" if positive else f">= {low:g}")
    if x < low or (positive and x == low) or (high is not None and x > high):
        raise UsageError(f"{name} must be {'in ' if high is not None else ''}{span} (got {value!r}){fix}")
    if x != 0 and not F32_TINY <= abs(x) <= F32_MAX:
        with np.errstate(all="ignore"):
            rounded = float(np.float32(x))
        raise UsageError(f"{name} {value!r} is outside float32's normal range (runs compute in float32, "
                         f"where it becomes {rounded:.3g}); use {'' if positive else '0 or '}a value in "
                         f"[{F32_TINY:.3g}, {F32_MAX:.3g}]")
    return x
