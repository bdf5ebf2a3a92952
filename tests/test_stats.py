"""Tests of jaxeac.stats (SPEC §6): each statistic against scipy/statsmodels or a closed form."""

from __future__ import annotations

import json
import math
from itertools import combinations
from pathlib import Path

import jax
import jax.extend.random as jxr
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from jaxeac.errors import UsageError
from jaxeac.stats import (
    a12,
    bca_ci,
    brunner_munzel,
    compare_measures,
    compare_run_dir,
    curve_bands,
    hedges_g,
    holm,
    iqm,
    iqm_ci,
    logrank,
    newcombe_diff,
    permutation_test,
    power_ttest,
    risk_ratio_ci,
    seeds_for_power,
    welch_t,
)
from jaxeac.stats._rng import key_words, mulhi32, random_subsets, threefry2x32, uniform_index
from jaxeac.stats.bca import jackknife_iqm
from jaxeac.stats.resample import bootstrap_sums

sm_prop = pytest.importorskip("statsmodels.stats.proportion")
sm_power = pytest.importorskip("statsmodels.stats.power")
sm_multi = pytest.importorskip("statsmodels.stats.multitest")
sm_surv = pytest.importorskip("statsmodels.duration.survfunc")


def samples(seed=0, nx=40, ny=33, ties=True):
    rng = np.random.default_rng(seed)
    if ties:
        return rng.integers(0, 10, nx).astype(float), rng.integers(1, 12, ny).astype(float)
    return rng.normal(0, 1, nx), rng.normal(0.4, 1.5, ny)


# ------------------------------------------------------------------ random draws
def test_threefry_matches_jax():
    key = jax.random.key(7)
    c = jnp.arange(16, dtype=jnp.uint32)
    ref = np.asarray(jxr.threefry_2x32(jax.random.key_data(key), jnp.concatenate([c, jnp.zeros_like(c)])))
    a, b = threefry2x32(*key_words(key), c, jnp.zeros_like(c))
    np.testing.assert_array_equal(np.concatenate([a, b]), ref)


def test_mulhi_is_exact():
    rng = np.random.default_rng(1)
    b = rng.integers(0, 2**32, 1000, dtype=np.uint64)
    for n in (1, 3, 10_000, 65_535, 65_536, 1_000_003, 2**32 - 1):
        got = np.asarray(mulhi32(jnp.asarray(b, jnp.uint32), n)).astype(np.uint64)
        np.testing.assert_array_equal(got, (b * np.uint64(n)) >> np.uint64(32))


@pytest.mark.parametrize("n", [7, 70_001])
def test_uniform_index_is_uniform(n):
    idx = np.asarray(uniform_index(jax.random.key(3), (200_000,), n))
    assert idx.min() >= 0 and idx.max() < n
    if n == 7:
        assert stats.chisquare(np.bincount(idx, minlength=n)).pvalue > 1e-3
    else:
        assert stats.kstest(idx / n, "uniform").pvalue > 1e-3


def test_random_subsets_exact_size_and_uniform():
    n, k, reps = 5, 2, 20_000
    sub = np.asarray(random_subsets(jax.random.key(0), n, k, reps))
    assert sub.shape == (n, reps)
    assert (sub.sum(0) == k).all()
    index = {c: i for i, c in enumerate(combinations(range(n), k))}
    counts = np.bincount([index[tuple(np.nonzero(col)[0])] for col in sub.T], minlength=len(index))
    assert stats.chisquare(counts).pvalue > 1e-3
    odd = np.asarray(random_subsets(jax.random.key(1), 7, 3, 1000))
    assert (odd.sum(0) == 3).all()


# ------------------------------------------------------------------ closed forms
@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), ties=st.booleans())
def test_welch_and_brunner_munzel_match_scipy(seed, ties):
    x, y = samples(seed, ties=ties)
    w = welch_t(x, y)
    ref = stats.ttest_ind(y, x, equal_var=False)
    assert w.statistic == pytest.approx(ref.statistic, rel=1e-10)
    assert w.pvalue == pytest.approx(ref.pvalue, rel=1e-9)
    assert w.df == pytest.approx(ref.df, rel=1e-10)
    bm = brunner_munzel(x, y)
    ref = stats.brunnermunzel(x, y)
    assert bm.statistic == pytest.approx(ref.statistic, rel=1e-10)
    assert bm.pvalue == pytest.approx(ref.pvalue, rel=1e-9)


def test_a12_and_hedges_closed_forms():
    x, y = samples(2)
    brute = np.mean(y[:, None] > x[None]) + 0.5 * np.mean(y[:, None] == x[None])
    est = a12(x, y)
    assert est.estimate == pytest.approx(brute, rel=1e-12)
    assert est.low < est.estimate < est.high
    nx, ny = x.size, y.size
    sp = np.sqrt(((nx - 1) * x.var(ddof=1) + (ny - 1) * y.var(ddof=1)) / (nx + ny - 2))
    df = nx + ny - 2
    j = math.gamma(df / 2) / (math.sqrt(df / 2) * math.gamma((df - 1) / 2))
    assert hedges_g(x, y) == pytest.approx(j * (y.mean() - x.mean()) / sp, rel=1e-10)
    assert j == pytest.approx(1 - 3 / (4 * df - 1), rel=1e-3)  # Hedges' approximation


def test_logrank_matches_statsmodels():
    rng = np.random.default_rng(4)
    tb, tt = rng.integers(1, 20, 50), rng.integers(1, 20, 40)
    eb, et = rng.random(50) < 0.7, rng.random(40) < 0.8
    res = logrank(tb, eb, tt, et)
    chi2, p = sm_surv.survdiff(np.r_[tb, tt], np.r_[eb, et].astype(int), np.r_[np.zeros(50), np.ones(40)])
    assert res.statistic == pytest.approx(chi2, rel=1e-10)
    assert res.pvalue == pytest.approx(p, rel=1e-9)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # statsmodels divides by zero for a zero count
@pytest.mark.parametrize(
    "counts", [(13, 40, 25, 42), (0, 30, 5, 30), (29, 30, 12, 31), (3, 200, 9, 150), (5, 30, 0, 30)]
)
def test_proportion_intervals_match_statsmodels(counts):
    cb, nb, ct, nt = counts
    d = newcombe_diff(cb, nb, ct, nt)
    lo, hi = sm_prop.confint_proportions_2indep(ct, nt, cb, nb, method="newcomb", compare="diff")
    assert (d.low, d.high) == pytest.approx((lo, hi), abs=1e-10)
    assert d.estimate == pytest.approx(ct / nt - cb / nb)
    r = risk_ratio_ci(cb, nb, ct, nt)
    lo, hi = sm_prop.confint_proportions_2indep(ct, nt, cb, nb, method="score", compare="ratio")
    assert r.low == pytest.approx(lo, rel=1e-6, abs=1e-9)
    assert r.high == pytest.approx(hi, rel=1e-6)  # inf when the baseline count is 0


def test_risk_ratio_endpoints_are_the_score_roots_to_the_last_float():
    """Each finite endpoint of the risk ratio's interval is where the score statistic crosses ∓z:
    the crossing lies between the endpoint's log and its neighbouring float, found without
    scipy.optimize, which the statistics no longer import (0.5 s on a 2-core CPU)."""
    import subprocess
    import sys

    from jaxeac.stats.events import _ratio_score_z

    cb, nb, ct, nt = 13, 40, 25, 42
    r = risk_ratio_ci(cb, nb, ct, nt)
    z = stats.norm.ppf(0.975)
    for end, target in ((r.low, z), (r.high, -z)):
        v = math.log(end)
        below, above = (_ratio_score_z(math.exp(u), ct, nt, cb, nb, True) - target
                        for u in (math.nextafter(v, -math.inf), math.nextafter(v, math.inf)))
        assert below >= 0 >= above  # z(phi) decreases: it crosses the target within a float of v
    code = ("import sys; from jaxeac.stats.events import proportions; import numpy as np; "
            "proportions(np.arange(40) < 13, np.arange(42) < 25); print('scipy.optimize' in sys.modules)")
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True).stdout.strip() == "False"


def test_power_matches_statsmodels():
    solver = sm_power.TTestIndPower()
    for d in (0.2, 0.5, 0.8, 0.31, 1.7):
        n = seeds_for_power(d)
        assert n == math.ceil(solver.solve_power(effect_size=d, alpha=0.05, power=0.8))
        assert power_ttest(d, n) >= 0.8 > power_ttest(d, n - 1)
        assert power_ttest(d, 50) == pytest.approx(solver.power(d, nobs1=50, alpha=0.05), rel=1e-8)
    assert seeds_for_power(0.0) is None


def test_holm_matches_statsmodels():
    rng = np.random.default_rng(5)
    for _ in range(20):
        p = rng.random(rng.integers(1, 8)) ** 3
        np.testing.assert_allclose(holm(p), sm_multi.multipletests(p, method="holm")[1], rtol=1e-12)


def test_iqm_and_its_jackknife():
    x = np.round(np.random.default_rng(6).exponential(3, 37))
    assert iqm(x) == pytest.approx(stats.trim_mean(x, 0.25))
    brute = [stats.trim_mean(np.delete(x, i), 0.25) for i in range(x.size)]
    np.testing.assert_allclose(jackknife_iqm(x), brute, rtol=1e-12)


# ------------------------------------------------------------------ resampling
def test_bootstrap_sums_moments_and_iqm_distribution():
    rng = np.random.default_rng(7)
    x = np.round(rng.exponential(2, 60))
    sums, q = bootstrap_sums(jax.random.key(1), x[:, None], 20_000, chunk=4000, iqm=True)
    means = sums[:, 0] / x.size
    assert means.mean() == pytest.approx(x.mean(), abs=4 * x.std() / np.sqrt(x.size) / np.sqrt(20_000))
    assert means.std() == pytest.approx(x.std() / np.sqrt(x.size), rel=0.03)
    idx = rng.integers(0, x.size, (20_000, x.size))
    ref = stats.trim_mean(x[idx], 0.25, axis=1)
    assert q.mean() == pytest.approx(ref.mean(), abs=0.02)
    assert q.std() == pytest.approx(ref.std(), rel=0.05)


def _ci_close(got, ref, frac=0.06):
    width = ref.high - ref.low
    assert abs(got.low - ref.low) < frac * width and abs(got.high - ref.high) < frac * width


@pytest.mark.parametrize("statistic", ["mean_diff", "hedges_g"])
def test_bca_matches_scipy(statistic):
    rng = np.random.default_rng(8)
    x, y = rng.exponential(1.0, 60), rng.exponential(1.6, 50)

    def stat(a, b, axis=-1):
        if statistic == "mean_diff":
            return b.mean(axis) - a.mean(axis)
        na, nb = a.shape[-1], b.shape[-1]
        sp = np.sqrt(((na - 1) * a.var(axis, ddof=1) + (nb - 1) * b.var(axis, ddof=1)) / (na + nb - 2))
        return (b.mean(axis) - a.mean(axis)) / sp * (1 - 3 / (4 * (na + nb) - 9))

    ref = stats.bootstrap((x, y), stat, n_resamples=20_000, method="BCa", rng=1).confidence_interval
    got = bca_ci(x, y, 0, statistic=statistic, resamples=20_000)
    _ci_close(got, ref)


def test_iqm_ci_matches_scipy():
    x = np.random.default_rng(9).exponential(1.0, 80)
    ref = stats.bootstrap(
        (x,), lambda a, axis=-1: stats.trim_mean(a, 0.25, axis=axis), n_resamples=20_000, method="BCa", rng=1
    ).confidence_interval
    _ci_close(iqm_ci(x, 3, resamples=20_000), ref)


def test_permutation_matches_scipy():
    x, y = samples(10, ties=False)
    ref = stats.permutation_test(
        (x, y),
        lambda a, b, axis=-1: stats.ttest_ind(b, a, equal_var=False, axis=axis).statistic,
        n_resamples=20_000,
        rng=2,
    ).pvalue
    got = permutation_test(x, y, 0, resamples=20_000)
    assert got.statistic == pytest.approx(welch_t(x, y).statistic, rel=1e-10)
    assert abs(got.pvalue - ref) < 4 * math.sqrt(ref * (1 - ref) / 20_000) + 1e-3


def test_permutation_p_uniform_under_null():
    rng = np.random.default_rng(11)
    ps = np.array(
        [
            permutation_test(rng.normal(size=15), rng.normal(size=12), i, resamples=199, chunk=199).pvalue
            for i in range(300)
        ]
    )
    assert stats.kstest(ps, "uniform").pvalue > 1e-3
    rejections = (ps <= 0.05).sum()
    assert 4 <= rejections <= 28  # Binomial(300, 0.05): mean 15, these are ~ 1e-3 tails


def test_same_key_same_output_different_key_different():
    x, y = samples(12, ties=False)
    r1 = compare_measures(x, y, 5, resamples=1000)
    r2 = compare_measures(x, y, 5, resamples=1000)
    r3 = compare_measures(x, y, 6, resamples=1000)
    assert json.dumps(r1, default=float) == json.dumps(r2, default=float)
    assert r1["value"]["diff_ci95"] != r3["value"]["diff_ci95"]
    assert r1["value"]["p_welch"] == r3["value"]["p_welch"]  # closed form: key-free


def test_compare_measures_agrees_with_single_functions():
    x, y = samples(13, ties=False)
    r = compare_measures({"m": x}, {"m": y}, 0, resamples=2000)["m"]
    assert r["p_welch"] == pytest.approx(welch_t(x, y).pvalue)
    assert r["a12"] == pytest.approx(a12(x, y).estimate)
    assert r["hedges_g"] == pytest.approx(hedges_g(x, y))
    assert r["brunner_munzel"]["p"] == pytest.approx(brunner_munzel(x, y).pvalue)
    assert r["diff_ci95"][0] < r["diff"] < r["diff_ci95"][1]
    assert r["seeds_for_80pct_power"] == seeds_for_power(r["hedges_g"])


# ------------------------------------------------------------------ curves
def test_curve_bands_find_planted_difference():
    rng = np.random.default_rng(14)
    T = 40
    p = np.full(T, 0.3)
    q = p.copy()
    q[25:] = 0.6
    cb, ct = rng.random((300, T)) < p, rng.random((300, T)) < q
    res = curve_bands(cb, ct, 0, resamples=1000)
    np.testing.assert_allclose(res["mean_baseline"], cb.mean(0))
    sig = set(res["significant_trials"])
    assert set(range(26, T + 1)) <= sig and not sig & set(range(1, 21))
    assert res["sustained_from_trial"] == 26
    crit = res["sup_t_critical"]["baseline"]
    assert stats.norm.ppf(0.975) < crit < stats.norm.ppf(1 - 0.025 / T) + 0.3
    lo, hi = res["band_baseline"]
    assert (lo <= res["mean_baseline"]).all() and (res["mean_baseline"] <= hi).all()


def test_curve_band_covers_whole_true_curve():
    rng = np.random.default_rng(15)
    T, n = 15, 150
    p = np.linspace(0.2, 0.8, T)
    cover = []
    for i in range(60):
        cb, ct = rng.random((n, T)) < p, rng.random((n, T)) < p
        res = curve_bands(cb, ct, i, resamples=400)
        lo, hi = res["band_treatment"]
        cover.append(bool(((lo <= p) & (p <= hi)).all()))
    assert np.mean(cover) >= 0.85  # nominal 0.95; pointwise bands would cover far less often


# ------------------------------------------------------------------ input errors
def test_shape_errors():
    x, y = samples(16)
    with pytest.raises(UsageError, match="at least 2 seeds"):
        compare_measures(x[:1], y, 0, resamples=200)
    with pytest.raises(UsageError, match="1-D"):
        compare_measures(np.ones((5, 200)), np.ones((5, 200)), 0, resamples=200)
    with pytest.raises(UsageError, match="differ"):
        compare_measures({"a": x}, {"b": y}, 0, resamples=200)
    with pytest.raises(UsageError, match="different numbers of seeds"):
        compare_measures({"a": x, "b": x[:-1]}, {"a": y, "b": y}, 0, resamples=200)
    with pytest.raises(UsageError, match="transposed"):
        curve_bands(np.zeros((200, 30)), np.zeros((30, 200)), 0, trials=200)
    with pytest.raises(UsageError, match="trials"):
        curve_bands(np.zeros((30, 200)), np.zeros((30, 100)), 0)
    with pytest.raises(UsageError, match="NaN"):
        welch_t([1.0, np.nan, 2.0], [1.0, 2.0])


# ------------------------------------------------------------------ run directory
def write_run(path: Path, n=60, T=30, experiment="grid", seed=0, eac_shift=0.2):
    rng = np.random.default_rng(seed)
    arrays, rows = {}, []
    header = (
        "algo,seed,successes,steps,first_success"
        if experiment == "grid"
        else "algo,seed,return,successes,first_success,extra"
    )
    for algo, shift in (("ac", 0.0), ("eac", eac_shift)):
        prob = np.clip(np.linspace(0.1, 0.6, T) + shift, 0, 1)
        s = rng.random((n, T)) < prob
        arrays[algo] = s
        first = np.where(s.any(1), s.argmax(1) + 1, -1)
        if experiment == "grid":
            rows += [f"{algo},{i},{s[i].sum()},{40 * T},{first[i]}" for i in range(n)]
        else:
            pins = np.where(s, 10, rng.integers(0, 10, (n, T)))
            arrays[f"{algo}_return"] = pins
            rows += [f"{algo},{i},{pins[i].sum()},{s[i].sum()},{first[i]},x" for i in range(n)]
    np.savez(path / "curves.npz", **arrays)
    (path / "per_seed.csv").write_text(header + "\n" + "\n".join(rows) + "\n")
    primary = "successes" if experiment == "grid" else "return"
    (path / "summary.json").write_text(
        json.dumps(
            {"experiment": experiment, "primary_measure": primary, "algos": ["ac", "eac"], "trials": T}
        )
    )


@pytest.mark.parametrize("experiment", ["grid", "bowling"])
def test_compare_run_dir_end_to_end(tmp_path, experiment):
    write_run(tmp_path, experiment=experiment, T=30 if experiment == "grid" else 10)
    out = compare_run_dir(
        tmp_path, resamples=500, key=3, calibration_splits=40, calibration_resamples=99, progress=False
    )
    saved = json.loads((tmp_path / "stats.json").read_text())
    assert saved == out
    need = {
        "measure",
        "n_baseline",
        "n_treatment",
        "mean_baseline",
        "mean_treatment",
        "diff",
        "diff_ci95",
        "p_welch",
        "p_permutation",
        "hedges_g",
        "a12",
        "seeds_for_80pct_power",
    }
    assert need <= set(saved["primary"])
    assert saved["primary"]["measure"] == ("successes" if experiment == "grid" else "return")
    assert set(saved["secondary"]) == {"late_success_rate", "first_success", "auc_cumulative"}
    assert saved["holm"]["family"][0] == saved["primary"]["measure"]
    assert saved["settings"]["key"] == 3 and saved["settings"]["resamples"] == 500
    assert len(saved["curves"]["mean_baseline"]) == saved["trials"]
    assert saved["calibration"]["splits"] == 40
    report = (tmp_path / "report.md").read_text()
    for fig in ("compare_curves.png", "compare_distributions.png", "compare_improvement.png"):
        assert (tmp_path / fig).stat().st_size > 1000
        assert f"]({fig})" in report
    assert "Holm" in report and "Key 3" in report
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".staging")]


def test_run_dir_errors_write_nothing(tmp_path):
    write_run(tmp_path)
    with pytest.raises(UsageError, match="--treatment 'bogus'"):
        compare_run_dir(tmp_path, treatment="bogus", resamples=200, progress=False)
    npz = dict(np.load(tmp_path / "curves.npz"))
    np.savez(tmp_path / "curves.npz", ac=npz["ac"].T, eac=npz["eac"])
    with pytest.raises(UsageError, match="trials axis first"):
        compare_run_dir(tmp_path, resamples=200, progress=False)
    npz["eac"] = npz["eac"][:-1]
    np.savez(tmp_path / "curves.npz", **npz)
    with pytest.raises(UsageError, match="different runs"):
        compare_run_dir(tmp_path, resamples=200, progress=False)
    assert not (tmp_path / "stats.json").exists() and not (tmp_path / "report.md").exists()


def test_calibration_rates_near_alpha(tmp_path):
    write_run(tmp_path, n=400, T=20, eac_shift=0.0)
    out = compare_run_dir(
        tmp_path, resamples=200, key=1, calibration_splits=300, calibration_resamples=199, progress=False
    )
    rates = out["calibration"]["false_positive_rate"]
    for test, per in rates.items():
        for name, r in per.items():
            assert r["rate"] <= 0.11, (test, name, r)  # alpha = 0.05; 300 splits
    assert out["primary"]["diff_ci95"][0] < 0.5 * out["primary"]["sd_baseline"]


def test_bootstrap_iqm_equals_trimmed_mean_of_each_resample():
    """The sort-free IQM of each resample equals scipy's trim_mean of the same draw."""
    rng = np.random.default_rng(17)
    x = np.sort(np.round(rng.exponential(3.0, 1000)))  # ties, several 128-unit blocks
    key = jax.random.key(4)
    _, q = bootstrap_sums(key, x[:, None], 50, chunk=50, iqm=True)
    idx = np.asarray(uniform_index(jax.random.fold_in(key, 0), (50, x.size), x.size))
    np.testing.assert_allclose(q, stats.trim_mean(x[idx], 0.25, axis=1), rtol=1e-5)


@pytest.mark.filterwarnings("error::RuntimeWarning")
def test_constant_groups_give_defined_results():
    r = compare_measures(np.zeros(10), np.ones(10), 0, resamples=300)["value"]
    assert r["p_welch"] == 0.0 and r["p_permutation"] == pytest.approx(1 / 301)
    assert r["a12"] == 1.0 and r["diff_ci95"] == [1.0, 1.0]
    same = compare_measures(np.ones(10), np.ones(10), 0, resamples=300)["value"]
    assert same["p_welch"] == 1.0 and same["p_permutation"] == 1.0 and same["seeds_for_80pct_power"] is None
    cb, ct = np.zeros((10, 5)), np.zeros((10, 5))
    ct[:, 2] = 1
    assert curve_bands(cb, ct, 0, resamples=300)["significant_trials"] == [3]
