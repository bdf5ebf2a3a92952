"""Bootstrap intervals: BCa (Efron 1987) and the IQM (SPEC §6).

The resampling here; the interval arithmetic (`bca_interval`, the closed-form jackknife
values) in `jaxeac.stats.bca`. Above `large.LARGE_N` seeds `bca_ci` takes the large-N path of
`jaxeac.stats.measure_large`, and `iqm_ci` the engine's `Group` (`jaxeac.stats.groups`).
"""

from __future__ import annotations

import jax
import numpy as np

from jaxeac.stats import large
from jaxeac.stats._rng import as_key
from jaxeac.stats.bca import bca_interval, bca_two_sample
from jaxeac.stats.closed_form import Estimate, check_sample, iqm
from jaxeac.stats.measure_large import measure_large
from jaxeac.stats.resample import bootstrap_sums


def bca_ci(
    x_baseline,
    x_treatment,
    key,
    *,
    statistic: str = "mean_diff",
    resamples: int = 10_000,
    alpha: float = 0.05,
    chunk: int = 1000,
) -> Estimate:
    """BCa bootstrap CI for mean(treatment) − mean(baseline) or Hedges' g (Efron 1987).

    The two samples are resampled independently (seeds within each method), as in
    `scipy.stats.bootstrap((x_baseline, x_treatment), ..., method="BCa")`.
    """
    if statistic not in ("mean_diff", "hedges_g"):
        raise ValueError(f"statistic must be 'mean_diff' or 'hedges_g', got {statistic!r}")
    x = check_sample(x_baseline, "x_baseline")
    y = check_sample(x_treatment, "x_treatment")
    kb, kt = jax.random.split(as_key(key), 2)
    if large.is_large(x.size, y.size):  # per-value bootstrap or ABC (`jaxeac.stats.large`)
        res = measure_large(x, y, (kb, kt, None), resamples=resamples, alpha=alpha, permutation=False)
        return res["diff" if statistic == "mean_diff" else "hedges_g"]
    centre = np.concatenate([x, y]).mean()
    x, y = x - centre, y - centre
    sb, _ = bootstrap_sums(kb, np.stack([x, x**2], 1), resamples, chunk=chunk)
    st, _ = bootstrap_sums(kt, np.stack([y, y**2], 1), resamples, chunk=chunk)
    return bca_two_sample(statistic, x, y, sb[:, 0], sb[:, 1], st[:, 0], st[:, 1], alpha)


def iqm_ci(x, key, *, resamples: int = 10_000, alpha: float = 0.05, chunk: int = 1000) -> Estimate:
    """IQM of one method's per-seed values with a BCa bootstrap CI, on the path
    `large.resampling_path` gives (raw draws on the device, counts per value, or the normal limit)."""
    x = check_sample(x)
    if large.is_large(x.size):  # counts per value or the normal limit: the engine's group
        from jaxeac.stats.groups import Group

        est, lo, hi = Group(x, as_key(key), resamples, chunk).iqm(alpha)
        return Estimate(est, lo, hi, 1 - alpha)
    est = iqm(x)
    _, q = bootstrap_sums(as_key(key), x[:, None], resamples, chunk=chunk, iqm=True)
    lo, hi = large.iqm_interval(est, large.RAW, alpha, x=x, star=q)
    return Estimate(est, lo, hi, 1 - alpha)


__all__ = ["bca_ci", "bca_interval", "iqm", "iqm_ci"]
