"""One measure's resampled results above `large.LARGE_N` seeds per method (`measure_large`),
and the Monte-Carlo permutation p both paths report (`perm_p`).

Shared by the comparison (`jaxeac.stats.compare`) and the bootstrap's `bca_ci`
(`jaxeac.stats.bootstrap`); see `jaxeac.stats.large` for the methods and their references.
"""

from __future__ import annotations

import jax
import numpy as np

from jaxeac.stats import large
from jaxeac.stats._rng import as_key, host_rng, hypergeometric_counts, multinomial_counts
from jaxeac.stats.asymptotic import abc_intervals, normal_permutation_p
from jaxeac.stats.bca import bca_two_sample_counts
from jaxeac.stats.closed_form import iqm_sorted, welch_t_stat


def perm_p(t_obs, t_star):
    """Two-sided Monte-Carlo permutation p = (1 + #{|t*| ≥ |t|}) / (P + 1) (Phipson & Smyth 2010)."""
    return (1 + (np.abs(t_star) >= _threshold(t_obs)).sum(0)) / (t_star.shape[0] + 1)


def permutation_welch_p(nb: int, nt: int, t_obs, tot1, tot2, s1, s2) -> float:
    """The studentised permutation p of one measure (Janssen 1997), its one definition: Welch's t
    of each relabelling, from its treatment sums s1, s2 [P] and the pooled totals, against t_obs."""
    return float(perm_p(t_obs, welch_t_stat(nb, tot1 - s1, tot2 - s2, nt, s1, s2)[:, None])[0])


def _threshold(t_obs):
    """|t| less a relative 1e-6, so sums of an equal labelling formed in another order count as ties."""
    a = np.abs(np.asarray(t_obs, np.float64))
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(a), a - 1e-6 * np.maximum(a, 1e-12), a)


def measure_large(
    x, y, key, *, resamples, alpha, bootstrap=True, permutation=True, iqm=False, centre=None, table=None,
    centred=False,
) -> dict:
    """Resampled results of one measure above `large.LARGE_N` seeds (see `jaxeac.stats.large`).

    key: (bootstrap baseline, bootstrap treatment, permutation) keys, or one key to split.
    x, y: raw per-seed values; the sums use them less `centre` (default: the pooled mean).
    centred: x and y are already less `centre` (then `table`, of the raw values, is needed).
    Returns the t statistic and the sums it comes from (of the centred values and their
    squares), p_permutation (permutation=True), diff and Hedges' g intervals (bootstrap=True),
    the IQM intervals (iqm=True) and the methods used.
    """
    if not isinstance(key, tuple):
        key = tuple(jax.random.split(as_key(key), 3))
    k_b, k_t, k_p = key
    c = np.concatenate([x, y]).mean() if centre is None else centre
    xc, yc = (x, y) if centred else (x - c, y - c)
    nb, nt = x.size, y.size
    sums = (xc.sum(), (xc**2).sum(), yc.sum(), (yc**2).sum())
    t_obs = float(welch_t_stat(nb, *sums[:2], nt, *sums[2:]))
    table = large.ValueTable(x, y) if table is None else table
    v = table.values - c
    out = {"t_welch": t_obs, "sums": sums, "distinct_values": table.distinct,
           "path": large.path_above(table.distinct)}  # the one rule (`large.resampling_path`)
    if out["path"] == large.PER_VALUE:
        out["methods"] = {
            "bootstrap": large.REFERENCES["bootstrap_per_value"],
            "permutation": large.REFERENCES["permutation_per_value"],
        }
        if permutation:
            pooled = table.kb + table.kt
            h = hypergeometric_counts(host_rng(k_p), pooled, nt, resamples)
            pt1, pt2 = large.moment_sums(h, v)
            tot1, tot2 = pooled @ v, pooled @ (v * v)
            out["p_permutation"] = permutation_welch_p(nb, nt, t_obs, tot1, tot2, pt1, pt2)
        if bootstrap or iqm:  # everything below is O(distinct values) per resample
            sums, groups = [], []
            for side, k, counts in (("baseline", k_b, table.kb), ("treatment", k_t, table.kt)):
                keep = counts > 0
                kk, vv = counts[keep].astype(np.float64), v[keep]
                groups.append((vv, kk))
                cnt = multinomial_counts(host_rng(k), counts[keep], resamples)
                sums.append(large.moment_sums(cnt, vv))
                if iqm:
                    q = large.iqm_from_counts(cnt, vv)
                    est = float(large.iqm_from_counts(kk[None], vv)[0])
                    lo, hi = large.iqm_interval(est, large.PER_VALUE, alpha, star=q, values=vv, counts=kk)
                    out[f"iqm_{side}"] = (est + c, lo + c, hi + c)
            (vb, kb), (vt, kt) = groups
            if bootstrap:
                for stat, name in (("mean_diff", "diff"), ("hedges_g", "hedges_g")):
                    out[name] = bca_two_sample_counts(stat, vb, kb, vt, kt, *sums[0], *sums[1], alpha)
        return out
    out["methods"] = {
        "bootstrap": large.REFERENCES["abc"],
        "permutation": large.REFERENCES["normal_permutation"],
    }
    out["p_permutation"] = float(normal_permutation_p(t_obs))
    if bootstrap:
        abc = abc_intervals(("mean_diff", "hedges_g"), xc, yc, alpha)
        out["diff"], out["hedges_g"] = abc["mean_diff"], abc["hedges_g"]
    if iqm:
        out["methods"]["iqm"] = large.REFERENCES["normal_bca"]
        for side, z in (("baseline", xc), ("treatment", yc)):
            est = iqm_sorted(np.sort(z))
            lo, hi = large.iqm_interval(est, large.ASYMPTOTIC, alpha, x=z)
            out[f"iqm_{side}"] = (est + c, lo + c, hi + c)
    return out
