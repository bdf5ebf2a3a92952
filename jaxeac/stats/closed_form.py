"""Closed-form tests, intervals and effect sizes, on the host (SPEC §6).

The vectorised helpers (`*_masks`) take one pooled sample and a bool matrix of
group labels [S, N] (row s: which units are in the treatment group of split s),
so the AC-versus-AC calibration runs hundreds of splits at once; the public
functions are thin wrappers for two plain samples.

Every closed-form estimator (Welch, t intervals, effect sizes, A12, power, Holm) is defined
once, here; the tests of events (log-rank, proportions) in `jaxeac.stats.events`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import special  # not scipy.stats: its import held the interpreter 0.6-0.8 s of a GPU report

from jaxeac.errors import UsageError


@dataclass(frozen=True)
class TestResult:
    """A test statistic, its two-sided p-value and (where defined) degrees of freedom."""

    statistic: float
    pvalue: float
    df: float = math.nan


@dataclass(frozen=True)
class Estimate:
    """A point estimate with a two-sided confidence interval."""

    estimate: float
    low: float
    high: float
    level: float = 0.95


def check_sample(x, name: str = "x") -> np.ndarray:
    """A 1-D float array of per-seed values with at least 2 finite entries."""
    arr = np.asarray(x, dtype=np.float64)
    if arr.ndim != 1:
        raise UsageError(
            f"{name} must be 1-D (one value per seed), got shape {arr.shape}; "
            "reduce the trials axis first (e.g. sum over trials)"
        )
    if arr.shape[0] < 2:
        raise UsageError(f"{name} has {arr.shape[0]} seed(s); at least 2 seeds per method are needed")
    if not np.all(np.isfinite(arr)):
        raise UsageError(f"{name} contains NaN or inf; remove or fix those seeds")
    return arr


# ---------------------------------------------------------------- Welch
def mean_var(n, s, ss):
    """Mean and unbiased variance from sums (ss=None: 0/1 data, var from the mean)."""
    m = s / n
    v = m * (1 - m) * n / (n - 1) if ss is None else np.maximum(ss - n * m**2, 0) / (n - 1)
    return m, np.maximum(v, 0)


def welch_t_stat(nb, sb, ssb, nt, st, sst):
    """Welch's t (treatment − baseline) from sums, its one definition; where both variances are
    0: t = ±inf if the means differ, else 0. Arrays broadcast (bootstrap and permutation sums)."""
    mb, vb = mean_var(nb, sb, ssb)
    mt, vt = mean_var(nt, st, sst)
    se = np.sqrt(vb / nb + vt / nt)
    gap = mt - mb
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(se > 0, gap / np.where(se > 0, se, 1), np.where(gap == 0, 0.0, np.sign(gap) * np.inf))


def satterthwaite(a, b, n1, n2):
    """Welch's degrees of freedom from the squared standard errors a = v1/n1, b = v2/n2
    (Satterthwaite 1946), their one definition."""
    return (a + b) ** 2 / (a**2 / (n1 - 1) + b**2 / (n2 - 1))


def welch_from_moments(n1, s1, ss1, n2, s2, ss2):
    """Welch t (group 2 minus group 1), df and p from sums and centred sums of squares.

    Welch (1947); Satterthwaite (1946) degrees of freedom. Arrays broadcast.
    """
    t = welch_t_stat(n1, s1, ss1, n2, s2, ss2)
    (m1, v1), (m2, v2) = mean_var(n1, s1, ss1), mean_var(n2, s2, ss2)
    a, b = v1 / n1, v2 / n2
    pos = np.sqrt(a + b) > 0
    gap = m2 - m1
    with np.errstate(divide="ignore", invalid="ignore"):  # zero variances: p = 0 where the means differ
        df = np.where(pos, satterthwaite(a, b, n1, n2), np.nan)
    p = np.where(pos, 2 * special.stdtr(np.where(pos, df, 1.0), -np.abs(t)), np.where(gap == 0, 1.0, 0.0))
    return t, df, p


def welch_t(x_baseline, x_treatment) -> TestResult:
    """Welch's unequal-variance t-test of mean(treatment) − mean(baseline)."""
    x = check_sample(x_baseline, "x_baseline")
    y = check_sample(x_treatment, "x_treatment")
    c = np.concatenate([x, y]).mean()
    x, y = x - c, y - c
    t, df, p = welch_from_moments(x.size, x.sum(), (x**2).sum(), y.size, y.sum(), (y**2).sum())
    return TestResult(float(t), float(p), float(df))


def welch_interval(x_baseline, x_treatment, level: float = 0.95) -> Estimate:
    """mean(treatment) − mean(baseline) with the Welch–Satterthwaite t interval (Welch 1947); a
    zero standard error gives the point."""
    a, b = np.asarray(x_baseline, np.float64), np.asarray(x_treatment, np.float64)
    diff = float(b.mean() - a.mean())
    va, vb = a.var(ddof=1) / a.size, b.var(ddof=1) / b.size
    se = math.sqrt(va + vb)
    if se == 0:
        return Estimate(diff, diff, diff, level)
    df = satterthwaite(va, vb, a.size, b.size)
    half = float(special.stdtrit(df, 0.5 + level / 2)) * se
    return Estimate(diff, diff - half, diff + half, level)


def t_half_width(sd, n: int, level: float = 0.95):
    """Half the width of the Student t interval of a mean: t_{n−1, (1+level)/2} · sd / √n."""
    return special.stdtrit(n - 1, 0.5 + level / 2) * sd / math.sqrt(n)


def t_interval(x, level: float = 0.95, axis=None):
    """(mean, sd, low, high): the Student t interval of a mean (NaN sd and bounds where n < 2);
    along `axis` of an array, each an array."""
    x = np.asarray(x, np.float64)
    n = x.size if axis is None else x.shape[axis]
    mean = x.mean(axis=axis)
    if n < 2:
        nan = np.full(np.shape(mean), np.nan)
        return (float(mean), math.nan, math.nan, math.nan) if axis is None else (mean, nan, nan, nan)
    sd = x.std(ddof=1, axis=axis)
    half = t_half_width(sd, n, level)
    if axis is None:
        return float(mean), float(sd), float(mean - half), float(mean + half)
    return mean, sd, mean - half, mean + half


def iqm_sorted(xs) -> float:
    """The interquartile mean of ascending values, its one definition: the mean of positions
    [n // 4, n − n // 4), the middle 50 % (`scipy.stats.trim_mean(x, 0.25)`; Agarwal et al. 2021)."""
    n = len(xs)
    return float(np.mean(xs[n // 4 : n - n // 4]))


def iqm(x) -> float:
    """Interquartile mean of per-seed values in any order: `iqm_sorted`'s positions, taken by
    `scipy.stats.trim_mean` (a partition instead of a sort; its numbers are pinned)."""
    from scipy import stats
    return float(stats.trim_mean(check_sample(x), 0.25))


# ---------------------------------------------------------------- effect sizes
def hedges_correction(n1, n2):
    """Exact small-sample factor J(df) = Γ(df/2) / (sqrt(df/2) Γ((df-1)/2)) (Hedges 1981)."""
    df = np.asarray(n1 + n2 - 2, dtype=np.float64)
    return np.exp(special.gammaln(df / 2) - special.gammaln((df - 1) / 2)) / np.sqrt(df / 2)


def hedges_from_moments(n1, s1, ss1, n2, s2, ss2):
    """Hedges' g (group 2 minus group 1) from sums and sums of squares; arrays broadcast."""
    m1, m2 = s1 / n1, s2 / n2
    pooled = (np.maximum(ss1 - n1 * m1**2, 0) + np.maximum(ss2 - n2 * m2**2, 0)) / (n1 + n2 - 2)
    sd = np.sqrt(pooled)
    gap = m2 - m1
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.where(sd > 0, gap / np.where(sd > 0, sd, 1.0), np.where(gap == 0, 0.0, np.sign(gap) * np.inf))
    return d * hedges_correction(n1, n2)


def hedges_g(x_baseline, x_treatment) -> float:
    """Hedges' g = J · (mean_t − mean_b) / pooled SD (Hedges 1981; Hedges & Olkin 1985)."""
    x = check_sample(x_baseline, "x_baseline")
    y = check_sample(x_treatment, "x_treatment")
    c = np.concatenate([x, y]).mean()
    x, y = x - c, y - c
    return float(hedges_from_moments(x.size, x.sum(), (x**2).sum(), y.size, y.sum(), (y**2).sum()))


# ---------------------------------------------------------------- Brunner–Munzel / A12
def brunner_munzel_masks(pooled: np.ndarray, masks: np.ndarray, alpha: float = 0.05):
    """Brunner–Munzel for many splits of one pooled sample (Brunner & Munzel 2000).

    masks: bool [S, N], True = treatment. Returns (p̂ = P(T > B) + ½P(T = B),
    W, df, p two-sided, CI low, CI high) arrays of length S; the CI for p̂ is
    p̂ ± t_{df,1−α/2} · sqrt(n_b S²_b + n_t S²_t)/(n_b n_t) (Neubert & Brunner 2007).
    Ranks depend only on how many units of each group share each distinct value, so
    this is `brunner_munzel_counts` on those counts.
    """
    masks = np.atleast_2d(np.asarray(masks, bool))
    _, inv = np.unique(pooled, return_inverse=True)
    inv = inv.reshape(-1)
    U = int(inv.max()) + 1
    total = np.bincount(inv, minlength=U).astype(np.float64)
    kt = np.stack([np.bincount(inv, weights=m, minlength=U) for m in masks.astype(np.float64)])
    return brunner_munzel_counts(total - kt, kt, alpha)


def brunner_munzel_counts(kb, kt, alpha: float = 0.05):
    """Brunner–Munzel from counts per distinct value (ascending): kb, kt [S, U] or [U].

    Same results as `brunner_munzel_masks` (mid-ranks are half-integers, so the sums
    are exact in float64 below 2^53) in O(S · U) instead of O(S · N log N).
    """
    kb = np.atleast_2d(np.asarray(kb, np.float64))
    kt = np.atleast_2d(np.asarray(kt, np.float64))

    def mid_ranks(c):  # mid-rank of each value within the units counted by c
        return np.cumsum(c, axis=1) - c + (c + 1) / 2

    rc = mid_ranks(kb + kt)  # pooled mid-ranks
    rt, rb = mid_ranks(kt), mid_ranks(kb)
    nt, nb = kt.sum(1), kb.sum(1)
    dt, db = rc - rt, rc - rb
    mean_t = (kt * dt).sum(1) / nt
    mean_b = (kb * db).sum(1) / nb
    s2t = ((kt * dt**2).sum(1) - nt * mean_t**2) / (nt - 1)
    s2b = ((kb * db**2).sum(1) - nb * mean_b**2) / (nb - 1)
    rct = (kt * rc).sum(1) / nt
    rcb = (kb * rc).sum(1) / nb
    phat = a12_counts(kb, kt)  # = (rct − (nt + 1) / 2) / nb, the pairs counted exactly
    var = nb * s2b + nt * s2t
    se = np.sqrt(np.maximum(var, 0)) / (nb * nt)
    with np.errstate(divide="ignore", invalid="ignore"):
        w = (rct - rcb) * nb * nt / ((nb + nt) * np.sqrt(var))
        df = var**2 / ((nb * s2b) ** 2 / (nb - 1) + (nt * s2t) ** 2 / (nt - 1))
    deg = ~(var > 0)
    w = np.where(deg, 0.0, w)
    df = np.where(deg, np.nan, df)
    p = np.where(
        deg, np.where(np.isclose(phat, 0.5), 1.0, 0.0), 2 * special.stdtr(np.where(deg, 1, df), -np.abs(w))
    )
    q = np.where(deg, 0.0, special.stdtrit(np.where(deg, 1, df), 1 - alpha / 2))
    lo = np.clip(phat - q * se, 0, 1)
    hi = np.clip(phat + q * se, 0, 1)
    return phat, w, df, p, lo, hi


def a12_counts(kb, kt):
    """A12 = P(T > B) + ½P(T = B) (Vargha & Delaney 2000), its one definition: the pairs counted
    from counts per ascending distinct value kb, kt [..., U], each treatment unit scoring the
    baseline units below it and half of those equal to it. Half-integers: the sum is exact in
    float64 below 2^52 pairs, so the result is the correctly rounded share."""
    kb, kt = np.asarray(kb, np.float64), np.asarray(kt, np.float64)
    return (kt * (np.cumsum(kb, axis=-1) - 0.5 * kb)).sum(-1) / (kb.sum(-1) * kt.sum(-1))


def _pool(x_baseline, x_treatment):
    x = check_sample(x_baseline, "x_baseline")
    y = check_sample(x_treatment, "x_treatment")
    pooled = np.concatenate([x, y])
    mask = np.concatenate([np.zeros(x.size, bool), np.ones(y.size, bool)])[None]
    return pooled, mask


def brunner_munzel(x_baseline, x_treatment) -> TestResult:
    """Brunner–Munzel test of P(T > B) + ½P(T = B) = ½ (Brunner & Munzel 2000).

    Same statistic and p-value as `scipy.stats.brunnermunzel(x_baseline, x_treatment)`.
    """
    pooled, mask = _pool(x_baseline, x_treatment)
    _, w, df, p, _, _ = brunner_munzel_masks(pooled, mask)
    return TestResult(float(w[0]), float(p[0]), float(df[0]))


def a12(x_baseline, x_treatment, alpha: float = 0.05) -> Estimate:
    """Vargha–Delaney A12 = P(T > B) + ½P(T = B) with the Brunner–Munzel CI (Vargha & Delaney 2000)."""
    pooled, mask = _pool(x_baseline, x_treatment)
    phat, _, _, _, lo, hi = brunner_munzel_masks(pooled, mask, alpha)
    return Estimate(float(phat[0]), float(lo[0]), float(hi[0]), 1 - alpha)


# ---------------------------------------------------------------- power, Holm
def power_ttest(d: float, n: int, alpha: float = 0.05) -> float:
    """Power of the two-sided two-sample t-test with n per group (noncentral t; Cohen 1988)."""
    df = 2 * n - 2
    nc = d * math.sqrt(n / 2)
    crit = special.stdtrit(df, 1 - alpha / 2)
    return float(1 - special.nctdtr(df, nc, crit) + special.nctdtr(df, nc, -crit))


def seeds_for_power(d: float, power: float = 0.8, alpha: float = 0.05, n_max: int = 10**8) -> int | None:
    """Smallest seeds per method giving `power` to detect standardised effect |d| (None if > n_max)."""
    d = abs(float(d))
    if not d > 0 or not math.isfinite(d):
        return None
    z = special.ndtri(1 - alpha / 2) + special.ndtri(power)
    guess = max(2, int(2 * (z / d) ** 2))
    if guess > n_max:
        return None
    lo, hi = 2, max(3, guess)
    while power_ttest(d, hi, alpha) < power:
        lo, hi = hi, hi * 2
        if hi > n_max:
            return None
    while hi - lo > 1:  # power increases with n: bisect
        mid = (lo + hi) // 2
        if power_ttest(d, mid, alpha) >= power:
            hi = mid
        else:
            lo = mid
    return hi if power_ttest(d, lo, alpha) < power else lo


def holm(pvalues) -> np.ndarray:
    """Holm (1979) step-down adjusted p-values (same order as given)."""
    p = np.asarray(pvalues, dtype=np.float64)
    m = p.size
    order = np.argsort(p)
    adj = np.maximum.accumulate((m - np.arange(m)) * p[order])
    out = np.empty(m)
    out[order] = np.minimum(adj, 1.0)
    return out


def level_keys(obj, level: float):
    """`obj` with level-neutral interval keys: ``x_ci95`` becomes ``x_ci`` (``ci95``: ``ci``), the
    level being stated once beside them. At level 0.95 the old name stays too, after the new one,
    for readers of the release before; at any other level it is dropped, so no key says 95 %
    of an interval that is not."""
    keep = abs(level - 0.95) < 1e-12
    if isinstance(obj, dict):
        out = {}
        for k, v in obj.items():
            v = level_keys(v, level)
            if isinstance(k, str) and (k.endswith("_ci95") or k == "ci95"):
                out[k[:-2]] = v
                if keep:
                    out[k] = v
            else:
                out[k] = v
        return out
    if isinstance(obj, list):
        return [level_keys(v, level) for v in obj]
    return obj
