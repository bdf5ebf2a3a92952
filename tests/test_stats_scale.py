"""Statistics at scale (SPEC §6): results at 10^4 seeds pinned, the large-N path against exact references.

The pinned results (tests/data/stats_scale_10k_pinned.json; their digests, `PINNED_DIGESTS`,
were pinned with the statistics as they were before the large-N path, `jaxeac.stats.large`,
was added: build 332415e plus the working tree of that day) were computed on the 2-core CPU.
Keys added to the output since then are listed in `ADDED_KEYS` and left out. Every number that
no resampling gives (point estimates, closed-form p-values, counts, effect sizes, n) must stay
the same (`assert_as_pinned`); resampled ones (interval endpoints, Monte-Carlo p-values,
critical values) moved once, by the tie fix: the bootstrap and permutation replicates are kept
in float64 (sums on the host from the device's exact counts) instead of float32 device sums.
Regenerate only for a deliberate, documented change: ``python tests/test_stats_scale.py``.

The large-N checks run at 2·10^5 seeds per method (curves: just above `LARGE_N`),
each against a slow exact reference on the same data with a tolerance from the
Monte Carlo error: drawing seeds (bootstrap) and relabelling seeds (permutation)
directly, scipy's Brunner–Munzel and statsmodels' log-rank, BCa of an exact
bootstrap (for ABC), exact permutations (for the normal-limit p), the seed
bootstrap and label permutation of the small-N path (for the Gaussian curve laws).
"""

from __future__ import annotations

import hashlib
import json
import re
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

from jaxeac.bits import SuccessBits
from jaxeac.io import to_jsonable
from jaxeac.stats import bca_ci, compare_experiment, curve_bands, iqm_ci, permutation_test

#: Output keys that did not exist when the pins were taken (dotted paths).
ADDED_KEYS: tuple[str, ...] = ("settings.scale", "analysis", "paired")
#: Run-dependent keys, never pinned.
UNPINNED = ("timing", "versions")


def synthetic(n: int, trials: int = 200, seed: int = 2024):
    """AC- and EAC-like success curves [n, trials]: Bernoulli with rising per-trial rates."""
    rng = np.random.default_rng(seed)
    t = np.arange(1, trials + 1)
    out = []
    for shift in (0.0, 0.15):
        ability = rng.normal(0.0, 0.6, (n, 1))
        logit = -1.2 + 2.4 * t / trials + shift + ability
        out.append(rng.random((n, trials)) < 1 / (1 + np.exp(-logit)))
    return out


def synthetic_bowling(n: int, trials: int = 10, seed: int = 7):
    rng = np.random.default_rng(seed)
    out = []
    for shift in (0.0, 0.1):
        s = rng.random((n, trials)) < np.linspace(0.1, 0.5, trials) + shift
        out.append((s, np.where(s, 10, rng.integers(0, 10, (n, trials)))))
    return out


def _strip(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        path = f"{prefix}{k}"
        if path in ADDED_KEYS or (not prefix and k in UNPINNED):
            continue
        out[k] = _strip(v, path + ".") if isinstance(v, dict) else v
    return out


def digest(obj) -> str:
    text = json.dumps(to_jsonable(obj), sort_keys=True, allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def grid_10k():
    sb, st = synthetic(10_000)
    stats, _ = compare_experiment(sb, st, key=7)
    return _strip(stats)


def bowling_10k():
    (sb, rb), (st, rt) = synthetic_bowling(10_000)
    stats, _ = compare_experiment(
        sb,
        st,
        returns_baseline=rb,
        returns_treatment=rt,
        experiment="bowling",
        key=11,
        resamples=2000,
        calibration_splits=100,
        calibration_resamples=99,
    )
    return _strip(stats)


def api_10k():
    sb, st = synthetic(10_000, trials=50, seed=5)
    x, y = sb.sum(1).astype(float), st.sum(1).astype(float)
    return {
        "bca_mean_diff": bca_ci(x, y, 3, resamples=2000),
        "bca_hedges_g": bca_ci(x, y, 4, statistic="hedges_g", resamples=2000),
        "iqm": iqm_ci(y, 5, resamples=2000),
        "permutation": permutation_test(x, y, 6, resamples=2000),
        "curves": curve_bands(sb, st, 8, resamples=2000),
    }


def _jsonable_api(r: dict) -> dict:
    return {k: (v.__dict__ if hasattr(v, "__dict__") else v) for k, v in r.items()}


#: The digests of the pinned results as they were pinned (before replicates were kept in float64).
PINNED_DIGESTS = {"grid_10k": "02408b4eedfaa5f1", "bowling_10k": "fdc2a9b3653e2847",
                  "api_10k": "cdbbb918bd1ccc26"}
PINNED_FILE = Path(__file__).parent / "data" / "stats_scale_10k_pinned.json"
#: Numbers that come from resampling: interval endpoints and bands, Monte-Carlo p-values and
#: critical values (a path matching this, by its last key).
RESAMPLED = re.compile(r"(_ci(95)?|^ci(95)?|^band_\w+|^low|^high|critical|^p_permutation(_holm)?|^p_maxT)$")
#: The tie fix moves a resampled interval endpoint by at most this share of its interval's width
#: (measured: 0.38 %, the bowling late-success-rate difference; 8.9e-4 of the endpoint at most).
#: Differences of means of integer measures lie on a lattice; in float32 sums their replicates
#: carried rounding noise of ~3e-7, so replicates equal to the estimate fell above or below it at
#: random, while in float64 they are counted as ties (one half each), which moves BCa's bias
#: correction, and so its quantile levels, by a few of the 10,000 order statistics.
TIE_FIX_WIDTH = 0.005
#: A Monte-Carlo permutation p moves by at most this (measured: 10 of 10,001 relabellings, 1.0e-3,
#: first success of a 10,000-seed grid run): relabellings whose |t| equals the observed one on
#: integer data were counted as ties (|t*| ≥ |t|) or not at random under float32 sums' errors
#: of up to 1e-5 relative; in float64 they differ from it by 1e-13 and all count.
P_TIES = 2e-3
#: Elsewhere resampled numbers stay within this relative change (float32 versus float64 sums).
RESAMPLED_REL = 1e-6
#: Every number no resampling gives stays within this relative change (in fact identical).
EXACT_REL = 1e-12


def pinned_leaves(old, new, path="", skip=lambda path, key: False):
    """(path, old value, new value, width of the interval it ends or None) of every leaf of `old`
    (a result as pinned) and the same place in `new`; keys ending ``_ci95``/``ci95`` may be named
    without ``95`` in `new` (the level-neutral names). A key of `old` missing in `new` fails."""
    if isinstance(old, dict):
        for k, v in old.items():
            if skip(path, k):
                continue
            nk = k if k in new else (k[:-2] if k.endswith("_ci95") or k == "ci95" else k)
            assert nk in new, f"{path}/{k} is gone"
            if isinstance(v, dict) and all(isinstance(v.get(e), float) for e in ("low", "high")):
                width = abs(v["high"] - v["low"])
                for e in ("low", "high"):
                    yield f"{path}/{nk}/{e}", v[e], new[nk][e], width
                yield from pinned_leaves({e: x for e, x in v.items() if e not in ("low", "high")}, new[nk],
                                         f"{path}/{nk}", skip)
                continue
            yield from pinned_leaves(v, new[nk], f"{path}/{nk}", skip)
    elif isinstance(old, list):
        assert isinstance(new, list) and len(old) == len(new), path
        pair = len(old) == 2 and all(isinstance(v, float) for v in old)
        for i, (u, v) in enumerate(zip(old, new, strict=True)):
            if pair:
                yield f"{path}[{i}]", u, v, abs(old[1] - old[0])
            else:
                yield from pinned_leaves(u, v, f"{path}[{i}]", skip)
    else:
        yield path, old, new, None


def assert_number_as_pinned(path: str, a, b, width) -> float:
    """One number of a result as pinned (`a`) and now (`b`): non-resampled within `EXACT_REL`;
    resampled (`RESAMPLED`, by its last key) within `RESAMPLED_REL`, or an interval endpoint within
    `TIE_FIX_WIDTH` of its interval's `width`, or a permutation p within `P_TIES`. Returns the
    share of the width moved (0 where none)."""
    if not (isinstance(a, float) and isinstance(b, float)) or a == b or (a != a and b != b):
        assert a == b or (a != a and b != b), path
        return 0.0
    last = re.sub(r"\[\d+\]$", "", path).rsplit("/", 1)[-1]
    if not RESAMPLED.search(last):
        assert b == pytest.approx(a, rel=EXACT_REL, abs=1e-15), f"{path}: {a} -> {b}"
    elif b != pytest.approx(a, rel=RESAMPLED_REL):
        if last.startswith("p_"):
            assert abs(b - a) <= P_TIES, f"{path}: {a} -> {b}"
            return 0.0
        assert width and abs(b - a) <= TIE_FIX_WIDTH * width, f"{path}: {a} -> {b} (interval width {width})"
        return abs(b - a) / width
    return 0.0


def assert_as_pinned(old, new, skip=lambda path, key: False) -> float:
    """`new` has every number of `old` (a result as pinned), each as `assert_number_as_pinned`
    says. Returns the largest share of an interval's width moved."""
    return max([assert_number_as_pinned(*leaf) for leaf in pinned_leaves(old, new, "", skip)] or [0.0])


def _pinned(name: str) -> dict:
    return json.loads(PINNED_FILE.read_text())[name]


cpu_only = pytest.mark.skipif(
    jax.default_backend() != "cpu", reason="pinned on the CPU; GPU float32 sums round differently"
)


@cpu_only
def test_pinned_file_is_what_was_pinned():
    for name, want in PINNED_DIGESTS.items():
        assert digest(_pinned(name)) == want, name


@cpu_only
def test_grid_10k_as_pinned():
    assert assert_as_pinned(_pinned("grid_10k"), to_jsonable(grid_10k())) <= TIE_FIX_WIDTH


@cpu_only
def test_bowling_10k_as_pinned():
    assert assert_as_pinned(_pinned("bowling_10k"), to_jsonable(bowling_10k())) <= TIE_FIX_WIDTH


@cpu_only
def test_api_10k_as_pinned():
    assert assert_as_pinned(_pinned("api_10k"), to_jsonable(_jsonable_api(api_10k()))) <= TIE_FIX_WIDTH


# ------------------------------------------------------------------ the large-N path
from scipy import stats as sps  # noqa: E402

from jaxeac.stats import _rng, asymptotic, device_sums, large  # noqa: E402
from jaxeac.stats import closed_form as cf  # noqa: E402
from jaxeac.stats import events as ev  # noqa: E402
from jaxeac.stats.curves import curve_results, curve_results_large  # noqa: E402
from jaxeac.stats.resample import dispatch_bootstrap, dispatch_permutation  # noqa: E402

BIG = 200_000  # seeds per method for the checks against exact references (large path: > LARGE_N)


def _mc_band(ref: np.ndarray, q: float, z: float = 4.0) -> tuple[float, float]:
    """Distribution-free Monte Carlo band for the q-quantile of `ref`'s law: order statistics at
    ranks R·q ± z·sqrt(R q (1 − q))."""
    r = np.sort(ref)
    R = r.size
    half = z * np.sqrt(R * q * (1 - q))
    return r[max(int(R * q - half), 0)], r[min(int(R * q + half), R - 1)]


def test_threshold_switches_between_paths():
    assert not large.is_large(large.LARGE_N, 10) and large.is_large(large.LARGE_N + 1, 10)
    n = large.LARGE_N + 1
    sb, st = synthetic(n, trials=20, seed=3)
    stats, _ = compare_experiment(
        sb, st, key=1, resamples=500, calibration_splits=50, calibration_resamples=49
    )
    sc = stats["settings"]["scale"]
    assert sc["path"] == "large-N" and sc["large_n_threshold"] == large.LARGE_N
    assert sc["measures"]["successes"]["bootstrap"].startswith("exact")
    assert "Gaussian" in stats["curves"]["band_method"] and "large_n" in stats["calibration"]
    small, _ = compare_experiment(sb[:500], st[:500], key=1, resamples=500, calibration_splits=0)
    assert small["settings"]["scale"]["path"] == "seed resampling"


def test_per_value_bootstrap_is_the_seed_bootstrap():
    """Counts per distinct value against drawing seeds (a direct index-resampling bootstrap of the
    same data) and the bootstrap's exact moments: mean, SE and the whole law (KS)."""
    rng = np.random.default_rng(1)
    x = rng.binomial(200, rng.beta(2, 3, BIG)).astype(float)  # 0..200, skewed: like successes
    table = large.ValueTable(x, x[:2])
    keep = table.kb > 0
    v = table.values[keep]
    R = 2000
    cnt = _rng.multinomial_counts(_rng.host_rng(jax.random.key(0)), table.kb[keep], R)
    assert (cnt.sum(1) == BIG).all()
    means = cnt @ v / BIG
    q = large.iqm_from_counts(cnt, v)
    se = x.std() / np.sqrt(BIG)  # exact SE of the bootstrap mean (biased SD)
    assert abs(means.mean() - x.mean()) < 4 * se / np.sqrt(R)
    assert means.std(ddof=1) == pytest.approx(se, rel=4 / np.sqrt(2 * R))
    ref_means, ref_q = [], []  # the slow exact reference: draw seeds, 300 resamples
    for _ in range(10):
        xs = x[rng.integers(0, BIG, (30, BIG))]
        ref_means.append(xs.mean(1))
        ref_q.append(sps.trim_mean(xs, 0.25, axis=1))
    ref_means, ref_q = np.concatenate(ref_means), np.concatenate(ref_q)
    assert sps.ks_2samp(means, ref_means).pvalue > 1e-3
    assert sps.ks_2samp(q, ref_q).pvalue > 1e-3
    # the IQM of counts is the trimmed mean of the expanded resample, exactly
    for row in cnt[:3]:
        assert large.iqm_from_counts(row[None], v)[0] == pytest.approx(
            sps.trim_mean(np.repeat(v, row.astype(int)), 0.25), rel=1e-12
        )


def test_per_value_jackknife_and_bca_equal_the_per_seed_ones():
    """The O(distinct values) estimate, jackknife and BCa equal the per-seed computation."""
    from jaxeac.stats.bca import bca_two_sample_counts, jackknife_iqm

    rng = np.random.default_rng(3)
    x, y = rng.integers(0, 30, 3001).astype(float), rng.integers(2, 35, 2500).astype(float)
    tb, tt = large.ValueTable(x, x[:0]), large.ValueTable(y, y[:0])
    (vb, kb), (vt, kt) = ((t.values, t.kb.astype(float)) for t in (tb, tt))
    R = 500
    sb = large.moment_sums(_rng.multinomial_counts(_rng.host_rng(jax.random.key(0)), tb.kb, R), vb)
    st = large.moment_sums(_rng.multinomial_counts(_rng.host_rng(jax.random.key(1)), tt.kb, R), vt)
    for statistic in ("mean_diff", "hedges_g"):
        a = bca_two_sample_counts(statistic, x, np.ones(x.size), y, np.ones(y.size), *sb, *st, 0.05)
        b = bca_two_sample_counts(statistic, vb, kb, vt, kt, *sb, *st, 0.05)
        assert (b.estimate, b.low, b.high) == pytest.approx((a.estimate, a.low, a.high), rel=1e-9)
    jk = jackknife_iqm(x)
    per_value = large.jackknife_iqm_counts(kb, vb)
    np.testing.assert_allclose(per_value[np.searchsorted(vb, x)], jk, rtol=1e-12)
    assert large.iqm_from_counts(kb[None], vb)[0] == pytest.approx(sps.trim_mean(x, 0.25), rel=1e-12)


def test_per_value_permutation_is_the_label_permutation():
    """Multivariate hypergeometric counts per value against relabelling seeds: exact moments of the
    treatment sum (finite-population) and the law against direct permutations."""
    rng = np.random.default_rng(2)
    n = BIG
    x = rng.integers(0, 41, 2 * n) / 40.0  # like late_success_rate
    table = large.ValueTable(x[:n], x[n:])
    pooled = table.kb + table.kt
    R = 2000
    h = _rng.hypergeometric_counts(_rng.host_rng(jax.random.key(1)), pooled, n, R)
    assert (h.sum(1) == n).all() and (h <= pooled).all()
    sums = h @ table.values
    N = 2 * n
    var = n * n / (N * (N - 1)) * ((x - x.mean()) ** 2).sum()
    assert abs(sums.mean() - n * x.mean()) < 4 * np.sqrt(var / R)
    assert sums.std(ddof=1) == pytest.approx(np.sqrt(var), rel=4 / np.sqrt(2 * R))
    ref = np.array([x[rng.permutation(N)[:n]].sum() for _ in range(300)])
    assert sps.ks_2samp(sums, ref).pvalue > 1e-3


def test_ranks_and_logrank_at_scale_match_scipy_and_statsmodels():
    sb, st = synthetic(BIG, trials=100, seed=4)
    from jaxeac.stats.measures import per_seed_measures

    mb, mt = per_seed_measures(sb), per_seed_measures(st)
    for name in ("successes", "auc_cumulative"):
        table = large.ValueTable(mb[name], mt[name])
        phat, w, df, p, lo, hi = (float(v[0]) for v in cf.brunner_munzel_counts(table.kb, table.kt))
        ref = sps.brunnermunzel(mb[name], mt[name])
        assert w == pytest.approx(ref.statistic, rel=1e-9) and p == pytest.approx(
            ref.pvalue, rel=1e-6, abs=1e-300
        )
        sub = slice(0, 3000)  # A12 by brute force on a subsample, against the counts on the same
        x, y = mb[name][sub], mt[name][sub]
        brute = np.mean(y[:, None] > x[None]) + 0.5 * np.mean(y[:, None] == x[None])
        t2 = large.ValueTable(x, y)
        assert float(cf.brunner_munzel_counts(t2.kb, t2.kt)[0][0]) == pytest.approx(brute, rel=1e-12)
    sm_surv = pytest.importorskip("statsmodels.duration.survfunc")
    sub = slice(0, 20_000)
    lr = ev.logrank(mb["_time"][sub], mb["_event"][sub], mt["_time"][sub], mt["_event"][sub])
    chi2, p = sm_surv.survdiff(
        np.r_[mb["_time"][sub], mt["_time"][sub]],
        np.r_[mb["_event"][sub], mt["_event"][sub]].astype(int),
        np.r_[np.zeros(20_000), np.ones(20_000)],
    )
    assert lr.statistic == pytest.approx(chi2, rel=1e-9)


def test_abc_interval_matches_bca():
    """ABC (analytic BCa) against BCa of many resamples: scipy at small n (second-order agreement),
    and at 2·10^5 seeds against the exact per-value bootstrap's BCa within its Monte Carlo error."""
    from jaxeac.stats.bca import bca_two_sample_counts

    rng = np.random.default_rng(5)
    x, y = rng.exponential(1.0, 400), rng.exponential(1.4, 300)
    for statistic in ("mean_diff", "hedges_g"):

        def stat(a, b, axis=-1, statistic=statistic):
            if statistic == "mean_diff":
                return b.mean(axis) - a.mean(axis)
            return cf.hedges_from_moments(
                a.shape[-1], a.sum(axis), (a * a).sum(axis), b.shape[-1], b.sum(axis), (b * b).sum(axis)
            )

        ref = sps.bootstrap((x, y), stat, n_resamples=40_000, method="BCa", rng=1).confidence_interval
        got = asymptotic.abc_two_sample(statistic, x, y)
        width = ref.high - ref.low
        assert abs(got.low - ref.low) < 0.03 * width and abs(got.high - ref.high) < 0.03 * width
    # large n: the asymptotic path's intervals against an exact bootstrap's BCa of the same data
    x = np.round(rng.gamma(2.0, 30.0, BIG))
    y = np.round(rng.gamma(2.1, 30.0, BIG))
    c = np.r_[x, y].mean()
    R = 4000
    sums = []
    for seed, z in ((7, x), (8, y)):
        t = large.ValueTable(z, z[:2])
        keep = t.kb > 0
        cnt = _rng.multinomial_counts(_rng.host_rng(jax.random.key(seed)), t.kb[keep], R)
        sums.append(large.moment_sums(cnt, t.values[keep] - c))
    for statistic in ("mean_diff", "hedges_g"):
        one = np.ones(BIG)
        bca = bca_two_sample_counts(statistic, x - c, one, y - c, one, *sums[0], *sums[1], 0.05)
        abc = asymptotic.abc_two_sample(statistic, x - c, y - c)
        width = bca.high - bca.low
        assert abs(abc.low - bca.low) < 0.06 * width and abs(abc.high - bca.high) < 0.06 * width


def test_normal_permutation_p_matches_exact_permutation():
    """The normal limit of the studentised permutation test against an exact one (per-value
    hypergeometric relabellings) for a measure with many distinct values, near p = 0.05."""
    rng = np.random.default_rng(6)
    x = np.round(rng.gamma(2.0, 1.0, BIG) * 500) / 500  # ~ 10^4 distinct values
    y = rng.gamma(2.0, 1.0, BIG)
    se = np.sqrt(x.var(ddof=1) / BIG + y.var(ddof=1) / BIG)
    y = np.round((y + 2.0 * se - (y.mean() - x.mean())) * 500) / 500  # Welch t near 2: p near 0.05
    res = permutation_test(x, y, jax.random.key(2), resamples=10)
    t = large.ValueTable(x, y)
    assert t.distinct > large.MAX_DISTINCT
    c = np.r_[x, y].mean()
    v = t.values - c
    R = 4000
    h = _rng.hypergeometric_counts(_rng.host_rng(jax.random.key(3)), t.kb + t.kt, BIG, R)
    s1, s2 = large.moment_sums(h, v)
    tot1, tot2 = (t.kb + t.kt) @ v, (t.kb + t.kt) @ (v * v)
    from jaxeac.stats.closed_form import welch_t_stat

    t_star = welch_t_stat(BIG, tot1 - s1, tot2 - s2, BIG, s1, s2)
    p_exact = (1 + (np.abs(t_star) >= abs(res.statistic)).sum()) / (R + 1)
    assert 0.005 < p_exact < 0.5
    assert abs(res.pvalue - p_exact) < 4 * np.sqrt(p_exact * (1 - p_exact) / R) + 1e-3


def test_gaussian_curve_bands_and_max_t_match_the_seed_resampling():
    """Just above the threshold, the Gaussian sup-t and max-T laws against the seed bootstrap and
    the label permutation of the same data (the path used below the threshold)."""
    n, T, R, alpha = large.LARGE_N + 5000, 40, 2000, 0.05
    rng = np.random.default_rng(9)
    logit = np.linspace(-1.2, 1.2, T)
    bump = np.where((np.arange(T) >= 20) & (np.arange(T) < 30), 0.06, 0.0)  # small: p_maxT spread out
    sb, st = (
        rng.random((n, T)) < 1 / (1 + np.exp(-(logit + b + rng.normal(0, 0.6, (n, 1))))) for b in (0.0, bump)
    )
    kb, kt, kp = jax.random.split(jax.random.key(4), 3)
    bb, _ = dispatch_bootstrap(kb, sb, R)()
    bt, _ = dispatch_bootstrap(kt, st, R)()
    pt = dispatch_permutation(kp, np.concatenate([sb, st]), n, R)()
    exact = curve_results(sb.astype(float), st.astype(float), bb, bt, pt, alpha, True)
    mom = [device_sums.curve_moments(c)() for c in (sb, st)]
    gauss = curve_results_large(mom[0], mom[1], (kb, kt, kp), R, alpha, True)
    np.testing.assert_allclose(gauss["mean_baseline"], exact["mean_baseline"], rtol=1e-12)
    np.testing.assert_allclose(gauss["t_welch"], exact["t_welch"], rtol=1e-9)
    # the whole laws: max deviation of the bootstrap and of the Gaussian, max |t| under permutation
    seb = np.sqrt(exact["mean_baseline"] * (1 - exact["mean_baseline"]) * n / (n - 1) / n)
    boot_dev = (np.abs(bb / n - exact["mean_baseline"]) / seb).max(1)
    cov = device_sums.covariance(mom[0]) / n
    g_dev = (np.abs(device_sums.gaussian_draws(_rng.host_rng(jax.random.key(5)), cov, R)) / seb).max(1)
    assert sps.ks_2samp(boot_dev, g_dev).pvalue > 1e-3
    lo, hi = _mc_band(boot_dev, 1 - alpha)
    assert lo <= gauss["sup_t_critical"]["baseline"] <= hi
    from jaxeac.stats.closed_form import welch_t_stat

    tot = sb.sum(0) + st.sum(0)
    perm_max = np.abs(welch_t_stat(n, tot - pt, None, n, pt, None)).max(1)
    pooled = {"n": 2 * n, "s": mom[0]["s"] + mom[1]["s"], "G": mom[0]["G"] + mom[1]["G"]}
    g_max = device_sums.gaussian_max_abs(_rng.host_rng(jax.random.key(6)), device_sums.covariance(pooled), R)
    assert sps.ks_2samp(perm_max, g_max).pvalue > 1e-3
    lo, hi = _mc_band(perm_max, 1 - alpha)
    assert lo <= gauss["maxT_critical"] <= hi
    mid = (exact["p_maxT"] > 0.01) & (exact["p_maxT"] < 0.9)
    assert mid.any()
    pe, pg = exact["p_maxT"][mid], gauss["p_maxT"][mid]
    assert (np.abs(pe - pg) < 4 * np.sqrt(pe * (1 - pe) * 2 / R) + 2e-3).all()


def test_curve_moments_and_subset_sums_are_exact():
    rng = np.random.default_rng(8)
    c = rng.random((device_sums.BLOCK + 123, 7)) < 0.3
    m = device_sums.curve_moments(c)()
    x = c.astype(float)
    np.testing.assert_array_equal(m["G"], x.T @ x)
    np.testing.assert_array_equal(m["s"], x.sum(0))
    packed = device_sums.curve_moments(SuccessBits.pack(c))()  # unpacked on the device: the same sums
    np.testing.assert_array_equal(packed["G"], m["G"])
    np.testing.assert_array_equal(packed["s"], m["s"])
    key = jax.random.key(5)
    subset_sums = device_sums.dispatch_subset_sums
    np.testing.assert_array_equal(subset_sums(key, SuccessBits.pack(c[:3000]), 1000, 50)(),
                                  subset_sums(key, c[:3000], 1000, 50)())
    pins = rng.integers(0, 11, (5000, 4))
    mp = device_sums.curve_moments(pins)()
    np.testing.assert_array_equal(mp["G"], pins.T.astype(float) @ pins)
    # random halves: each draw takes exactly k units, and all C(n, k) subsets are equally likely
    n, k, reps = 5, 2, 20_000
    sums = device_sums.dispatch_subset_sums(jax.random.key(0), np.eye(n, dtype=bool), k, reps, block=2)()
    assert (sums.sum(1) == k).all()
    from itertools import combinations

    index = {cmb: i for i, cmb in enumerate(combinations(range(n), k))}
    counts = np.bincount([index[tuple(np.nonzero(r)[0])] for r in sums], minlength=len(index))
    assert sps.chisquare(counts).pvalue > 1e-3
    n, k, reps = 150, 40, 4000  # several blocks of 64, 32 positions per matmul
    sums = device_sums.dispatch_subset_sums(jax.random.key(1), np.eye(n, dtype=bool), k, reps, block=64)()
    assert (sums.sum(1) == k).all() and set(np.unique(sums)) <= {0.0, 1.0}
    assert sps.chisquare(sums.sum(0)).pvalue > 1e-3  # every seed equally likely to be taken


def test_large_path_calibration_near_alpha_and_report(tmp_path):
    """Null data just above the threshold: every calibrated test near alpha; the report says which
    methods the large-N path used."""
    n = large.LARGE_N + 2000
    sb, _ = synthetic(2 * n, trials=100, seed=12)
    stats, _ = compare_experiment(
        sb[:n], sb[n:], key=3, resamples=1000, calibration_splits=300, calibration_resamples=199
    )
    for test, per in stats["calibration"]["false_positive_rate"].items():
        for name, r in per.items():
            assert r["rate"] <= 0.11, (test, name, r)
    assert (
        stats["primary"]["diff_ci95"][0] < 0 < stats["primary"]["diff_ci95"][1]
        or stats["primary"]["p_welch"] < 0.05
    )
    from jaxeac.stats.report import render_markdown

    stats["run_dir"] = str(tmp_path)
    stats["timing"]["total_seconds"] = 0.0
    text = render_markdown(to_jsonable(stats))
    assert "large-N path" in text and "ABC intervals" in text and "Gaussian multiplier" in text


if __name__ == "__main__":
    results = {"api_10k": _jsonable_api(api_10k()), "bowling_10k": bowling_10k(), "grid_10k": grid_10k()}
    PINNED_FILE.write_text(json.dumps(to_jsonable(results), allow_nan=True))
    print("PINNED_DIGESTS = " + json.dumps({k: digest(v) for k, v in results.items()}, indent=4))
    sys.exit(0)


def test_compile_ahead_builds_the_large_path_programs_only_when_needed():
    """`large.compile_ahead` (a head start for `jaxeac grid` on GPUs): nothing below the
    threshold; above it, every device program of the large path compiles for the given shapes."""
    assert large.compile_ahead(100, 16, 4) is None
    large.compile_ahead(large.LARGE_N + 3, 16, 4)  # odd n: halves of 2·⌊n/2⌋ seeds too


_KEY_PROGRAMS = """
import sys, jax, jax.monitoring, numpy as np
from jaxeac.stats import compare_experiment
from jaxeac.stats._rng import warm_key_programs
if sys.argv[1] == "warm":
    warm_key_programs()
names = []
def seen(event, seconds, **meta):
    if event.endswith("backend_compile_duration"):
        names.append(str(meta.get("fun_name")).removeprefix("jit(").removesuffix(")"))
jax.monitoring.register_event_duration_secs_listener(seen)
rng = np.random.default_rng(0)
sb, st = (rng.random((64, 12)) < p for p in (0.3, 0.6))
compare_experiment(sb, st, resamples=100, calibration_splits=0, key=3, paired=True)
print(sorted({n for n in names if "threefry" in n or n == "unstack"}))
"""


def test_warm_key_programs_leave_no_key_program_to_compile():
    """`warm_key_programs` (run on the compile-ahead thread of `jaxeac grid`): in a fresh process, a
    paired comparison compiles key-derivation programs without it and none after it."""
    import subprocess

    def key_programs(mode: str) -> str:
        out = subprocess.run([sys.executable, "-c", _KEY_PROGRAMS, mode], capture_output=True, text=True,
                             check=True)
        return out.stdout.strip().splitlines()[-1]

    assert "_threefry_split" in key_programs("cold")
    assert key_programs("warm") == "[]"


def test_large_path_from_codes_is_the_float_path_bit_for_bit(monkeypatch):
    """Measures held as integer codes (`Coded`: counts per value from the codes, float64 values
    made a measure at a time, means a block of seeds at a time, measures in turn within the host
    budget) give the very results of the float64 arrays they stand for: analyses, calibration,
    log-rank and the figures' tables, at a threshold lowered so a small case takes the large path."""
    from jaxeac.stats import calibration as cal_mod
    from jaxeac.stats import compare
    from jaxeac.stats import measures as rundir

    monkeypatch.setattr(large, "LARGE_N", 400)
    monkeypatch.setattr(large, "MAX_DISTINCT", 100)  # the area measure takes the ABC / normal-limit path
    monkeypatch.setattr(large, "HOST_BUDGET", large.HostBudget(1))  # one analysis at a time
    monkeypatch.setattr(rundir, "_COUNT_BLOCK", 97)  # several blocks of codes, the last one short
    sb, st = synthetic(1001, trials=60, seed=5)
    codes = [rundir.per_seed_codes(s) for s in (sb, st)]
    floats = [rundir.per_seed_measures(s) for s in (sb, st)]
    names = [k for k in codes[0] if not k.startswith("_")]
    for c, f in zip(codes, floats, strict=True):
        for k in names:
            assert c[k].codes.itemsize <= 2
            np.testing.assert_array_equal(c[k].values(), f[k])
            for got, want in zip(rundir.value_counts(c[k]), np.unique(f[k], return_counts=True), strict=True):
                np.testing.assert_array_equal(got, want)

    def same(a, b):
        assert json.dumps(to_jsonable(a), sort_keys=True) == json.dumps(to_jsonable(b), sort_keys=True)

    def analyse(m):
        res = compare._analyse(*({k: x[k] for k in names} for x in m), 3, resamples=300, alpha=0.05,
                               chunk=100, perm_chunk=100, higher_is_better=None)
        return res["measures"], res["scale"]

    coded = analyse(codes)
    same(coded, analyse(floats))
    methods = coded[1]
    assert "ABC" in methods["auc_cumulative"]["bootstrap"]
    assert methods["successes"]["bootstrap"].startswith("exact")

    def calibration(m):
        return cal_mod.calibrate({k: m[k] for k in names}, None, 4, splits=40, resamples=50,
                                 time_event=(m["_time"], m["_event"]))

    same(calibration(codes[0]), calibration(floats[0]))
    lr = ev.logrank_tables(*(rundir.event_counts(c["_time"], c["_event"]) for c in codes))
    (fb, ft) = floats
    mask = np.r_[np.zeros(fb["_time"].size, bool), np.ones(ft["_time"].size, bool)][None]
    chi2, p, _, _ = ev.logrank_masks(np.r_[fb["_time"], ft["_time"]].astype(float),
                                     np.r_[fb["_event"], ft["_event"]], mask)
    assert (lr.statistic, lr.pvalue) == (chi2[0], p[0])
    for cols in ([codes[0][k] for k in names], [floats[0][k] for k in names], [codes[0]["successes"]]):
        direct = np.stack([rundir.as_values(c)[:1000] for c in cols], 1).mean(0)
        np.testing.assert_array_equal(large.stacked_means(cols, 1000, block=64), direct)


@pytest.mark.parametrize("n", [3, 64, 65, 1000])
def test_running_column_sums_are_the_whole_arrays(n):
    """ABC's moments of [z, z²] and the calibration's means, a block of rows at a time, are those
    NumPy gives for the whole [n, M] array, bit for bit."""
    z = np.random.default_rng(n).normal(size=n) * 7
    u = np.stack([z, z * z], 1)
    mean, sd = asymptotic._units_moments(z, block=16)
    np.testing.assert_array_equal(mean, u.mean(0))
    np.testing.assert_array_equal(sd, u.std(0))
    cols = [z, z * 3, np.cos(z)]
    direct = np.stack(cols, 1)[: n - 1].mean(0)
    np.testing.assert_array_equal(large.stacked_means(cols, n - 1, block=16), direct)


@pytest.mark.parametrize("device", [False, True])
@pytest.mark.parametrize("trials", [1, 7, 8, 9, 13, 200, 203])
def test_measures_from_packed_bits_are_those_of_the_unpacked_rows(trials, device, monkeypatch):
    """`per_seed_codes` reads `SuccessBits` byte by byte (set bits and their positions per byte), on
    host threads or, on an accelerator, in one device program (`device_codes`, here on the CPU's
    XLA, in blocks of 7,000 seeds); every code equals the unpacked bool path's, dtype included, on
    empty, full and random rows, and bits past the last trial (a damaged pad) change nothing."""
    from jaxeac.stats import device_sums, measures
    from jaxeac.stats.measures import per_seed_codes

    monkeypatch.setattr(measures, "_on_device", lambda: device)
    monkeypatch.setattr(device_sums, "CODES_BLOCK", 7_000)

    rng = np.random.default_rng(trials)
    success = rng.random((40_000, trials)) < rng.choice([0.0, 0.02, 0.5, 0.98, 1.0], size=(40_000, 1))
    success[0], success[1] = False, True
    packed = SuccessBits.pack(success)
    dirty = SuccessBits(packed.bits.copy(), trials)
    if trials % 8:
        dirty.bits[:, -1] |= np.uint8(0xFF << (trials % 8) & 0xFF)  # the pad bits set
    want = per_seed_codes(success)
    for bits in (packed, dirty):
        got = per_seed_codes(bits)
        assert list(got) == list(want)
        for name, value in want.items():
            a, b = getattr(value, "codes", value), getattr(got[name], "codes", got[name])
            assert a.dtype == b.dtype and np.array_equal(a, b), name
    assert want["successes"].codes[1] == trials and want["first_success"].codes[0] == trials + 1
