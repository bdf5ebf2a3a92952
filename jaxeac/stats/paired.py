"""Paired comparisons: seed i of both methods shares its key (R1), so compare differences.

In a jaxeac run, seed i of AC and seed i of EAC start from the same key
``fold_in(root, i)`` and draw the same random streams, so their results correlate and
the per-seed differences d_i = x_EAC,i − x_AC,i carry less noise than two independent
samples. The paired analysis of a measure (Student 1908; Efron & Tibshirani 1993) gives:

* the mean difference with a **paired BCa bootstrap** interval: seeds (pairs) resampled
  together (Efron 1987), by the path `large.resampling_path(n, distinct, paired=True)` picks
  (recorded as ``path``): counts per distinct difference where there are at most
  `large.MAX_DISTINCT` (the same law as drawing pairs one by one, Efron 1979, so exact at any
  N), else pairs one by one up to `large.LARGE_N` seeds, else the bootstrap's normal limit
  (`normal_bca`, jackknife SE and acceleration);
* the **paired t test** (n − 1 degrees of freedom) and a **sign-flip permutation test**
  (under no difference each d_i is as likely to be −d_i; Fisher 1935): the flips of the
  seeds sharing a value |d| are a binomial count per value, exact for any N; with more
  distinct values the flips are drawn per seed up to `large.LARGE_N` seeds, and above
  that the permutation law's normal limit (its variance Σ d_i² is exact);
* the paired effect size **d_z** = mean(d) / sd(d) (Cohen 1988) with a BCa interval from
  the same resamples, and the correlation of the two methods' per-seed values.

Resampling draws come from NumPy's exact samplers seeded from the JAX key
(`host_rng`), so results do not depend on the device.
"""

from __future__ import annotations

import math

import jax
import numpy as np
from scipy import special

from jaxeac.rng import as_key
from jaxeac.stats import large
from jaxeac.stats._rng import host_rng, multinomial_counts
from jaxeac.stats.asymptotic import normal_bca
from jaxeac.stats.bca import bca_interval

#: Random draws per block when resampling pairs or flipping signs seed by seed.
DRAWS = 1 << 22

DESIGN = ("paired: seed i of both methods starts from the same key fold_in(root, i) and draws the "
          "same random streams (SPEC R1), so the per-seed differences are compared")


def _dz(mean: np.ndarray, square: np.ndarray, n: int) -> np.ndarray:
    """d_z = mean / sd from the mean and the mean square of the differences (undefined, NaN, for
    fewer than two: a jackknife sample of a two-seed run). In place where it can: the jackknife
    passes one value per seed."""
    if n < 2:
        return np.full(np.shape(mean), np.nan)
    mean = np.asarray(mean, np.float64)
    sd = np.array(square - mean * mean, np.float64)
    np.maximum(sd, 0.0, out=sd)
    sd *= n
    sd /= n - 1
    np.sqrt(sd, out=sd)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.array(mean / sd)
    bad = ~(sd > 0)
    if bad.any():
        m = np.broadcast_to(mean, out.shape)[bad]
        out[bad] = np.where(m == 0, 0.0, np.copysign(np.inf, m))
    return out


#: The fields `paired_tests` gives.
PAIRED_TEST_FIELDS = ("n", "mean_diff", "sd_diff", "se_diff", "t_paired", "df", "p_paired_t", "d_z")


def paired_tests(d: np.ndarray) -> dict:
    """The closed-form part of a paired comparison of per-seed differences d, its one definition
    (run folders and the engine): the mean difference, its sd and se, the paired t test (Student
    1908; n − 1 df; no spread gives t = ±inf, p = 0, or t = 0, p = 1) and d_z (`_dz`)."""
    n = d.size
    mean = float(d.mean())
    sd = float(d.std(ddof=1))
    se = sd / math.sqrt(n)
    t = mean / se if se > 0 else (math.copysign(math.inf, mean) if mean else 0.0)
    p = float(2 * special.stdtr(n - 1, -abs(t))) if math.isfinite(t) else (0.0 if mean else 1.0)
    dz = float(_dz(np.array(mean), np.array(float((d * d).mean())), n))
    return dict(zip(PAIRED_TEST_FIELDS, (n, mean, sd, se, t, n - 1, p, dz), strict=True))


def paired_analysis(baseline, treatment, key, *, resamples: int = 10_000, alpha: float = 0.05,
                    mean_only: bool = False) -> dict:
    """The paired comparison of one measure: x_treatment,i − x_baseline,i over seeds i. `mean_only`
    (the engine's paired rows, which report no more): the mean difference's interval without d_z's
    interval and the sign-flip test; the same draws, so the same interval."""
    xb, xt = np.asarray(baseline, np.float64), np.asarray(treatment, np.float64)
    del baseline, treatment  # arrays made for the call go with xb and xt below
    if xb.shape != xt.shape or xb.ndim != 1 or xb.size < 2:
        raise ValueError(f"a paired comparison needs two samples of the same seeds, got {xb.shape} and "
                         f"{xt.shape}")
    # the correlation first: its [2, N] copies come and go before the differences exist
    r = float(np.corrcoef(xb, xt)[0, 1]) if xb.std() > 0 and xt.std() > 0 else math.nan
    d = xt - xb
    del xb, xt
    out = paired_tests(d)
    n, mean, dz = out["n"], out["mean_diff"], out["d_z"]
    k_boot, k_flip = jax.random.split(as_key(key))
    values, counts = np.unique(d, return_counts=True)
    out |= {"correlation": r, "distinct_differences": int(values.size)}
    rng = host_rng(k_boot)
    path = large.resampling_path(n, values.size, paired=True)  # the one rule
    out["path"] = path
    u = values if path == large.PER_VALUE else d  # the jackknife: one pair (of each value) left out
    jk_mean = n * mean - u  # made in place (one value per seed on the large path)
    jk_mean /= n - 1
    jk_sq = u * u
    np.subtract((d * d).sum(), jk_sq, out=jk_sq)
    jk_sq /= n - 1
    jk_dz = _dz(jk_mean, jk_sq, n - 1)
    del jk_sq
    if path == large.PER_VALUE:  # exact: counts per distinct difference
        c = multinomial_counts(rng, counts, resamples)
        s1, s2 = large.moment_sums(c, values)
        boot_mean, boot_sq = s1 / n, s2 / n
        jk, jk_dz = [(jk_mean, counts)], [(jk_dz, counts)]
        out["bootstrap"] = "exact: multinomial counts per distinct difference (Efron 1979)"
    elif path == large.RAW:  # pairs one by one
        boot_mean, boot_sq = np.empty(resamples), np.empty(resamples)
        step = max(1, DRAWS // n)  # resamples per block
        for i in range(0, resamples, step):
            k = min(step, resamples - i)
            idx = rng.integers(0, n, (k, n))
            boot_mean[i:i + k] = d[idx].mean(1)
            boot_sq[i:i + k] = (d[idx] ** 2).mean(1)
        jk, jk_dz = [jk_mean], [jk_dz]
        out["bootstrap"] = "pairs resampled one by one"
    else:  # the bootstrap's normal limit
        out |= {"mean_diff_ci95": list(normal_bca(mean, jk_mean, alpha)),
                "bootstrap": large.REFERENCES["normal_bca"]}
        if not mean_only:
            out["d_z_ci95"] = list(normal_bca(dz, jk_dz, alpha))
        boot_mean = None
    if boot_mean is not None:
        out["mean_diff_ci95"] = list(bca_interval(mean, boot_mean, jk, alpha))
        if not mean_only:
            out["d_z_ci95"] = list(bca_interval(dz, _dz(boot_mean, boot_sq, n), jk_dz, alpha))
    if not mean_only:
        out |= sign_flip_p(d, values, counts, k_flip, resamples)
    return out


def sign_flip_p(d: np.ndarray, values: np.ndarray, counts: np.ndarray, key, resamples: int) -> dict:
    """Two-sided sign-flip permutation p of Σ d_i: (1 + #{|S*| ≥ |S|}) / (R + 1)."""
    observed = abs(float(d.sum()))
    rng = host_rng(key)
    mags, inv = np.unique(np.abs(values), return_inverse=True)
    per_mag = np.bincount(inv.reshape(-1), weights=counts, minlength=mags.size).astype(np.int64)
    keep = mags > 0
    mags, per_mag = mags[keep], per_mag[keep]
    tol = 1e-9 * max(1.0, observed)
    path = large.resampling_path(d.size, mags.size, paired=True)  # the one rule
    if path == large.PER_VALUE:  # exact: the number of + signs per magnitude is binomial
        plus = rng.binomial(per_mag[None, :], 0.5, size=(resamples, mags.size))
        s = (2 * plus - per_mag[None, :]) @ mags
        method = "exact: binomial sign counts per distinct |difference| (Fisher 1935)"
    elif path == large.RAW:
        s = np.empty(resamples)
        step = max(1, DRAWS // d.size)
        for i in range(0, resamples, step):
            k = min(step, resamples - i)
            s[i:i + k] = np.where(rng.random((k, d.size)) < 0.5, -1.0, 1.0) @ d
        method = "signs flipped seed by seed"
    else:
        z = observed / math.sqrt(float((d * d).sum())) if (d * d).sum() > 0 else 0.0
        return {"p_sign_flip": float(2 * special.ndtr(-z)), "sign_flip": "normal limit, variance Σ d²"}
    p = (1 + int((np.abs(s) >= observed - tol).sum())) / (resamples + 1)
    return {"p_sign_flip": p, "sign_flip": method}
