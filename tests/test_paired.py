"""The paired analysis (`jaxeac.stats.paired`): against scipy and by hand, exact per-value
resampling against pairs drawn one by one, the sign-flip test against full enumeration, and
`jaxeac compare` choosing it for a shared-key run folder."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest
from scipy import stats as sps

from jaxeac.cli import main
from jaxeac.stats import large
from jaxeac.stats.paired import paired_analysis, sign_flip_p


def correlated(n: int, rng, shift: float = 1.5, integer: bool = True):
    ability = rng.normal(0, 8, n)
    x = 50 + ability + rng.normal(0, 3, n)
    y = 50 + shift + ability + rng.normal(0, 3, n)
    return (np.round(x), np.round(y)) if integer else (x, y)


def test_paired_t_dz_and_correlation_by_hand(rng):
    x, y = correlated(400, rng)
    r = paired_analysis(x, y, 0, resamples=500)
    ref = sps.ttest_rel(y, x)
    d = y - x
    assert np.isclose(r["t_paired"], ref.statistic) and np.isclose(r["p_paired_t"], ref.pvalue, rtol=1e-10)
    assert r["df"] == 399 and np.isclose(r["mean_diff"], d.mean()) and np.isclose(r["se_diff"], sps.sem(d))
    assert np.isclose(r["d_z"], d.mean() / d.std(ddof=1))
    assert np.isclose(r["correlation"], sps.pearsonr(x, y).statistic)
    lo, hi = r["mean_diff_ci95"]
    assert lo < d.mean() < hi
    assert hi - lo < 0.7 * (2 * 1.96 * np.sqrt(x.var(ddof=1) / 400 + y.var(ddof=1) / 400))  # pairing helps


def test_per_value_bootstrap_agrees_with_pairs_drawn_one_by_one(rng, monkeypatch):
    """Integer differences: multinomial counts per value are the law of resampling pairs, so the
    BCa endpoints agree with the one-by-one bootstrap within Monte Carlo error."""
    x, y = correlated(3000, rng)
    exact = paired_analysis(x, y, 1, resamples=20_000)
    assert exact["bootstrap"].startswith("exact")
    monkeypatch.setattr(large, "MAX_DISTINCT", 0)
    drawn = paired_analysis(x, y, 2, resamples=20_000)
    assert drawn["bootstrap"] == "pairs resampled one by one"
    se = exact["se_diff"]
    np.testing.assert_allclose(exact["mean_diff_ci95"], drawn["mean_diff_ci95"], atol=0.08 * se * 3.92)
    np.testing.assert_allclose(exact["d_z_ci95"], drawn["d_z_ci95"], atol=0.02)


@pytest.mark.parametrize("path, integer, max_distinct, n", [(large.PER_VALUE, True, None, 300),
                                                            (large.RAW, True, 0, 300),
                                                            (large.ASYMPTOTIC, False, None, large.LARGE_N + 10)])
def test_mean_only_is_the_same_interval_without_the_rest(rng, monkeypatch, path, integer, max_distinct, n):
    """The engine's paired rows ask for the mean difference's interval alone (`mean_only`): the
    same draws give the same endpoints, bit for bit, on each resampling path, and no sign-flip
    test or d_z interval is computed."""
    if max_distinct is not None:
        monkeypatch.setattr(large, "MAX_DISTINCT", max_distinct)
    x, y = correlated(n, rng, integer=integer)
    full = paired_analysis(x, y, 7, resamples=2_000)
    alone = paired_analysis(x, y, 7, resamples=2_000, mean_only=True)
    assert alone["path"] == full["path"] == path and alone["mean_diff_ci95"] == full["mean_diff_ci95"]
    assert "p_sign_flip" in full and "d_z_ci95" in full
    assert "p_sign_flip" not in alone and "d_z_ci95" not in alone


def test_sign_flip_matches_full_enumeration(rng):
    d = np.array([3.0, -1.0, 2.0, 2.0, 5.0, -2.0, 1.0, 4.0, 0.0, 3.0, 1.0, -1.0])
    signs = np.array(list(itertools.product([-1, 1], repeat=d.size)))
    exact = np.mean(np.abs(signs @ d) >= abs(d.sum()) - 1e-12)
    values, counts = np.unique(d, return_counts=True)
    import jax

    p = sign_flip_p(d, values, counts, jax.random.key(3), 40_000)["p_sign_flip"]
    assert abs(p - exact) < 4 * np.sqrt(exact * (1 - exact) / 40_000) + 1e-4


def test_null_paired_tests_hold_their_level(rng):
    """No true difference: paired t and sign-flip reject at about α over many data sets."""
    import jax

    rejections = np.zeros(2)
    for i in range(300):
        x, y = correlated(60, rng, shift=0.0)
        r = paired_analysis(x, y, jax.random.key(i), resamples=400)
        rejections += [r["p_paired_t"] <= 0.05, r["p_sign_flip"] <= 0.05]
    rate = rejections / 300
    assert np.all(rate < 0.05 + 3 * np.sqrt(0.05 * 0.95 / 300)), rate


def test_continuous_large_n_uses_normal_limits(rng):
    x, y = correlated(large.LARGE_N + 10, rng, integer=False)
    r = paired_analysis(x, y, 0, resamples=200)
    assert "normal" in r["bootstrap"] and "normal" in r["sign_flip"]
    d = y - x
    half = 1.96 * d.std(ddof=1) / np.sqrt(d.size)
    np.testing.assert_allclose(r["mean_diff_ci95"], [d.mean() - half, d.mean() + half], atol=0.02 * half)


def test_compare_pairs_a_shared_key_run_unless_told_not_to(tmp_path, capsys):
    out = tmp_path / "run"
    small = ["--seeds", "30", "--trials", "10", "--chances", "15", "--quiet"]
    assert main(["grid", *small, "--out", str(out)]) == 0
    stats = json.loads((out / "stats.json").read_text())
    assert stats["analysis"] == "paired" and set(stats["paired"]["measures"]) >= {"successes"}
    in_memory = stats["paired"]
    assert "## Paired analysis" in (out / "report.md").read_text()
    assert main(["compare", str(out)]) == 0
    again = json.loads((out / "stats.json").read_text())
    assert again["paired"] == in_memory  # read back from the folder: the same paired results
    assert main(["compare", str(out), "--unpaired"]) == 0
    unpaired = json.loads((out / "stats.json").read_text())
    assert unpaired["analysis"] == "unpaired" and "paired" not in unpaired
    assert "## Paired analysis" not in (out / "report.md").read_text()
    assert unpaired["primary"] == again["primary"]  # the unpaired results do not move


@pytest.mark.parametrize("bad", [([1.0, 2.0], [1.0]), ([1.0], [2.0])])
def test_paired_needs_the_same_seeds(bad):
    with pytest.raises(ValueError, match="same seeds"):
        paired_analysis(np.array(bad[0]), np.array(bad[1]), 0)


def test_paired_on_unequal_seeds_is_one_clear_error(tmp_path, capsys, rng):
    """Seeds of unequal count: compare falls back to unpaired, and --paired is one error line."""
    success = {"ac": rng.random((30, 6)) < 0.4, "eac": rng.random((25, 6)) < 0.6}
    np.savez(tmp_path / "curves.npz", **success)
    rows = ["algo,seed,successes,steps,first_success"]
    for algo, s in success.items():
        first = np.where(s.any(1), s.argmax(1) + 1, -1)
        rows += [f"{algo},{i},{s[i].sum()},0,{first[i]}" for i in range(len(s))]
    (tmp_path / "per_seed.csv").write_text("\n".join(rows) + "\n")
    (tmp_path / "summary.json").write_text(json.dumps({"experiment": "grid", "primary_measure": "successes",
                                                       "algos": ["ac", "eac"], "trials": 6}))
    assert main(["compare", str(tmp_path), "--resamples", "200"]) == 0
    assert json.loads((tmp_path / "stats.json").read_text())["analysis"] == "unpaired"
    before = (tmp_path / "stats.json").read_text()
    capsys.readouterr()
    assert main(["compare", str(tmp_path), "--paired", "--resamples", "200"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: --paired needs the same seeds") and len(err.splitlines()) == 1
    assert (tmp_path / "stats.json").read_text() == before  # nothing rewritten


def test_pairing_of_a_table(tmp_path, capsys):
    """A table pairs where two algorithms ran the same seed ids (the paired result answers, the
    unpaired one is secondary); --paired refuses other seeds, --unpaired leaves pairing out."""
    table = tmp_path / "t.csv"
    table.write_text("algo,seed,value\na,0,1\na,1,2\na,2,4\nb,0,3\nb,1,5\nb,2,6\n")
    assert main(["compare", "--table", str(table), "--paired", "--resamples", "400"]) == 0
    out = capsys.readouterr().out
    assert "b - a, paired (same seeds): +2.3333" in out and "unpaired (secondary)" in out
    res = json.loads((tmp_path / "t_compare" / "stats_table.json").read_text())
    (row,) = res["rows"]
    assert row["analysis"] == "paired" and row["p"] == row["paired"]["p_paired_t"]
    assert row["paired"]["p_paired_t"] == pytest.approx(sps.ttest_rel([3, 5, 6], [1, 2, 4]).pvalue)
    assert main(["compare", "--table", str(table), "--unpaired", "--resamples", "400", "--out",
                 str(tmp_path / "u")]) == 0
    assert json.loads((tmp_path / "u" / "stats_table.json").read_text())["rows"][0]["paired"] is None
    other = tmp_path / "o.csv"
    other.write_text("algo,seed,value\na,0,1\na,1,2\nb,7,3\nb,8,4\n")
    capsys.readouterr()
    assert main(["compare", "--table", str(other), "--paired", "--resamples", "400"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: --paired needs the same seed ids") and len(err.splitlines()) == 1
    assert not (tmp_path / "o_compare").exists()


def test_one_resampling_rule_for_paired_differences(rng):
    """Run folders and the engine take a paired interval's path from `large.resampling_path`
    (paired: counts per distinct difference wherever they are few, at any n) and record it."""
    from jaxeac.perseed import PerSeed
    from jaxeac.stats.engine import compare

    assert large.resampling_path(50, 10, paired=True) == large.PER_VALUE
    assert large.resampling_path(50, 10) == large.RAW  # unpaired groups: raw draws up to LARGE_N
    assert large.resampling_path(50, large.MAX_DISTINCT + 1, paired=True) == large.RAW
    # differences that do not repeat gain nothing from counts per value (1,000 continuous paired
    # seeds took 6x longer per value): raw draws, as unpaired
    assert large.resampling_path(1000, 1000, paired=True) == large.RAW
    assert large.resampling_path(50, 26, paired=True) == large.RAW
    assert large.resampling_path(50, 25, paired=True) == large.PER_VALUE
    assert large.resampling_path(10**6, 1000, paired=True) == large.PER_VALUE
    assert large.resampling_path(large.LARGE_N + 1, large.MAX_DISTINCT + 1, paired=True) == large.ASYMPTOTIC
    x, y = correlated(60, rng)  # integers: few distinct differences
    assert paired_analysis(x, y, 3, resamples=400)["path"] == large.PER_VALUE
    seeds = np.arange(60).astype(str)
    per = PerSeed({"": {"a": x, "b": y}}, {"": {"a": seeds, "b": seeds}}, "value", "arrays", "arrays", {})
    (row,) = compare(per, resamples=400, key=5).rows
    assert row["paired"]["path"] == large.PER_VALUE
    n = large.MAX_DISTINCT + 100
    x2, y2 = correlated(n, rng, integer=False)  # continuous: every difference distinct, more than a
    ids = np.arange(n).astype(str)  # per-value path takes
    per2 = PerSeed({"": {"a": x2, "b": y2}}, {"": {"a": ids, "b": ids}}, "value", "arrays", "arrays", {})
    (row2,) = compare(per2, resamples=400, key=5).rows
    pr = row2["paired"]
    assert pr["path"] == large.RAW and pr["mean_diff_ci"][0] < pr["mean_diff"] < pr["mean_diff_ci"][1]
