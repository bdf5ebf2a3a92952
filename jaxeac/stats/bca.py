"""BCa intervals (Efron 1987) from bootstrap replicates and closed-form jackknife values.

`bca_interval` follows Efron & Tibshirani (1993, ch. 14) exactly as
`scipy.stats.bootstrap(method="BCa")` does: bias correction from the share of
replicates below the estimate, acceleration from jackknife influence values
summed over the samples. Jackknife values are closed-form here (leave-one-out
means, variances and trimmed means), so no statistic is recomputed n times.

Arithmetic on replicates already drawn: no resampling, so the resampling code of every path
(`jaxeac.stats.groups`, `jaxeac.stats.compare`) builds on it.
"""

from __future__ import annotations

import numpy as np
from scipy import special

from jaxeac.stats.closed_form import Estimate, hedges_from_moments


def bca_interval(theta_hat: float, theta_star, jackknife, alpha: float = 0.05) -> tuple[float, float]:
    """BCa interval from bootstrap replicates and per-sample jackknife values (Efron 1987).

    jackknife: a list with one 1-D array of leave-one-out estimates per sample, or per
    sample a pair (estimates, counts): the leave-one-out estimate of each distinct value
    and how many units have it (the large-N path, `jaxeac.stats.large`).
    """
    theta_star = np.asarray(theta_star, np.float64)
    if not np.isfinite(theta_hat):  # e.g. Hedges' g of two constant samples
        return float(theta_hat), float(theta_hat)
    b = theta_star.size
    # ties with the estimate count one half: a replicate equal to the estimate may differ from it
    # in the last bits (the replicates' float64 sums run in another order than the estimate's;
    # on integer data every tie once counted as below), so both are rounded to float32 here
    star32, hat32 = theta_star.astype(np.float32), np.float32(theta_hat)
    pct = ((star32 < hat32).sum() + (star32 <= hat32).sum()) / (2 * b)
    z0 = special.ndtri(pct)
    nums, dens = 0.0, 0.0
    for jk in jackknife:
        if isinstance(jk, tuple):  # (estimate per distinct value, units with that value)
            jk, w = (np.asarray(a, np.float64) for a in jk)
            if not np.isfinite(jk).all():
                nums, dens = 0.0, 0.0
                break
            n = w.sum()
            u = (n - 1) * ((w @ jk) / n - jk)
            nums += (w @ u**3) / n**3
            dens += (w @ u**2) / n**2
            continue
        jk = np.asarray(jk, np.float64)
        if not np.isfinite(jk).all():
            nums, dens = 0.0, 0.0  # undefined influence values: no acceleration
            break
        n = jk.size
        u = (n - 1) * (jk.mean() - jk)
        nums += (u**3).sum() / n**3
        dens += (u**2).sum() / n**2
    a = nums / (6 * dens**1.5) if dens > 0 else 0.0
    za = special.ndtri(alpha / 2)
    if np.isfinite(z0):
        lo_q = special.ndtr(z0 + (z0 + za) / (1 - a * (z0 + za)))
        hi_q = special.ndtr(z0 + (z0 - za) / (1 - a * (z0 - za)))
    else:  # all replicates on one side: fall back to the percentile interval
        lo_q, hi_q = alpha / 2, 1 - alpha / 2
    with np.errstate(invalid="ignore"):
        lo, hi = np.percentile(theta_star, [100 * lo_q, 100 * hi_q])
    return float(lo), float(hi)


def jackknife_iqm(x: np.ndarray) -> np.ndarray:
    """Leave-one-out IQMs in O(n log n) from prefix sums of the sorted sample."""
    order = np.argsort(x, kind="stable")
    xs = x[order]
    n = xs.size
    m = n - 1
    g = m // 4
    a, b = g, m - g
    pre = np.concatenate([[0.0], np.cumsum(xs)])
    j = np.arange(n)
    s_after = pre[b] - pre[a]  # removed unit sorts after the kept block
    s_before = pre[b + 1] - pre[a + 1]  # removed unit sorts before it
    s_inside = (pre[np.minimum(j, b)] - pre[a]) + (pre[b + 1] - pre[np.minimum(j + 1, b + 1)])
    s = np.where(j >= b, s_after, np.where(j < a, s_before, s_inside))
    out = np.empty(n)
    out[order] = s / (b - a)
    return out


def _two_sample_stat(statistic, n1, s1, ss1, n2, s2, ss2):
    if statistic == "mean_diff":
        return s2 / n2 - s1 / n1
    return hedges_from_moments(n1, s1, ss1, n2, s2, ss2)


def bca_two_sample_counts(statistic, vb, kb, vt, kt, sb1, sb2, st1, st2, alpha) -> Estimate:
    """mean(t) − mean(b) ("mean_diff") or Hedges' g with its BCa interval, from each sample's
    distinct values and their counts (v*, k*; units one by one: counts of 1) and the bootstrap sums
    of values and squares of each (sb*, st* [R]): the estimate and the jackknife in O(values)."""
    nb, nt = kb.sum(), kt.sum()
    b1, b2, t1, t2 = kb @ vb, kb @ vb**2, kt @ vt, kt @ vt**2
    # A few seeds per method: resamples and leave-one-out samples without spread give g = ±inf
    # or NaN (0/0), which the interval below takes as they are; numpy need not warn of them.
    with np.errstate(divide="ignore", invalid="ignore"):
        est = float(_two_sample_stat(statistic, nb, b1, b2, nt, t1, t2))
        star = _two_sample_stat(statistic, nb, sb1, sb2, nt, st1, st2)
        jx = _two_sample_stat(statistic, nb - 1, b1 - vb, b2 - vb**2, nt, t1, t2)
        jy = _two_sample_stat(statistic, nb, b1, b2, nt - 1, t1 - vt, t2 - vt**2)
        lo, hi = bca_interval(est, star, [(jx, kb), (jy, kt)], alpha)
    return Estimate(est, lo, hi, 1 - alpha)
