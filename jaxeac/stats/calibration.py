"""The AC-versus-AC calibration (SPEC §6, "calibration"): each test's false-positive rate on
random disjoint halves of one method's seeds, which must sit at α.

Below `large.LARGE_N` seeds the halves are uniform random subsets drawn on the device
(`resample.dispatch_subsets`); above it (`_calibrate_large`) each measure's halves are
multivariate hypergeometric counts per distinct value and the curves' halves exact random
halves of the seeds (`jaxeac.stats.device_sums`), the path `large.resampling_path` picks.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor

import jax
import numpy as np

from jaxeac.bits import SuccessBits
from jaxeac.rng import as_key
from jaxeac.stats import closed_form as cf
from jaxeac.stats import large
from jaxeac.stats._rng import host_rng, hypergeometric_counts
from jaxeac.stats.asymptotic import normal_permutation_p
from jaxeac.stats.closed_form import welch_t_stat
from jaxeac.stats.curves import curve_columns, is_binary
from jaxeac.stats.device_sums import covariance, curve_moments, dispatch_subset_sums, gaussian_max_abs
from jaxeac.stats.events import logrank_counts, logrank_masks, wilson_ci
from jaxeac.stats.measures import Coded, as_values, event_counts, value_counts
from jaxeac.stats.resample import dispatch_subsets, perm_p


def _rate(p, alpha):
    k = int((np.asarray(p) <= alpha).sum())
    n = int(np.asarray(p).size)
    lo, hi = wilson_ci(k, n, alpha) if n else (math.nan, math.nan)
    return {"rate": k / n if n else math.nan, "ci95": [lo, hi], "rejections": k, "splits": n}


def _measure_rates(rates: dict, name: str, pvalues, alpha) -> None:
    """A measure's rates of its Welch, permutation and Brunner–Munzel tests (p of each split)."""
    for test, p in zip(("welch", "permutation", "brunner_munzel"), pvalues, strict=True):
        rates.setdefault(test, {})[name] = _rate(p, alpha)


def dispatch_calibration(key, n: int, splits: int, resamples: int):
    """Start drawing the calibration's random halves of n seeds: `splits` splits, then
    `resamples` reference relabellings, all uniform k-of-N subsets with N = 2·(n // 2)."""
    h = n // 2
    if h < 2 or large.is_large(n):  # the large-N calibration draws per value (see `calibrate`)
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
    moments=None,
) -> dict:
    """False-positive rates of each test on random disjoint halves of one method's seeds.

    measures: {name: [n] or `Coded`} of a single method; curves [n, T] or None; time_event:
    (time, event) for the log-rank test (time: integers or `Coded`). Each split is a uniform random half; the
    permutation reference set (`resamples` relabellings) is shared by all splits.
    labels: the waiter from `dispatch_calibration(key, n, splits, resamples)`, if
    already started (the draws then overlap other work). Above `large.LARGE_N` seeds
    the halves are drawn per distinct value (measures) and per block of seeds (curves),
    see `_calibrate_large`; moments: the curves' `curve_moments` (the dict, or the function
    that waits for it), if at hand.
    """
    names = list(measures)
    n = measures[names[0]].size
    h = n // 2
    if h < 2:
        return {"skipped": f"needs at least 4 baseline seeds, got {n}"}
    if large.is_large(n):
        return _calibrate_large(
            measures,
            curves,
            key,
            splits=splits,
            resamples=resamples,
            alpha=alpha,
            time_event=time_event,
            moments=moments,
        )
    N = 2 * h
    measures = {k: as_values(v) for k, v in measures.items()}
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

    rates: dict = {}
    for j, name in enumerate(names):
        a1, a2 = split_sums[:, j], split_sums[:, M + j]
        t_split, _, p_w = cf.welch_from_moments(h, tot[j] - a1, tot[M + j] - a2, h, a1, a2)
        p_perm = perm_p(t_split, tstats(ref_sums, slice(j, j + 1), slice(M + j, M + j + 1)))
        _measure_rates(rates, name, (p_w, p_perm, cf.brunner_munzel_masks(x[:, j], masks, alpha)[3]), alpha)
    if time_event is not None:
        tm, ev = time_event
        tm = tm.codes.astype(np.int64) if isinstance(tm, Coded) else tm
        rates["logrank"] = {"first_success": _rate(logrank_masks(tm[:N], ev[:N], masks)[1], alpha)}
    if curves is not None:
        T = curves.shape[1]
        cols = slice(2 * M, 2 * M + T)
        sq = None if binary else slice(2 * M + T, 2 * M + 2 * T)
        max_ref = np.abs(tstats(ref_sums, cols, sq)).max(1)
        max_split = np.abs(tstats(split_sums, cols, sq)).max(1)
        rates["curve_maxT"] = {"any_trial": _rate(perm_p(max_split, max_ref[:, None]), alpha)}
    return _calibration_record(splits, resamples, h, alpha, rates)


def _calibration_record(splits, resamples, h, alpha, rates, **extra) -> dict:
    return {
        "description": "baseline against itself: random disjoint halves; the rate is the share of splits "
        "a test calls significant (expected: alpha)",
        "splits": splits,
        "resamples": resamples,
        "group_size": h,
        "alpha": alpha,
        "false_positive_rate": rates,
        **extra,
    }


def _calibrate_large(measures, curves, key, *, splits, resamples, alpha, time_event, moments) -> dict:
    """`calibrate` above `large.LARGE_N` seeds.

    Measure j: each random half is a multivariate hypergeometric count per distinct value
    under fold_in(key, j) (exact); the permutation reference is `resamples` more such halves
    where the main comparison resamples that measure exactly, else the test's normal limit.
    Log-rank: counts per (time, event) under fold_in(key, M). Curves: exact random halves of
    the seeds drawn on the device under fold_in(key, CURVE_STREAM); the max-T reference is
    the Gaussian limit used by the main comparison (draws under fold_in(key, CURVE_STREAM + 1)).
    """
    key = as_key(key)
    names = list(measures)
    n = measures[names[0]].size
    h = n // 2
    N = 2 * h
    M = len(names)
    means = large.stacked_means([measures[k] for k in names], N)  # the first N seeds' means
    wait_curve = None
    if curves is not None:
        packed = isinstance(curves, SuccessBits)
        c = SuccessBits(curves.bits[:N], curves.trials) if packed else np.asarray(curves)[:N]
        binary = is_binary(c)
        cols = c if binary else np.concatenate([c, c * c], 1)
        wait_curve = dispatch_subset_sums(jax.random.fold_in(key, large.CURVE_STREAM), cols, h, splits)
    rates, methods = {}, {}

    def one(j: int):  # a measure's halves and tests (on a host thread; its own key)
        raw, counts = value_counts(measures[names[j]], N)
        vals, inv = np.unique(raw - means[j], return_inverse=True)  # the centred values of the seeds
        K = np.bincount(inv.reshape(-1), weights=counts, minlength=vals.size).astype(np.int64)
        exact = large.path_above(vals.size) == large.PER_VALUE  # the one rule
        rng = host_rng(jax.random.fold_in(key, j))
        H = hypergeometric_counts(rng, K, h, splits + (resamples if exact else 0))
        s1, s2 = large.moment_sums(H, vals)
        tot1, tot2 = K @ vals, K @ (vals * vals)
        a1, a2 = s1[:splits], s2[:splits]
        t_split, _, p_w = cf.welch_from_moments(h, tot1 - a1, tot2 - a2, h, a1, a2)
        if exact:
            r1, r2 = s1[splits:], s2[splits:]
            p_perm = perm_p(t_split, welch_t_stat(h, tot1 - r1, tot2 - r2, h, r1, r2)[:, None])
        else:
            p_perm = normal_permutation_p(t_split)
        p_bm = cf.brunner_munzel_counts(K - H[:splits], H[:splits], alpha)[3]
        return p_w, p_perm, p_bm, {
            "distinct_values": int(vals.size),
            "path": large.path_above(vals.size),
            "permutation": large.REFERENCES["permutation_per_value" if exact else "normal_permutation"],
        }

    with ThreadPoolExecutor(max_workers=M) as pool:
        done = list(pool.map(one, range(M)))
    for name, (*pvalues, method) in zip(names, done, strict=True):
        _measure_rates(rates, name, pvalues, alpha)
        methods[name] = method
    if time_event is not None:
        _, K = event_counts(*time_event, N)
        H = hypergeometric_counts(host_rng(jax.random.fold_in(key, M)), K, h, splits)
        p_lr = logrank_counts(K, H)[1]
        rates["logrank"] = {"first_success": _rate(p_lr, alpha)}
    if curves is not None:
        T = c.shape[1]
        treat = wait_curve()
        tot = cols.column_sums() if packed else cols.sum(0, dtype=np.float64)
        sq = None if binary else slice(T, 2 * T)

        def part(a, s):
            return None if s is None else a[..., s]

        base = tot - treat
        t_split = welch_t_stat(h, base[:, :T], part(base, sq), h, treat[:, :T], part(treat, sq))
        max_split = np.abs(t_split).max(1)
        mom = moments() if callable(moments) else moments
        if mom is None or mom["n"] != N:
            if mom is not None and mom["n"] == N + 1:  # drop the odd seed out
                last = (curves.rows(N, N + 1)[0] if packed else np.asarray(curves)[N]).astype(np.float64)
                mom = {"n": N, "s": mom["s"] - last, "G": mom["G"] - np.outer(last, last)}
            else:
                mom = curve_moments(c)()
        rng = host_rng(jax.random.fold_in(key, large.CURVE_STREAM + 1))
        max_ref = gaussian_max_abs(rng, covariance(mom), resamples)
        rates["curve_maxT"] = {"any_trial": _rate(perm_p(max_split, max_ref[:, None]), alpha)}
        methods["curve_maxT"] = large.REFERENCES["max_t_gaussian"]
    return _calibration_record(
        splits, resamples, h, alpha, rates,
        large_n={
            "threshold": large.LARGE_N,
            "halves": "measures: multivariate hypergeometric counts per distinct value; curves: exact "
            "random halves of the seeds (selection sampling on the device)",
            "methods": methods,
        },
    )
