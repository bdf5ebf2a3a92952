"""AC-versus-EAC comparison of per-seed measures and curves (SPEC §6).

The seed is the unit of analysis. One bootstrap draw per method and one set of
permutations of the pooled seeds serve every measure and the curves at once
(see `resample`); everything else is closed-form on the host. Each measure gets
the difference of means with a BCa CI (Efron 1987), Welch's t-test (Welch
1947) checked by a studentised permutation test (Janssen 1997), Brunner–Munzel
(Brunner & Munzel 2000), Hedges' g with a BCa CI, A12 with the Brunner–Munzel
CI, and the seeds needed for 80 % power. Holm (1979) adjusts the declared
family of measures. The AC-versus-AC calibration is `jaxeac.stats.calibration`.

Which path a measure's resampling takes is `large.resampling_path`'s one rule: above
`large.LARGE_N` seeds per method the same results come from `_analyse_large`: the engine's
groups (`jaxeac.stats.groups`, counts per distinct value, exact) where a measure takes few
values, and named asymptotically exact methods elsewhere; see `jaxeac.stats.large` for which,
why and the references.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor

import jax
import numpy as np

from jaxeac.errors import UsageError
from jaxeac.rng import as_key
from jaxeac.stats import closed_form as cf
from jaxeac.stats import large
from jaxeac.stats._rng import host_rng, hypergeometric_counts
from jaxeac.stats.asymptotic import abc_intervals, normal_permutation_p
from jaxeac.stats.bca import bca_two_sample_counts
from jaxeac.stats.closed_form import welch_t_stat
from jaxeac.stats.curves import curve_columns, curve_results, curve_results_large, is_binary
from jaxeac.stats.device_sums import curve_moments
from jaxeac.stats.groups import Group, two_sample_ci
from jaxeac.stats.measures import as_values, fill_values
from jaxeac.stats.resample import (
    dispatch_bootstrap,
    dispatch_permutation,
    permutation_sums,
    permutation_welch_p,
)

POWER_DS = (0.2, 0.5, 0.8)
STATISTICS = ("mean_diff", "hedges_g")  # with a BCa (or ABC) interval


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
    xc, yc = x - c, y - c
    t_obs = float(welch_t_stat(x.size, xc.sum(), (xc**2).sum(), y.size, yc.sum(), (yc**2).sum()))
    if large.is_large(x.size, y.size):
        k_p = jax.random.split(as_key(key), 3)[2]
        return cf.TestResult(t_obs, _permutation_large(large.ValueTable(x, y), t_obs, c, k_p, resamples))
    z = np.stack([np.r_[xc, yc], np.r_[xc, yc] ** 2], 1)
    pt = permutation_sums(as_key(key), z, y.size, resamples, chunk=chunk)
    tot = z.sum(0)
    return cf.TestResult(t_obs, permutation_welch_p(x.size, y.size, t_obs, *tot[:2], pt[:, 0], pt[:, 1]))


def _permutation_large(table: large.ValueTable, t_obs: float, centre: float, key, resamples: int) -> float:
    """The permutation p above `large.LARGE_N` seeds: multivariate hypergeometric relabellings per
    distinct value (exact) where the values are few, else its normal limit (`jaxeac.stats.large`)."""
    if not table.exact:
        return float(normal_permutation_p(t_obs))
    v, pooled = table.values - centre, table.kb + table.kt
    h = hypergeometric_counts(host_rng(key), pooled, table.nt, resamples)
    tot = (pooled @ v, pooled @ (v * v))
    return permutation_welch_p(table.nb, table.nt, t_obs, *tot, *large.moment_sums(h, v))


def _row(name, hib, nb, nt, means, moments, ranks, alpha) -> dict:
    """One measure's result, the same dictionary on both paths: `means` (mean and sd of each
    method), `moments` (Σx, Σx², Σy, Σy² of the centred values), `ranks` (A12, Brunner–Munzel
    W, df, p and A12's interval); the resampled intervals and p are filled in later."""
    mean_b, mean_t, sd_b, sd_t = means
    sx, sxx, sy, syy = moments
    t, df, p = cf.welch_from_moments(nb, sx, sxx, nt, sy, syy)
    g = float(cf.hedges_from_moments(nb, sx, sxx, nt, sy, syy))
    a, w, bm_df, bm_p, a_lo, a_hi = ranks
    power = {"observed_d": abs(g), "seeds_for_80pct_power": cf.seeds_for_power(g, 0.8, alpha),
             **{f"d={d}": cf.seeds_for_power(d, 0.8, alpha) for d in POWER_DS}}
    return {
        "measure": name,
        "higher_is_better": hib,
        "n_baseline": nb,
        "n_treatment": nt,
        "mean_baseline": float(mean_b),
        "mean_treatment": float(mean_t),
        "sd_baseline": float(sd_b),
        "sd_treatment": float(sd_t),
        "diff": float(mean_t - mean_b),
        "diff_ci95": None,
        "t_welch": float(t),
        "df_welch": float(df),
        "p_welch": float(p),
        "p_permutation": None,
        "hedges_g": g,
        "hedges_g_ci95": None,
        "brunner_munzel": {"statistic": w, "df": bm_df, "p": bm_p},
        "a12": a,
        "a12_ci95": [a_lo, a_hi],
        "prob_improvement": a if hib else 1 - a,
        "prob_improvement_ci95": [a_lo, a_hi] if hib else [1 - a_hi, 1 - a_lo],
        "seeds_for_80pct_power": power["seeds_for_80pct_power"],
        "power": power,
    }


def _resampled(fields: dict, diff, g, p: float) -> None:
    """A measure's resampled results into its `_row`, the same on both paths."""
    fields |= {"diff_ci95": [diff.low, diff.high], "hedges_g_ci95": [g.low, g.high], "p_permutation": p}


def _iqm(fields: dict, side: str, est: float, lo: float, hi: float) -> None:
    fields |= {f"iqm_{side}": est, f"iqm_{side}_ci95": [lo, hi]}


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
    moments=None,
) -> dict:
    """Measures (and optionally curves) from one shared bootstrap and permutation draw.
    `moments`: above `large.LARGE_N`, the curves' `curve_moments` if already dispatched."""
    names = list(mb)
    if list(mt) != names:
        raise UsageError(
            f"baseline measures {names} and treatment measures {list(mt)} differ; "
            "pass the same measures for both"
        )
    nb, nt = mb[names[0]].size, mt[names[0]].size
    if large.is_large(nb, nt):
        return _analyse_large(mb, mt, key, curves=curves, resamples=resamples, alpha=alpha,
                              higher_is_better=higher_is_better, moments=moments)
    mb, mt = ({k: as_values(v) for k, v in m.items()} for m in (mb, mt))
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
    t_dispatch = time.perf_counter() - t0
    # closed-form parts on the host while XLA draws the resamples
    out = {}
    for j, name in enumerate(names):
        x, y = xb[:, j], xt[:, j]
        hib = True if higher_is_better is None else bool(higher_is_better.get(name, True))
        pooled = np.concatenate([x, y])
        mask = np.r_[np.zeros(nb, bool), np.ones(nt, bool)][None]
        ranks = [float(v[0]) for v in cf.brunner_munzel_masks(pooled, mask, alpha)]
        means = (mb[name].mean(), mt[name].mean(), mb[name].std(ddof=1), mt[name].std(ddof=1))
        sums = (x.sum(), (x**2).sum(), y.sum(), (y**2).sum())
        out[name] = _row(name, hib, nb, nt, means, sums, ranks, alpha)
    t_closed = time.perf_counter()
    (boot_b, iqm_b), (boot_t, iqm_t), perm = wait_b(), wait_t(), wait_p()
    t_resample = time.perf_counter() - t0
    t_wait = time.perf_counter() - t_closed
    t_closed = t_closed - t0 - t_dispatch
    t1 = time.perf_counter()
    tot = zb.sum(0) + zt.sum(0)
    one_b, one_t = np.ones(nb), np.ones(nt)  # units one by one
    for j, name in enumerate(names):
        x, y = xb[:, j], xt[:, j]
        boot = (boot_b[:, j], boot_b[:, M + j], boot_t[:, j], boot_t[:, M + j])
        diff, g = (bca_two_sample_counts(s, x, one_b, y, one_t, *boot, alpha) for s in STATISTICS)
        t_obs = welch_t_stat(nb, x.sum(), (x**2).sum(), nt, y.sum(), (y**2).sum())
        p = permutation_welch_p(nb, nt, t_obs, tot[j], tot[M + j], perm[:, j], perm[:, M + j])
        _resampled(out[name], diff, g, p)
    # IQM per method of the first (primary) measure
    for side, x, q in (("baseline", xb[:, 0], iqm_b), ("treatment", xt[:, 0], iqm_t)):
        est = cf.iqm_sorted(np.sort(x))
        lo, hi = large.iqm_interval(est, large.RAW, alpha, x=x, star=q)
        _iqm(out[names[0]], side, est + centre[0], lo + centre[0], hi + centre[0])
    t_bca = time.perf_counter() - t1
    t1 = time.perf_counter()
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
    pieces = {
        "dispatch_resampling": t_dispatch,
        "closed_form_and_ranks": t_closed,
        "resampling_wait": t_wait,
        "bca_iqm_and_permutation_p": t_bca,
        "curve_bands_and_maxT": time.perf_counter() - t1,
    }
    return {"measures": out, "curves": curve, "resample_seconds": t_resample, "pieces": pieces}


def _iqm_normal(z: np.ndarray, centre: float, alpha: float) -> tuple[float, float, float]:
    """The IQM of the raw values z + centre and its interval on the bootstrap's normal limit."""
    est = cf.iqm_sorted(np.sort(z))
    lo, hi = large.iqm_interval(est, large.ASYMPTOTIC, alpha, x=z)
    return est + centre, lo + centre, hi + centre


def _analyse_large(
    mb: dict, mt: dict, key, *, curves, resamples: int, alpha: float, higher_is_better, moments=None
) -> dict:
    """`_analyse` above `large.LARGE_N` seeds per method: same results dict, scalable methods.
    `moments`: the curves' `curve_moments` waiters, if already dispatched."""
    names = list(mb)
    nb, nt = mb[names[0]].size, mt[names[0]].size
    k_b, k_t, k_p = jax.random.split(as_key(key), 3)
    pieces: dict = {}
    t0 = time.perf_counter()
    binary = None
    if curves is not None:  # per-chunk sums on the device while the host does the measures
        binary = is_binary(*curves)
        moments = moments or [curve_moments(c) for c in curves]
    pieces["dispatch_curve_sums"] = time.perf_counter() - t0
    def one(j: int, name: str):  # a measure's closed forms and resampling (on a host thread)
        with large.HOST_BUDGET.hold(large.job_bytes(nb, nt)):
            t1 = time.perf_counter()
            pooled = np.empty(nb + nt)  # both methods' values, then less their mean, in place
            xr, yr = fill_values(mb[name], pooled[:nb]), fill_values(mt[name], pooled[nb:])
            c = pooled.mean()
            hib = True if higher_is_better is None else bool(higher_is_better.get(name, True))
            means = (xr.mean(), yr.mean(), xr.std(ddof=1), yr.std(ddof=1))
            table = large.ValueTable(mb[name], mt[name])
            pooled -= c
            t2 = time.perf_counter()
            keys = [jax.random.fold_in(k, j) for k in (k_b, k_t, k_p)]
            sums = (xr.sum(), (xr**2).sum(), yr.sum(), (yr**2).sum())
            t_obs = float(welch_t_stat(nb, *sums[:2], nt, *sums[2:]))
            p = _permutation_large(table, t_obs, c, keys[2], resamples)
            path = large.path_above(table.distinct)  # the one rule (`large.resampling_path`)
            if path == large.PER_VALUE:  # the engine's groups: counts per distinct value, exact
                groups = [Group(None, k, resamples, counted=(table.values[kk > 0], kk[kk > 0]))
                          for k, kk in ((keys[0], table.kb), (keys[1], table.kt))]
                diff, g = (two_sample_ci(stat, *groups, alpha) for stat in STATISTICS)
                iqm = [grp.iqm(alpha) for grp in groups] if j == 0 else None
                methods = {"bootstrap": "bootstrap_per_value", "permutation": "permutation_per_value"}
            else:
                diff, g = abc_intervals(STATISTICS, xr, yr, alpha).values()
                iqm = [_iqm_normal(z, c, alpha) for z in (xr, yr)] if j == 0 else None
                methods = {"bootstrap": "abc", "permutation": "normal_permutation"}
                methods |= {"iqm": "normal_bca"} if j == 0 else {}
            del pooled, xr, yr
            t3 = time.perf_counter()
        ranks = [float(v[0]) for v in cf.brunner_munzel_counts(table.kb, table.kt, alpha)]
        fields = _row(name, hib, nb, nt, means, sums, ranks, alpha)
        _resampled(fields, diff, g, p)
        for side, res in zip(("baseline", "treatment"), iqm or (), strict=False):
            _iqm(fields, side, *res)
        record = {"distinct_values": table.distinct, "path": path,
                  **{k: large.REFERENCES[v] for k, v in methods.items()}}
        return fields, record, t2 - t1, t3 - t2

    # the measures side by side while their temporaries fit `large.HOST_BUDGET`: NumPy's samplers
    # and array work free the GIL, and each measure draws from its own keys, so the results do
    # not depend on the threads
    with ThreadPoolExecutor(max_workers=len(names)) as pool:
        done = list(pool.map(one, range(len(names)), names))
    out, scale = {}, {}
    for name, (fields, methods, closed, resampled) in zip(names, done, strict=True):
        out[name], scale[name] = fields, methods
        pieces[f"closed_form_and_ranks[{name}]"] = closed
        pieces[f"resampling[{name}]"] = resampled
    curve = None
    if curves is not None:
        t1 = time.perf_counter()
        mom = [m() for m in moments]
        pieces["curve_sums_wait"] = time.perf_counter() - t1
        t1 = time.perf_counter()
        curve = curve_results_large(mom[0], mom[1], (k_b, k_t, k_p), resamples, alpha, binary)
        pieces["curve_bands_and_maxT"] = time.perf_counter() - t1
    return {
        "measures": out,
        "curves": curve,
        "resample_seconds": time.perf_counter() - t0,
        "pieces": pieces,
        "scale": scale,
    }


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
    return cf.level_keys(res["measures"], round(1 - alpha, 12))


