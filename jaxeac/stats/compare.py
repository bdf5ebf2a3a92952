"""AC-versus-EAC comparison of per-seed measures and curves (SPEC §6).

The seed is the unit of analysis. One bootstrap draw per method and one set of
permutations of the pooled seeds serve every measure and the curves at once
(see `resample`); everything else is closed-form on the host. Each measure gets
the difference of means with a BCa CI (Efron 1987), Welch's t-test (Welch
1947) checked by a studentised permutation test (Janssen 1997), Brunner–Munzel
(Brunner & Munzel 2000), Hedges' g with a BCa CI, A12 with the Brunner–Munzel
CI, and the seeds needed for 80 % power. Holm (1979) adjusts the declared
family of measures. An AC-versus-AC calibration checks each test's false-positive
rate on random disjoint splits of the baseline seeds.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping

import jax
import numpy as np

from jaxeac.errors import UsageError
from jaxeac.stats import closed_form as cf
from jaxeac.stats._rng import as_key
from jaxeac.stats.bootstrap import (
    bca_interval,
    bca_two_sample,
    jackknife_iqm,
)
from jaxeac.stats.curves import curve_columns, curve_results, is_binary, welch_t_stat
from jaxeac.stats.resample import dispatch_bootstrap, dispatch_permutation, dispatch_subsets, permutation_sums

POWER_DS = (0.2, 0.5, 0.8)


def _as_measures(x, name: str) -> dict:
    if isinstance(x, Mapping):
        if not x:
            raise UsageError(f"{name} has no measures")
        out = {k: cf.check_sample(v, f"{name}[{k!r}]") for k, v in x.items()}
    else:
        out = {"value": cf.check_sample(x, name)}
    sizes = {v.shape[0] for v in out.values()}
    if len(sizes) != 1:
        raise UsageError(
            f"{name}: measures have different numbers of seeds {sorted(sizes)}; "
            "give one value per seed for each"
        )
    return out


def _perm_p(t_obs, t_star):
    """Two-sided Monte-Carlo permutation p = (1 + #{|t*| ≥ |t|}) / (P + 1) (Phipson & Smyth 2010)."""
    return (1 + (np.abs(t_star) >= _threshold(t_obs)).sum(0)) / (t_star.shape[0] + 1)


def _threshold(t_obs):
    """|t| less a relative 1e-6, so float32 sums of the same labelling count as ties."""
    a = np.abs(np.asarray(t_obs, np.float64))
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(a), a - 1e-6 * np.maximum(a, 1e-12), a)


def permutation_test(
    x_baseline, x_treatment, key, *, resamples: int = 10_000, chunk: int = 1000
) -> cf.TestResult:
    """Permutation test of the studentised (Welch) t over random relabellings of the pooled seeds.

    Exact under exchangeability, and asymptotically valid for unequal variances
    because the statistic is studentised (Janssen 1997).
    """
    x = cf.check_sample(x_baseline, "x_baseline")
    y = cf.check_sample(x_treatment, "x_treatment")
    c = np.concatenate([x, y]).mean()
    x, y = x - c, y - c
    z = np.stack([np.r_[x, y], np.r_[x, y] ** 2], 1)
    pt = permutation_sums(as_key(key), z, y.size, resamples, chunk=chunk)
    tot = z.sum(0)
    t_obs = welch_t_stat(x.size, x.sum(), (x**2).sum(), y.size, y.sum(), (y**2).sum())
    t_star = welch_t_stat(x.size, tot[0] - pt[:, 0], tot[1] - pt[:, 1], y.size, pt[:, 0], pt[:, 1])
    return cf.TestResult(float(t_obs), float(_perm_p(t_obs, t_star[:, None])[0]))


def _power(g: float, alpha: float) -> dict:
    return {
        "observed_d": abs(g),
        "seeds_for_80pct_power": cf.seeds_for_power(g, 0.8, alpha),
        **{f"d={d}": cf.seeds_for_power(d, 0.8, alpha) for d in POWER_DS},
    }


def _analyse(
    mb: dict,
    mt: dict,
    key,
    *,
    curves=None,
    resamples: int,
    alpha: float,
    chunk: int,
    perm_chunk: int,
    higher_is_better: Mapping | None,
) -> dict:
    """Measures (and optionally curves) from one shared bootstrap and permutation draw."""
    names = list(mb)
    if list(mt) != names:
        raise UsageError(
            f"baseline measures {names} and treatment measures {list(mt)} differ; "
            "pass the same measures for both"
        )
    nb, nt = mb[names[0]].size, mt[names[0]].size
    xb = np.stack([mb[k] for k in names], 1)
    xt = np.stack([mt[k] for k in names], 1)
    centre = np.concatenate([xb, xt]).mean(0)
    xb, xt = xb - centre, xt - centre
    M = len(names)
    zb, zt = [xb, xb**2], [xt, xt**2]
    binary = True
    if curves is not None:
        cb, ct = curves
        binary = is_binary(cb, ct)
        zb.append(curve_columns(cb, binary))
        zt.append(curve_columns(ct, binary))
    zb, zt = np.concatenate(zb, 1), np.concatenate(zt, 1)
    k_b, k_t, k_p = jax.random.split(as_key(key), 3)
    t0 = time.perf_counter()
    # dispatch all three before waiting on any, so XLA can overlap them
    wait_b = dispatch_bootstrap(k_b, zb, resamples, chunk=chunk, iqm=True)
    wait_t = dispatch_bootstrap(k_t, zt, resamples, chunk=chunk, iqm=True)
    wait_p = dispatch_permutation(k_p, np.concatenate([zb, zt]), nt, resamples, chunk=perm_chunk)
    # closed-form parts on the host while XLA draws the resamples
    out = {}
    for j, name in enumerate(names):
        x, y = xb[:, j], xt[:, j]
        hib = True if higher_is_better is None else bool(higher_is_better.get(name, True))
        t, df, p = cf.welch_from_moments(nb, x.sum(), (x**2).sum(), nt, y.sum(), (y**2).sum())
        pooled = np.concatenate([x, y])
        mask = np.r_[np.zeros(nb, bool), np.ones(nt, bool)][None]
        a, w, bm_df, bm_p, a_lo, a_hi = (float(v[0]) for v in cf.brunner_munzel_masks(pooled, mask, alpha))
        g = float(cf.hedges_from_moments(nb, x.sum(), (x**2).sum(), nt, y.sum(), (y**2).sum()))
        pw = _power(g, alpha)
        out[name] = {
            "measure": name,
            "higher_is_better": hib,
            "n_baseline": nb,
            "n_treatment": nt,
            "mean_baseline": float(mb[name].mean()),
            "mean_treatment": float(mt[name].mean()),
            "sd_baseline": float(mb[name].std(ddof=1)),
            "sd_treatment": float(mt[name].std(ddof=1)),
            "diff": float(mt[name].mean() - mb[name].mean()),
            "diff_ci95": None,
            "t_welch": float(t),
            "df_welch": float(df),
            "p_welch": float(p),
            "p_permutation": None,
            "brunner_munzel": {"statistic": w, "df": bm_df, "p": bm_p},
            "hedges_g": g,
            "hedges_g_ci95": None,
            "a12": a,
            "a12_ci95": [a_lo, a_hi],
            "prob_improvement": a if hib else 1 - a,
            "prob_improvement_ci95": [a_lo, a_hi] if hib else [1 - a_hi, 1 - a_lo],
            "seeds_for_80pct_power": pw["seeds_for_80pct_power"],
            "power": pw,
        }
    (boot_b, iqm_b), (boot_t, iqm_t), perm = wait_b(), wait_t(), wait_p()
    t_resample = time.perf_counter() - t0
    tot = zb.sum(0) + zt.sum(0)
    for j, name in enumerate(names):
        x, y = xb[:, j], xt[:, j]
        boot = (boot_b[:, j], boot_b[:, M + j], boot_t[:, j], boot_t[:, M + j])
        diff = bca_two_sample("mean_diff", x, y, *boot, alpha)
        g = bca_two_sample("hedges_g", x, y, *boot, alpha)
        t_star = welch_t_stat(
            nb, tot[j] - perm[:, j], tot[M + j] - perm[:, M + j], nt, perm[:, j], perm[:, M + j]
        )
        t_obs = welch_t_stat(nb, x.sum(), (x**2).sum(), nt, y.sum(), (y**2).sum())
        out[name]["diff_ci95"] = [diff.low, diff.high]
        out[name]["hedges_g_ci95"] = [g.low, g.high]
        out[name]["p_permutation"] = float(_perm_p(t_obs, t_star[:, None])[0])
    # IQM per method of the first (primary) measure
    first = names[0]
    for side, x, q, n_ in (("baseline", xb[:, 0], iqm_b, nb), ("treatment", xt[:, 0], iqm_t, nt)):
        est = float(np.mean(np.sort(x)[n_ // 4 : n_ - n_ // 4]))
        lo, hi = bca_interval(est, q, [jackknife_iqm(x)], alpha)
        out[first][f"iqm_{side}"] = est + centre[0]
        out[first][f"iqm_{side}_ci95"] = [lo + centre[0], hi + centre[0]]
    curve = None
    if curves is not None:
        K = 2 * M
        curve = curve_results(
            curves[0].astype(np.float64),
            curves[1].astype(np.float64),
            boot_b[:, K:],
            boot_t[:, K:],
            perm[:, K:],
            alpha,
            binary,
        )
    return {"measures": out, "curves": curve, "resample_seconds": t_resample}


def compare_measures(
    x_baseline,
    x_treatment,
    key,
    *,
    resamples: int = 10_000,
    alpha: float = 0.05,
    higher_is_better: Mapping | None = None,
    chunk: int = 1000,
    perm_chunk: int = 1000,
) -> dict:
    """Compare per-seed measures of two methods (treatment − baseline).

    x_*: a 1-D array [seeds] or a dict {measure: 1-D array}, same measures for both.
    Returns {measure: results}; the first measure also gets the IQM of each method.
    """
    mb = _as_measures(x_baseline, "x_baseline")
    mt = _as_measures(x_treatment, "x_treatment")
    res = _analyse(
        mb,
        mt,
        key,
        resamples=resamples,
        alpha=alpha,
        chunk=chunk,
        perm_chunk=perm_chunk,
        higher_is_better=higher_is_better,
    )
    return res["measures"]


def _rate(p, alpha):
    k = int((np.asarray(p) <= alpha).sum())
    n = int(np.asarray(p).size)
    lo, hi = cf.wilson_ci(k, n) if n else (math.nan, math.nan)
    return {"rate": k / n if n else math.nan, "ci95": [lo, hi], "rejections": k, "splits": n}


def dispatch_calibration(key, n: int, splits: int, resamples: int):
    """Start drawing the calibration's random halves of n seeds: `splits` splits, then
    `resamples` reference relabellings, all uniform k-of-N subsets with N = 2·(n // 2)."""
    h = n // 2
    if h < 2:
        return lambda: None
    return dispatch_subsets(as_key(key), 2 * h, h, splits + resamples)


def calibrate(
    measures: dict,
    curves: np.ndarray | None,
    key,
    *,
    splits: int = 200,
    resamples: int = 200,
    alpha: float = 0.05,
    time_event=None,
    labels=None,
) -> dict:
    """False-positive rates of each test on random disjoint halves of one method's seeds.

    measures: {name: [n]} of a single method; curves [n, T] or None; time_event:
    (time, event) for the log-rank test. Each split is a uniform random half; the
    permutation reference set (`resamples` relabellings) is shared by all splits.
    labels: the waiter from `dispatch_calibration(key, n, splits, resamples)`, if
    already started (the draws then overlap other work).
    """
    names = list(measures)
    n = measures[names[0]].size
    h = n // 2
    if h < 2:
        return {"skipped": f"needs at least 4 baseline seeds, got {n}"}
    N = 2 * h
    x = np.stack([measures[k][:N] for k in names], 1)
    x = x - x.mean(0)
    M = len(names)
    z = [x, x**2]
    binary = True
    if curves is not None:
        c = np.asarray(curves[:N], np.float64)
        binary = is_binary(c)
        z.append(curve_columns(c, binary))
    z = np.concatenate(z, 1)
    if labels is None:
        labels = dispatch_calibration(key, n, splits, resamples)
    drawn = labels()  # [S + R, N]: the first S rows are the splits, the rest the reference
    masks = drawn[:splits]  # True = pseudo-treatment
    sums = drawn.astype(np.float64) @ z
    split_sums, ref_sums = sums[:splits], sums[splits:]
    tot = z.sum(0)

    def tstats(sums, cols, sq):
        ss_t = None if sq is None else sums[:, sq]
        ss_b = None if sq is None else tot[sq] - sums[:, sq]
        return welch_t_stat(h, tot[cols] - sums[:, cols], ss_b, h, sums[:, cols], ss_t)

    rates: dict = {"welch": {}, "permutation": {}, "brunner_munzel": {}}
    for j, name in enumerate(names):
        cols, sq = slice(j, j + 1), slice(M + j, M + j + 1)
        _, _, p_w = cf.welch_from_moments(
            h,
            tot[j] - split_sums[:, j],
            tot[M + j] - split_sums[:, M + j],
            h,
            split_sums[:, j],
            split_sums[:, M + j],
        )
        p_perm = _perm_p(tstats(split_sums, cols, sq)[:, 0], tstats(ref_sums, cols, sq))
        p_bm = cf.brunner_munzel_masks(x[:, j], masks, alpha)[3]
        rates["welch"][name] = _rate(p_w, alpha)
        rates["permutation"][name] = _rate(p_perm, alpha)
        rates["brunner_munzel"][name] = _rate(p_bm, alpha)
    if time_event is not None:
        tm, ev = time_event
        rates["logrank"] = {"first_success": _rate(cf.logrank_masks(tm[:N], ev[:N], masks)[1], alpha)}
    if curves is not None:
        T = curves.shape[1]
        cols = slice(2 * M, 2 * M + T)
        sq = None if binary else slice(2 * M + T, 2 * M + 2 * T)
        max_ref = np.abs(tstats(ref_sums, cols, sq)).max(1)
        max_split = np.abs(tstats(split_sums, cols, sq)).max(1)
        p_curve = (1 + (max_ref[None] >= max_split[:, None] * (1 - 1e-6)).sum(1)) / (max_ref.size + 1)
        rates["curve_maxT"] = {"any_trial": _rate(p_curve, alpha)}
    return {
        "description": "baseline against itself: random disjoint halves; the rate is the share of splits "
        "a test calls significant (expected: alpha)",
        "splits": splits,
        "resamples": resamples,
        "group_size": h,
        "alpha": alpha,
        "false_positive_rate": rates,
    }
