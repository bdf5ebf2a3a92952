"""Per-trial curves: simultaneous bands and family-wise trial-by-trial tests (SPEC §6).

* Each method's per-trial mean (success rate, or pins for bowling) gets a sup-t
  band that holds over all T trials at once: the (1 − α) quantile of the
  bootstrap max_t |r*_t − r_t| / se_t scales the pointwise SEs
  (Montiel Olea & Plagborg-Møller 2019). Same for the difference curve.
* Trials where the methods differ: single-step max-T permutation adjusted
  p-values of the per-trial Welch t (Westfall & Young 1993, Alg. 2.8), which
  control the family-wise error rate over all trials.
"""

from __future__ import annotations

import jax
import numpy as np

from jaxeac.bits import SuccessBits
from jaxeac.errors import UsageError
from jaxeac.rng import as_key
from jaxeac.stats._rng import host_rng
from jaxeac.stats.closed_form import mean_var, welch_t_stat
from jaxeac.stats.device_sums import covariance, curve_moments, gaussian_draws, gaussian_max_abs
from jaxeac.stats.resample import bootstrap_sums, perm_p, permutation_sums


def _sup_t(star, est, se, alpha):
    """Critical value of the sup-t band: quantile of max_t |star − est| / se over trials with se > 0."""
    ok = se > 0
    if not ok.any():
        return 0.0
    dev = np.abs(star[:, ok] - est[ok]) / se[ok]
    return float(np.quantile(dev.max(1), 1 - alpha))


def check_curves(curves_baseline, curves_treatment, trials: int | None = None):
    """Validate [n, T] curve arrays (same T, ≥ 2 seeds each) and return float64 copies."""
    cb = np.asarray(curves_baseline)
    ct = np.asarray(curves_treatment)
    for name, c in (("curves_baseline", cb), ("curves_treatment", ct)):
        if c.ndim != 2:
            raise UsageError(f"{name} must be 2-D [seeds, trials], got shape {c.shape}")
        if trials is not None and c.shape[1] != trials:
            hint = " (it looks transposed: pass [seeds, trials])" if c.shape[0] == trials else ""
            raise UsageError(f"{name} has {c.shape[1]} trials, expected {trials}{hint}")
        if c.shape[0] < 2:
            raise UsageError(f"{name} has {c.shape[0]} seed(s); at least 2 seeds per method are needed")
    if cb.shape[1] != ct.shape[1]:
        raise UsageError(
            f"baseline curves have {cb.shape[1]} trials but treatment curves {ct.shape[1]}; "
            "pass both as [seeds, trials] over the same trials"
        )
    return cb.astype(np.float64), ct.astype(np.float64)


def is_binary(*arrays) -> bool:
    """Whether every entry is 0 or 1 (O(N), no sort); `SuccessBits` are."""
    return all(isinstance(a, SuccessBits) or np.asarray(a).dtype == np.bool_
               or bool(((np.asarray(a) == 0) | (np.asarray(a) == 1)).all()) for a in arrays)


def curve_results(cb, ct, boot_b, boot_t, perm_t, alpha, binary: bool) -> dict:
    """Curve statistics from bootstrap and permutation column sums.

    boot_b, boot_t: [R, T(+T)] bootstrap sums of curves (and squares unless binary);
    perm_t: [P, T(+T)] treatment sums under permutation of the pooled seeds.
    """
    nb, nt, T = cb.shape[0], ct.shape[0], cb.shape[1]
    sums = [(c.sum(0), None if binary else (c**2).sum(0)) for c in (cb, ct)]
    (sb, ssb), (st, sst) = sums
    # max-T permutation over trials (Westfall & Young 1993)
    pt, pst = perm_t[..., :T], (None if binary else perm_t[..., T:])
    tot, tot2 = sb + st, (None if binary else ssb + sst)
    t_star = welch_t_stat(nb, tot - pt, None if binary else tot2 - pst, nt, pt, pst)
    stars = (boot_b[..., :T] / nb, boot_t[..., :T] / nt)
    return _summary(nb, nt, *sums, stars, True, np.abs(t_star).max(1), alpha, binary,
                    "bootstrap sup-t (Montiel Olea & Plagborg-Moller 2019)",
                    "single-step max-T permutation, FWER over trials (Westfall & Young 1993)")


def _summary(nb, nt, sums_b, sums_t, stars, about_means, max_star, alpha, binary, band_method,
             test_method) -> dict:
    """The curve results of both paths from each method's seeds, per-trial sums and sums of squares
    (None for 0/1 data), the draws of each method's mean curve (`stars`, baseline and treatment:
    resampled means `about_means`, else deviations about zero) that give the sup-t critical values,
    and the max-T reference draws."""
    (sb, ssb), (st, sst) = sums_b, sums_t
    mb, vb = mean_var(nb, sb, ssb)
    mt, vt = mean_var(nt, st, sst)
    seb, set_ = np.sqrt(vb / nb), np.sqrt(vt / nt)
    T = mb.size
    diff = mt - mb
    sed = np.sqrt(seb**2 + set_**2)
    star_b, star_t = stars
    eb, et = (mb, mt) if about_means else (np.zeros_like(mb), np.zeros_like(mt))
    cb_crit = _sup_t(star_b, eb, seb, alpha)
    ct_crit = _sup_t(star_t, et, set_, alpha)
    cd_crit = _sup_t(star_t - star_b, et - eb, sed, alpha)
    t_obs = welch_t_stat(nb, sb, ssb, nt, st, sst)
    p_adj = perm_p(t_obs, max_star[:, None])
    sig = p_adj <= alpha
    trial = np.arange(1, T + 1)
    sustained = None
    if sig[-1]:
        sign = np.sign(diff[-1])
        ok = sig & (np.sign(diff) == sign)
        k = T - 1
        while k > 0 and ok[k - 1]:
            k -= 1
        sustained = int(trial[k])
    with np.errstate(invalid="ignore"):  # a few seeds: max-T of trials without spread is inf (then NaN)
        maxt_critical = float(np.quantile(max_star, 1 - alpha))
    return {
        "trials": T,
        "kind": "success_rate" if binary else "mean",
        "mean_baseline": mb,
        "mean_treatment": mt,
        "band_baseline": [mb - cb_crit * seb, mb + cb_crit * seb],
        "band_treatment": [mt - ct_crit * set_, mt + ct_crit * set_],
        "diff": diff,
        "band_diff": [diff - cd_crit * sed, diff + cd_crit * sed],
        "sup_t_critical": {"baseline": cb_crit, "treatment": ct_crit, "diff": cd_crit},
        "band_method": band_method,
        "t_welch": t_obs,
        "p_maxT": p_adj,
        "maxT_critical": maxt_critical,
        "test_method": test_method,
        "significant_trials": trial[sig].tolist(),
        "first_significant_trial": int(trial[sig][0]) if sig.any() else None,
        "sustained_from_trial": sustained,
    }


def curve_results_large(mom_b: dict, mom_t: dict, keys, resamples: int, alpha: float, binary: bool) -> dict:
    """Curve statistics above `large.LARGE_N` seeds, from per-chunk moments (`curve_moments`).

    Means and SEs are exact; the sup-t critical values come from the Gaussian multiplier
    bootstrap N(0, Σ̂/n) per method (the diff band from the same draws, as the seed
    bootstrap does), the max-T reference from the normal limit N(0, R_pooled) of the
    permutation law (see `jaxeac.stats.large`). keys: (baseline, treatment, permutation).
    """
    from jaxeac.stats import large

    nb, nt = mom_b["n"], mom_t["n"]
    sums = [(m["s"], None if binary else np.diag(m["G"])) for m in (mom_b, mom_t)]
    k_b, k_t, k_p = (jax.random.fold_in(k, large.CURVE_STREAM) for k in keys)
    stars = (gaussian_draws(host_rng(k_b), covariance(mom_b) / nb, resamples),
             gaussian_draws(host_rng(k_t), covariance(mom_t) / nt, resamples))
    pooled = {"n": nb + nt, "s": mom_b["s"] + mom_t["s"], "G": mom_b["G"] + mom_t["G"]}
    max_star = gaussian_max_abs(host_rng(k_p), covariance(pooled), resamples)
    return _summary(nb, nt, *sums, stars, False, max_star, alpha, binary, large.REFERENCES["sup_t_gaussian"],
                    large.REFERENCES["max_t_gaussian"])


def curve_columns(c, binary):
    return c if binary else np.concatenate([c, c**2], 1)


def curve_bands(
    curves_baseline,
    curves_treatment,
    key,
    *,
    resamples: int = 10_000,
    alpha: float = 0.05,
    chunk: int = 1000,
    trials: int | None = None,
) -> dict:
    """Per-trial means of two methods with simultaneous (whole-curve) bands and max-T tests.

    curves_*: [seeds, T] (bool success per trial, or pins per trial). Returns a dict
    (see `curve_results`); `band_*` are [lower, upper] arrays that hold over all
    trials jointly with probability 1 − α.
    """
    from jaxeac.stats import large

    kb, kt, kp = jax.random.split(as_key(key), 3)
    raw_b, raw_t = np.asarray(curves_baseline), np.asarray(curves_treatment)
    if raw_b.ndim == 2 and raw_t.ndim == 2 and large.is_large(raw_b.shape[0], raw_t.shape[0]):
        check_curves(raw_b[:2], raw_t[:2], trials)
        binary = is_binary(raw_b, raw_t)
        mom_b, mom_t = curve_moments(raw_b), curve_moments(raw_t)
        return curve_results_large(mom_b(), mom_t(), (kb, kt, kp), resamples, alpha, binary)
    cb, ct = check_curves(curves_baseline, curves_treatment, trials)
    binary = is_binary(cb, ct)
    zb, zt = curve_columns(cb, binary), curve_columns(ct, binary)
    bb, _ = bootstrap_sums(kb, zb, resamples, chunk=chunk)
    bt, _ = bootstrap_sums(kt, zt, resamples, chunk=chunk)
    pt = permutation_sums(kp, np.concatenate([zb, zt]), ct.shape[0], resamples)
    return curve_results(cb, ct, bb, bt, pt, alpha, binary)
