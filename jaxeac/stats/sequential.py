"""Group-sequential comparisons: run seeds in batches and stop when the answer is known.

With seeds nearly free, the risk is no longer too few seeds but looking again and
again until p < 0.05. A sequential comparison fixes, before the first batch, how many
looks it may take (K, at N/K, 2N/K, … N seeds per method) and how much of its error
rate α each look may spend, and then stops at the first look that decides.

**Design: repeated confidence intervals** (Jennison & Turnbull 1989; Jennison &
Turnbull 2000, *Group Sequential Methods*, ch. 9). At look k the interval for the
difference of means δ = mean(treatment) − mean(baseline) of the primary measure is

    RCI_k = (x̄_t − x̄_b) ± c_k · SE_k,   SE_k the Welch standard error at n_k seeds per method,

with boundaries c_1 … c_K from an α-spending function (Lan & DeMets 1983): the
probability that a standard Brownian motion, seen at the information fractions
t_k = n_k / N, first leaves ±c_k·sqrt(t_k) at look k is f(t_k) − f(t_{k−1}) on each
side, f spending α/2 per side (`spending`). The K intervals then cover δ at once
with probability ≥ 1 − α, whenever the comparison stops, so:

* **difference**: stop when RCI_k excludes 0 (the chance of this when δ = 0 is ≤ α);
* **no difference as large as the declared effect**: stop when RCI_k lies inside
  (−effect, +effect) (the chance of this when |δ| ≥ effect is ≤ α);
* otherwise the next look; after look K, **undecided** (N seeds did not suffice).

Assumptions: seeds are independent and identically distributed within a method
(true by construction, R1), the primary measure has finite variance, and Welch's
statistic is close to normal at the first look (the first batch has at least
`MIN_BATCH` seeds per method). Boundaries come from the recursive numerical
integration of Armitage, McPherson & Rowe (1969) as in Jennison & Turnbull (2000,
ch. 19); `tests/test_sequential.py` checks them against published values and by
simulation. The α-spending functions are those of gsDesign and ldbounds:
O'Brien–Fleming type f(t) = 2 − 2Φ(z_{1−α/4} / √t) (per side) and Pocock type
f(t) = (α/2)·ln(1 + (e − 1)t).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable

import numpy as np
from scipy import special

from jaxeac.errors import UsageError
from jaxeac.rundir import DECISIONS

#: α-spending functions per side: f(t, α) with f(0) = 0 and f(1) = α/2.
SPENDING: dict[str, Callable[[float, float], float]] = {
    "obrien_fleming": lambda t, a: (
        0.0 if t <= 0 else float(2 * special.ndtr(-special.ndtri(1 - a / 4) / math.sqrt(t)))),
    "pocock": lambda t, a: float(a / 2 * math.log(1 + (math.e - 1) * t)),
}
#: Fewest seeds per method in a batch (Welch's statistic close to normal from the first look).
MIN_BATCH = 10
#: Most looks a design may take (boundaries cost O(K²) integration; more looks buy little).
MAX_LOOKS = 50
#: A look whose share of α rounds to 0 gets this boundary (z), not an infinite one.
Z_CAP = 8.0
#: Simulated sequential experiments in a sequential run's own calibration (`calibration_record`).
SIMULATED_EXPERIMENTS = 1000
#: Grid points per unit of standard deviation in the numerical integration.
GRID_PER_SD = 64

REFERENCE = ("repeated confidence intervals (Jennison & Turnbull 1989; 2000, ch. 9) with "
             "Lan-DeMets alpha spending")


def spending(name: str, t: float, alpha: float) -> float:
    """α spent on one side by information fraction t (`SPENDING`)."""
    if name not in SPENDING:
        raise UsageError(f"unknown alpha spending {name!r}; choose one of {', '.join(SPENDING)}")
    return SPENDING[name](min(max(t, 0.0), 1.0), alpha)


def _simpson(lo: float, hi: float, sd: float) -> tuple[np.ndarray, np.ndarray]:
    """Points and Simpson weights on [lo, hi], about `GRID_PER_SD` per `sd`."""
    m = max(int(math.ceil((hi - lo) / sd * GRID_PER_SD)), 2)
    m += m % 2  # an even number of intervals
    x = np.linspace(lo, hi, m + 1)
    w = np.ones(m + 1)
    w[1:-1:2], w[2:-1:2] = 4.0, 2.0
    return x, w * (hi - lo) / (3 * m)


def boundaries(fractions, alpha: float = 0.05, spend: str = "obrien_fleming") -> np.ndarray:
    """Two-sided boundaries for looks at information `fractions` (see `_boundaries`; cached)."""
    return _boundaries(tuple(float(f) for f in np.asarray(fractions, np.float64).reshape(-1)),
                       float(alpha), spend).copy()


@functools.lru_cache(maxsize=64)
def _boundaries(fractions: tuple, alpha: float, spend: str) -> np.ndarray:
    """Two-sided boundaries c_1 … c_K on the z scale for looks at information `fractions`
    (increasing, the last 1): P_0(first |Z_k| ≥ c_k at look k) = 2·(f(t_k) − f(t_{k−1})).

    Recursive numerical integration of the sub-density of the Brownian motion S(t_k)
    on the continuation region (Armitage, McPherson & Rowe 1969; Jennison & Turnbull 2000,
    §19.2), each c_k found by root finding.
    """
    from scipy import optimize  # imported where used (as scipy.stats in closed_form)
    t = np.asarray(fractions, np.float64)
    if t.ndim != 1 or t.size < 1 or not np.all(np.diff(t) > 0) or t[0] <= 0 or not math.isclose(t[-1], 1.0):
        raise UsageError("looks must be at increasing information fractions in (0, 1], the last 1")
    if not 0 < alpha < 1:
        raise UsageError(f"alpha must lie in (0, 1) (got {alpha})")
    out = np.empty(t.size)
    x = w = dens = None  # the continuation region's grid, weights and sub-density of S(t_{k-1})
    spent = 0.0
    for k, tk in enumerate(t):
        target = spending(spend, tk, alpha) - spent  # upper-side crossing at look k
        spent += target
        if k == 0:
            out[0] = min(-special.ndtri(target), Z_CAP) if target > 0 else Z_CAP
            b = out[0] * math.sqrt(tk)
            x, w = _simpson(-b, b, math.sqrt(tk))
            dens = np.exp(-0.5 * x * x / tk) / math.sqrt(2 * math.pi * tk)
            continue
        step = math.sqrt(tk - t[k - 1])
        mass, grid = w * dens, x

        def upper(b: float, mass=mass, grid=grid, step=step) -> float:
            return float(mass @ special.ndtr((grid - b) / step))  # P(continued so far, S(t_k) > b)

        if target <= 0:
            b = Z_CAP * math.sqrt(tk)
        else:
            hi = x[-1] + 12 * step
            b = optimize.brentq(lambda v, target=target: upper(v) - target, -hi, hi, xtol=1e-12)
        out[k] = b / math.sqrt(tk)
        if k + 1 < t.size:
            nx, nw = _simpson(-b, b, step)
            kernel = np.exp(-0.5 * ((nx[:, None] - x[None, :]) / step) ** 2) / (math.sqrt(2 * math.pi) * step)
            dens = kernel @ (w * dens)
            x, w = nx, nw
    return out


@dataclasses.dataclass(frozen=True)
class SequentialDesign:
    """What a sequential comparison fixes before its first batch."""

    effect: float  # the difference of means that matters (primary measure's units), > 0
    max_seeds: int  # N: seeds per method at the last look
    looks: int = 5  # K equally spaced looks
    alpha: float = 0.05
    spend: str = "obrien_fleming"

    def __post_init__(self):
        if not (isinstance(self.effect, int | float) and math.isfinite(self.effect) and self.effect > 0):
            raise UsageError(f"--effect must be a positive number, the smallest difference that matters "
                             f"(got {self.effect!r})")
        if not isinstance(self.looks, int) or not 1 <= self.looks <= MAX_LOOKS:
            raise UsageError(f"--looks must be an integer from 1 to {MAX_LOOKS} (got {self.looks!r})")
        if not isinstance(self.max_seeds, int) or self.max_seeds < self.looks * MIN_BATCH:
            raise UsageError(f"--seeds {self.max_seeds} is too few for {self.looks} looks: each batch "
                             f"needs at least {MIN_BATCH} seeds per method "
                             f"(use --seeds ≥ {self.looks * MIN_BATCH})")
        if not 0 < self.alpha < 0.5:
            raise UsageError(f"--error-rate must lie in (0, 0.5) (got {self.alpha:g})")
        if self.spend not in SPENDING:
            raise UsageError(f"unknown alpha spending {self.spend!r}; choose one of {', '.join(SPENDING)}")

    @property
    def batch(self) -> int:
        """Seeds per method in each batch, ⌊N / K⌋: equal batches, so one compiled program."""
        return self.max_seeds // self.looks

    @property
    def sizes(self) -> list[int]:
        """Seeds per method at each look: k batches (the last look at K·⌊N / K⌋ ≤ N seeds)."""
        return [self.batch * k for k in range(1, self.looks + 1)]

    @property
    def fractions(self) -> np.ndarray:
        return np.arange(1, self.looks + 1, dtype=np.float64) / self.looks

    def boundaries(self) -> np.ndarray:
        return boundaries(self.fractions, self.alpha, self.spend)

    def describe(self) -> dict:
        """The design as summary.json records it (fixed before the first batch)."""
        return {"design": REFERENCE, "effect": self.effect, "max_seeds": self.max_seeds, "looks": self.looks,
                "sizes": self.sizes, "alpha": self.alpha, "spending": self.spend,
                "boundaries_z": self.boundaries().tolist()}




def look(baseline: np.ndarray, treatment: np.ndarray, boundary: float, effect: float, last: bool,
         paired: bool = False) -> dict:
    """One look: the difference of means, its standard error (Welch's, or with `paired` that of
    the mean per-seed difference: seed i of both methods shares its key), the repeated CI and
    the decision."""
    xb, xt = np.asarray(baseline, np.float64), np.asarray(treatment, np.float64)
    if paired:
        d = xt - xb
        diff, se = float(d.mean()), math.sqrt(d.var(ddof=1) / d.size)
    else:
        diff = float(xt.mean() - xb.mean())
        se = math.sqrt(xb.var(ddof=1) / xb.size + xt.var(ddof=1) / xt.size)
    lo, hi = diff - boundary * se, diff + boundary * se
    if lo > 0 or hi < 0:
        decision = "difference"
    elif -effect < lo and hi < effect:
        decision = "no difference"
    else:
        decision = "undecided" if last else "continue"
    z = diff / se if se > 0 else (math.copysign(math.inf, diff) if diff else 0.0)
    return {"seeds": int(xb.size), "diff": diff, "se": se, "z": z, "boundary_z": float(boundary),
            "rci": [lo, hi], "decision": decision}


def run_sequential(design: SequentialDesign, measure: Callable[[int, int], tuple[np.ndarray, np.ndarray]],
                   progress: Callable[[dict], None] | None = None, paired: bool = False) -> dict:
    """Take looks until one decides. `measure(first, n)` returns the primary measure of seeds
    first … first+n−1 of (baseline, treatment); it is called once per batch, in order.
    `paired`: row i of both is the same seed (see `look`). Returns the design, every look taken
    and the decision."""
    c = design.boundaries()
    xb, xt, looks = [], [], []
    done = 0
    for k, size in enumerate(design.sizes):
        b, t = measure(done, size - done)
        xb.append(np.asarray(b, np.float64))
        xt.append(np.asarray(t, np.float64))
        done = size
        last = k + 1 == design.looks
        result = look(np.concatenate(xb), np.concatenate(xt), c[k], design.effect, last, paired)
        looks.append(result)
        if progress is not None:
            progress(result)
        if result["decision"] != "continue":
            break
    return {**design.describe(), "paired": paired, "looks_taken": looks, "decision": looks[-1]["decision"],
            "seeds_used": looks[-1]["seeds"]}


def simulate(design: SequentialDesign, pool_baseline: np.ndarray, pool_treatment: np.ndarray | None,
             experiments: int, rng: np.random.Generator) -> dict:
    """Decision rates of `design` over `experiments` simulated sequential comparisons.

    Each draws `max_seeds` seeds per method from the pools and looks at them in the design's
    batches. `pool_treatment` None: both groups from `pool_baseline` (a null comparison, AC
    against AC), drawn without replacement when the pool holds 2·N seeds, else with
    replacement (a bootstrap of the pool, its empirical law standing in for the method's).
    Returns each decision's share with its Monte Carlo standard error, and the mean seeds
    used per method.
    """
    pb = np.asarray(pool_baseline, np.float64)
    pt = pb if pool_treatment is None else np.asarray(pool_treatment, np.float64)
    n = design.max_seeds
    null = pool_treatment is None
    replace = pb.size < (2 * n if null else n) or pt.size < n
    def draw():
        if null and not replace:
            idx = rng.choice(pb.size, 2 * n, replace=False)
            return pb[idx[:n]], pb[idx[n:]]
        return pb[rng.choice(pb.size, n, replace=replace)], pt[rng.choice(pt.size, n, replace=replace)]

    decisions, used = _tally(design, draw, experiments, paired=False)
    return {"experiments": experiments, "with_replacement": bool(replace), "decisions": decisions,
            "mean_seeds_used": used}


def _tally(design: SequentialDesign, draw: Callable[[], tuple[np.ndarray, np.ndarray]], experiments: int,
           paired: bool) -> tuple[dict, float]:
    """Run `experiments` sequential comparisons (`run_sequential`) of the (baseline, treatment)
    samples `draw()` gives: each decision's share with its Monte Carlo standard error, and the
    mean seeds used."""
    counts = dict.fromkeys(DECISIONS[:3], 0)
    used = 0
    for _ in range(experiments):
        b, t = draw()
        r = run_sequential(design, lambda first, n, b=b, t=t: (b[first:first + n], t[first:first + n]),
                           paired=paired)
        counts[r["decision"]] += 1
        used += r["seeds_used"]
    rates = {}
    for name, k in counts.items():
        p = k / experiments
        rates[name] = {"rate": p, "se": math.sqrt(p * (1 - p) / experiments), "count": k}
    return rates, used / experiments


def simulate_paired(design: SequentialDesign, differences: np.ndarray, experiments: int,
                    rng: np.random.Generator, null: bool) -> dict:
    """Decision rates of `design` on paired data, from per-seed differences d_i (treatment −
    baseline of seed i): each experiment draws N of them (without replacement when there are
    enough, else with) and looks with the paired standard error. `null`: each drawn difference
    gets a random sign (under no difference, d_i and −d_i are equally likely), so "difference"
    is a false positive."""
    d = np.asarray(differences, np.float64)
    n = design.max_seeds
    replace = d.size < n
    zero = np.zeros(n)

    def draw():
        x = d[rng.choice(d.size, n, replace=replace)]
        return zero, np.where(rng.random(n) < 0.5, -x, x) if null else x

    decisions, used = _tally(design, draw, experiments, paired=True)
    return {"experiments": experiments, "with_replacement": bool(replace), "paired": True,
            "null": "random signs of the run's per-seed differences" if null else None,
            "decisions": decisions, "mean_seeds_used": used}


def calibration_record(design: SequentialDesign, differences: np.ndarray, key: int,
                       experiments: int = SIMULATED_EXPERIMENTS) -> dict:
    """A sequential run's own calibration (summary.json): its decision rates simulated from the
    run's per-seed differences, with random signs (the null) and as they are."""
    rng = np.random.default_rng([key, 0x5E0])  # the calibration's own stream
    return {
        "source": "the run's own per-seed differences, drawn for each simulated experiment "
                  "(jaxeac.stats.sequential.simulate_paired)",
        "null": simulate_paired(design, differences, experiments, rng, null=True),
        "observed": simulate_paired(design, differences, experiments, rng, null=False),
    }
