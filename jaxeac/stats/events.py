"""Tests of events, on the host (SPEC §6): the log-rank test of time to first success (Mantel
1966; Peto & Peto 1972) and the intervals of proportions (any success, success in the final
trial): Wilson (1927), Newcombe (1998) and Miettinen & Nurminen (1985).

Like `jaxeac.stats.closed_form`, the vectorised helpers take counts per category or bool
masks [S, N] of many splits at once (the calibration), and the public functions are thin
wrappers for two plain samples.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import special

from jaxeac.errors import UsageError
from jaxeac.stats.closed_form import Estimate, TestResult, check_sample


def logrank_masks(time: np.ndarray, event: np.ndarray, masks: np.ndarray):
    """Two-sample log-rank (Mantel 1966; Peto & Peto 1972) for many splits.

    time: int [N] event or censoring times; event: bool [N]; masks bool [S, N]
    (True = treatment). Returns (chi2, p, observed_t, expected_t) of length S.
    Only counts per (time, event) pair enter, so this is `logrank_counts` on them.
    """
    masks = np.atleast_2d(np.asarray(masks, bool))
    times, inv = np.unique(np.asarray(time), return_inverse=True)
    code = 2 * inv.reshape(-1) + np.asarray(event, bool)  # category (time, event)
    total = np.bincount(code, minlength=2 * times.size)
    treat = np.stack([np.bincount(code, weights=m, minlength=total.size) for m in masks.astype(np.float64)])
    return logrank_counts(total, treat)


def logrank_counts(total_c, treat_c):
    """Log-rank test from counts per category, category 2j + e holding the units of the j-th
    distinct time (ascending) with event flag e (as `event_table` counts them): `total_c` [2J]
    units in both groups, `treat_c` [S, 2J] in the treatment group of each of S splits. Returns
    (chi2, p, observed_t, expected_t) of length S. O(S · J).
    """
    total_c = np.asarray(total_c, np.float64)
    treat_c = np.atleast_2d(np.asarray(treat_c, np.float64))
    ev = 1 + 2 * np.flatnonzero(total_c[1::2] > 0)  # the event categories, ascending in time
    if ev.size == 0:
        s = treat_c.shape[0]
        return np.zeros(s), np.ones(s), np.zeros(s), np.zeros(s)

    def at_risk(cnt):  # [..., 2J] -> [..., events]: units with time >= the event's time
        return np.cumsum(cnt[..., ::-1], axis=-1)[..., ::-1][..., ev - 1]

    d_t = treat_c[..., ev]  # [S, J] events in treatment
    d = total_c[ev]  # [J] events in both groups
    n_t = at_risk(treat_c)  # [S, J] at risk in treatment
    n_all = at_risk(total_c)  # [J]
    e_t = d * n_t / n_all
    with np.errstate(divide="ignore", invalid="ignore"):
        v = np.where(n_all > 1, d * (n_t / n_all) * (1 - n_t / n_all) * (n_all - d) / (n_all - 1), 0.0)
    o, e, var = d_t.sum(1), e_t.sum(1), v.sum(1)
    with np.errstate(divide="ignore", invalid="ignore"):
        chi2 = np.where(var > 0, (o - e) ** 2 / np.where(var > 0, var, 1), 0.0)
    return chi2, special.chdtrc(1, chi2), o, e


def event_table(time, event) -> tuple[np.ndarray, np.ndarray]:
    """A sample's log-rank categories: (distinct times ascending [J]; counts int64 [2J], category
    2j + e holding time j with event flag e)."""
    times, inv = np.unique(np.asarray(time), return_inverse=True)
    return times, np.bincount(2 * inv.reshape(-1) + np.asarray(event, bool), minlength=2 * times.size)


def logrank_tables(baseline, treatment) -> TestResult:
    """Two-sample log-rank from each group's `event_table` (O(J) after the tables)."""
    (tb, kb), (tt, kt) = baseline, treatment
    times = np.union1d(tb, tt).astype(np.float64)
    total, treat = np.zeros((times.size, 2)), np.zeros((times.size, 2))
    total[np.searchsorted(times, tb)] += kb.reshape(-1, 2)
    total[np.searchsorted(times, tt)] += kt.reshape(-1, 2)
    treat[np.searchsorted(times, tt)] = kt.reshape(-1, 2)
    chi2, p, _, _ = logrank_counts(total.reshape(-1), treat.reshape(1, -1))
    return TestResult(float(chi2[0]), float(p[0]), 1.0)


def logrank(time_baseline, event_baseline, time_treatment, event_treatment) -> TestResult:
    """Log-rank test for time to first success; censored units have event=False.

    Matches `statsmodels.duration.survfunc.survdiff`.
    """
    tb, tt = check_sample(time_baseline, "time_baseline"), check_sample(time_treatment, "time_treatment")
    eb, et = np.asarray(event_baseline, bool), np.asarray(event_treatment, bool)
    if eb.shape != tb.shape or et.shape != tt.shape:
        raise UsageError("event and time arrays have different shapes; pass one entry per seed in each")
    return logrank_tables(event_table(tb, eb), event_table(tt, et))


def wilson_ci(count: float, nobs: float, alpha: float = 0.05) -> tuple[float, float]:
    """Wilson (1927) score interval for a binomial proportion."""
    z = special.ndtri(1 - alpha / 2)
    p = count / nobs
    den = 1 + z**2 / nobs
    centre = (p + z**2 / (2 * nobs)) / den
    half = z * math.sqrt(p * (1 - p) / nobs + z**2 / (4 * nobs**2)) / den
    # at a count of 0 (of nobs) the bound is exactly 0 (1): centre and half are equal there
    low = 0.0 if count <= 0 else max(0.0, centre - half)
    return low, 1.0 if count >= nobs else min(1.0, centre + half)


def newcombe_diff(count_baseline, n_baseline, count_treatment, n_treatment, alpha=0.05) -> Estimate:
    """Risk difference p_t − p_b with Newcombe's hybrid score interval (Newcombe 1998, method 10)."""
    pb, pt = count_baseline / n_baseline, count_treatment / n_treatment
    lb, ub = wilson_ci(count_baseline, n_baseline, alpha)
    lt, ut = wilson_ci(count_treatment, n_treatment, alpha)
    d = pt - pb
    low = d - math.sqrt((pt - lt) ** 2 + (ub - pb) ** 2)
    high = d + math.sqrt((ut - pt) ** 2 + (pb - lb) ** 2)
    return Estimate(d, low, high, 1 - alpha)


def _ratio_score_z(phi, x1, n1, x2, n2, correction):
    """Score statistic for H0: p1 = phi·p2 (Miettinen & Nurminen 1985; Koopman 1984)."""
    big_n = n1 + n2
    a = big_n * phi
    b = -(n1 * phi + x1 + n2 + x2 * phi)
    c = x1 + x2
    p2r = (-b - math.sqrt(max(b * b - 4 * a * c, 0.0))) / (2 * a)
    p1r = phi * p2r
    var = p1r * (1 - p1r) / n1 + phi**2 * p2r * (1 - p2r) / n2
    if correction:
        var *= big_n / (big_n - 1)
    diff = x1 / n1 - phi * x2 / n2
    if var <= 0:
        return math.copysign(math.inf, diff) if diff else 0.0
    return diff / math.sqrt(var)


def _root(f, lo: float, hi: float, *args) -> float:
    """The root of f(·, *args) in [lo, hi] (f(lo) > 0 > f(hi)) by bisection to the last float: a
    few dozen evaluations, without importing scipy.optimize (0.5 s on a 2-core CPU, in the
    statistics' critical path)."""
    while True:
        mid = 0.5 * (lo + hi)
        if mid in (lo, hi):
            return mid
        if f(mid, *args) > 0:
            lo = mid
        else:
            hi = mid


def risk_ratio_ci(
    count_baseline, n_baseline, count_treatment, n_treatment, alpha=0.05, correction=True
) -> Estimate:
    """Risk ratio p_t / p_b with the score interval (Miettinen & Nurminen 1985).

    With correction=True this matches statsmodels
    `confint_proportions_2indep(..., compare="ratio", method="score")`.
    """
    x1, n1, x2, n2 = float(count_treatment), float(n_treatment), float(count_baseline), float(n_baseline)
    z = special.ndtri(1 - alpha / 2)
    est = (x1 / n1) / (x2 / n2) if x2 > 0 else math.inf

    def f(logphi, target):
        return _ratio_score_z(math.exp(logphi), x1, n1, x2, n2, correction) - target

    # z(phi) decreases in phi: the CI is {phi : -z <= z(phi) <= z}
    lo_end, hi_end = -30.0, 30.0
    low = 0.0 if x1 == 0 or f(lo_end, z) <= 0 else math.exp(_root(f, lo_end, hi_end, z))
    high = math.inf if x2 == 0 or f(hi_end, -z) >= 0 else math.exp(_root(f, lo_end, hi_end, -z))
    return Estimate(est, low, high, 1 - alpha)


def proportions(event_baseline, event_treatment, alpha: float = 0.05) -> dict:
    """A proportion's record (any success, success in the final trial) from bool [N] per method:
    the counts, the risk difference (`newcombe_diff`) and the risk ratio (`risk_ratio_ci`)."""
    ob, ot = np.asarray(event_baseline), np.asarray(event_treatment)
    cb, ct = int(ob.sum()), int(ot.sum())
    rd = newcombe_diff(cb, ob.size, ct, ot.size, alpha)
    rr = risk_ratio_ci(cb, ob.size, ct, ot.size, alpha)
    return {
        "count_baseline": cb,
        "n_baseline": int(ob.size),
        "count_treatment": ct,
        "n_treatment": int(ot.size),
        "risk_difference": rd.estimate,
        "risk_difference_ci95": [rd.low, rd.high],
        "risk_difference_method": "Newcombe (1998) hybrid score, method 10",
        "risk_ratio": rr.estimate,
        "risk_ratio_ci95": [rr.low, rr.high],
        "risk_ratio_method": "Miettinen-Nurminen (1985) score",
    }
