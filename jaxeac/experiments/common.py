"""What the experiments share: input checks, versions, per-seed intervals and the summary.json core.

The checks raise `UsageError` so that bad input fails before any compute (the CLI turns
it into a one-line error); `versions` is the one place that states what a result ran on.
"""

from __future__ import annotations

import dataclasses
import math
import platform
import sys
from importlib import metadata

import jax
import numpy as np
from scipy import stats as sps

from jaxeac import __version__
from jaxeac.algorithm.config import ALGORITHMS, algorithm
from jaxeac.errors import UsageError

# ------------------------------------------------------------------ input checks


def check_positive_int(name: str, value) -> None:
    """An integer > 0 (not a bool)."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value <= 0:
        raise UsageError(f"{name} must be a positive integer (got {value!r})")


def check_key(value) -> None:
    """A root key: an integer ≥ 0 (not a bool); seed i is ``fold_in(PRNGKey(key), i)`` (SPEC R1)."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 0:
        raise UsageError(f"key must be a non-negative integer (got {value!r})")


def check_rate(name: str, value, *, upper: float | None = None, positive: bool = False) -> None:
    """A finite number ≥ 0 (> 0 if `positive`), at most `upper` where given."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise UsageError(f"{name} must be a finite number (got {value!r})")
    if value < 0 or (positive and value == 0):
        raise UsageError(f"{name} must be {'positive' if positive else 'non-negative'} (got {value!r})")
    if upper is not None and value > upper:
        raise UsageError(f"{name} must lie in [0, {upper:g}] (got {value!r})")


def check_algos(algos) -> None:
    """A non-empty list of known algorithm names, each once."""
    if not algos:
        raise UsageError("algos is empty; pass at least one of " + ", ".join(sorted(ALGORITHMS)))
    for name in algos:
        algorithm(name)  # raises on unknown names
    if len(set(algos)) != len(algos):
        raise UsageError(f"algos lists an algorithm twice ({' '.join(algos)}); list each once")


# ------------------------------------------------------------------ versions

#: What a run folder's summary.json states (`versions()`), in this order.
RUN_PACKAGES = ("jaxeac", "python", "jax", "jaxlib", "numpy", "optax", "mujoco", "matplotlib", "platform")
#: Stated only where installed: the MJX backends' physics.
OPTIONAL_PACKAGES = ("mujoco-mjx", "warp-lang")


def versions(packages: tuple[str, ...] = RUN_PACKAGES,
             optional: tuple[str, ...] = OPTIONAL_PACKAGES) -> dict[str, str]:
    """Versions of the packages a result depends on, keyed by name (``-`` → ``_``).

    Each of `packages` is stated ("unknown" where not installed); each of `optional` only
    where installed. "python" and "platform" are the interpreter and the machine.
    """
    special = {"jaxeac": lambda: __version__, "python": platform.python_version,
               "platform": platform.platform}
    out = {}
    for name in (*packages, *optional):
        try:
            out[name.replace("-", "_")] = special[name]() if name in special else metadata.version(name)
        except metadata.PackageNotFoundError:
            if name in packages:
                out[name.replace("-", "_")] = "unknown"
    return out


# ------------------------------------------------------------------ per-seed summaries


def mean_ci95(x: np.ndarray) -> tuple[float, float, float, float]:
    """(mean, sd, lo, hi): Student-t 95 % interval of the mean (NaN bounds when n < 2)."""
    x = np.asarray(x, float)
    n, mean = x.size, float(x.mean())
    if n < 2:
        return mean, float("nan"), float("nan"), float("nan")
    sd = float(x.std(ddof=1))
    half = float(sps.t.ppf(0.975, n - 1)) * sd / math.sqrt(n)
    return mean, sd, mean - half, mean + half


def welch_diff_ci95(a: np.ndarray, b: np.ndarray) -> tuple[float, float, float]:
    """(mean(b) − mean(a), lo, hi) with the Welch–Satterthwaite 95 % interval."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    diff = float(b.mean() - a.mean())
    va, vb = a.var(ddof=1) / a.size, b.var(ddof=1) / b.size
    se = math.sqrt(va + vb)
    if se == 0:
        return diff, diff, diff
    df = (va + vb) ** 2 / (va**2 / (a.size - 1) + vb**2 / (b.size - 1))
    half = float(sps.t.ppf(0.975, df)) * se
    return diff, diff - half, diff + half


def summary_base(experiment: str, primary: str, settings, results: dict, measures: dict) -> dict:
    """The summary.json fields every run folder shares (`measures`: primary measure per algorithm)."""
    per_algo = {}
    for algo, r in results.items():
        mean, sd, lo, hi = mean_ci95(measures[algo])
        per_algo[algo] = {f"mean_{primary}": mean, f"sd_{primary}": sd, f"ci95_{primary}": [lo, hi],
                          "compile_seconds": r.compile_seconds, "run_seconds": r.run_seconds}
    out = {
        "experiment": experiment, "primary_measure": primary, "algos": list(settings.algos),
        "trials": settings.trials, "seeds": settings.seeds, "key": settings.key,
        "config": dataclasses.asdict(settings), "versions": versions(),
        "devices": [str(d) for d in jax.devices()], "command": " ".join(["jaxeac", *sys.argv[1:]]),
        "compile_seconds": sum(r.compile_seconds for r in results.values()),
        "run_seconds": sum(r.run_seconds for r in results.values()),
        "per_algo": per_algo,
    }
    if "ac" in measures and "eac" in measures:
        diff, lo, hi = welch_diff_ci95(measures["ac"], measures["eac"])
        out["eac_minus_ac"] = {"diff": diff, "ci95": [lo, hi], "method": "Welch t interval"}
    return out
