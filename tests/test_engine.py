"""The statistics engine (`jaxeac.stats.engine.compare`): pinned run-folder numbers, the BCa tie
rule, parity with scipy and with rliable's definitions across tasks, bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from jaxeac.cli import main
from jaxeac.perseed import PerSeed
from jaxeac.stats.bca import bca_interval, jackknife_iqm
from jaxeac.stats.engine import compare
from jaxeac.stats.resample import boot_counts, bootstrap_sums

PINNED = Path(__file__).parent / "data" / "stats_10k_before.json"
#: Intervals the first BCa tie fix moved (integer-valued IQMs and paired AUC differences): within 1e-4.
TIE_FIXED = ("iqm_baseline_ci", "iqm_treatment_ci", "mean_diff_ci")


def _skip(path: str, k: str) -> bool:
    return (k in ("timing", "run_dir", "versions") or (path.endswith("/settings") and k == "alpha")
            or (k == "alpha" and path.endswith("/calibration")))


@pytest.mark.slow
def test_run_folder_numbers_pinned_at_10k_seeds(tmp_path):
    """Every number of a 10,000-seed run folder's stats.json as before the engine, apart from the
    tie fixes and the key renames: the first (BCa endpoints of integer-valued statistics, within
    1e-4), then replicates kept in float64 (`test_stats_scale.assert_as_pinned`'s rule: every
    non-resampled number the same, resampled ones within its tolerances)."""
    from test_stats_scale import assert_number_as_pinned, pinned_leaves

    import jaxeac

    out = tmp_path / "run"
    jaxeac.run("grid-paper-v0", ["ac", "eac"], seeds=10_000, key=0, out=out)
    res = jaxeac.compare(out)
    assert res.stats["level"] == 0.95 and res.rows[0]["analysis"] == "paired"
    new = json.loads((out / "stats.json").read_text())
    moved = 0
    for path, a, b, width in pinned_leaves(json.loads(PINNED.read_text()), new, "", _skip):
        if any(f"/{k}[" in path or f"/{k}95[" in path for k in TIE_FIXED):
            moved += a != b
            assert b == pytest.approx(a, rel=1e-4), path
        else:
            assert_number_as_pinned(path, a, b, width)
    assert moved > 0  # the tie fix did move the integer IQM intervals


def test_bca_ties_in_the_replicates_precision():
    """Integer data: the IQM replicates (kept in float64) are those of the same resamples computed
    from their counts, ties with the estimate count one half (before the fix every tie counted as
    below), and scipy's BCa agrees within Monte-Carlo error."""
    from jaxeac.rng import as_key
    from jaxeac.stats import large

    x = np.random.default_rng(5).binomial(12, 0.5, 80).astype(float)
    key, R = as_key(7), 4000
    _, q = bootstrap_sums(key, np.sort(x)[:, None], R, iqm=True)
    counts = boot_counts(key, x.size, R).astype(np.float64)
    q64 = large.iqm_from_counts(counts, np.sort(x))
    np.testing.assert_allclose(q, q64, rtol=1e-12)
    est = float(stats.trim_mean(x, 0.25))
    assert (q64 == est).sum() > 100  # many ties with the estimate
    ours = bca_interval(est, q, [jackknife_iqm(x)])
    exact = bca_interval(est, q64, [jackknife_iqm(x)])
    assert ours == pytest.approx(exact, abs=1e-12)  # the same quantiles
    ref = stats.bootstrap((x,), lambda s, axis: stats.trim_mean(s, 0.25, axis=axis), n_resamples=R,
                          method="BCa", random_state=1).confidence_interval
    assert ours[0] == pytest.approx(ref.low, abs=0.2) and ours[1] == pytest.approx(ref.high, abs=0.2)


def test_two_sample_parity_with_scipy():
    rng = np.random.default_rng(2)
    a, b = rng.normal(0, 1, 60), rng.normal(0.4, 2, 45)
    res = compare({"a": a, "b": b}, baseline="a", resamples=4000, key=3)
    (r,) = res.rows
    assert r["p_welch"] == pytest.approx(stats.ttest_ind(b, a, equal_var=False).pvalue, rel=1e-10)
    ref = stats.bootstrap((a, b), lambda x, y, axis: y.mean(axis) - x.mean(axis), method="BCa",
                          n_resamples=4000, random_state=0).confidence_interval
    assert r["diff_ci"][0] == pytest.approx(ref.low, abs=0.08)
    assert r["diff_ci"][1] == pytest.approx(ref.high, abs=0.08)


def _rliable_reference(scores: dict, reps: int, seed: int = 0):
    """rliable's definitions (Agarwal et al. 2021), written independently: aggregates over the
    flattened [runs, tasks] scores (mean and median: of the per-task means), a stratified bootstrap of runs within each task, percentile
    intervals. The numbers of rliable itself: scripts/rliable_parity.py."""
    rng = np.random.default_rng(seed)

    def agg(s):
        return {"mean": s.mean(0).mean(), "median": np.median(s.mean(0)), "iqm": stats.trim_mean(s.reshape(-1), 0.25),
                "optimality_gap": 1 - np.minimum(s, 1).mean()}

    point = {a: agg(s) for a, s in scores.items()}
    boot = {a: [] for a in scores}
    for _ in range(reps):
        for a, s in scores.items():
            idx = rng.integers(0, s.shape[0], s.shape)  # runs drawn within each task (column)
            boot[a].append(agg(np.take_along_axis(s, idx, 0)))
    ci = {a: {k: np.percentile([b[k] for b in boot[a]], [2.5, 97.5]) for k in point[a]} for a in scores}
    return point, ci


def test_aggregates_across_tasks_match_rliable_definitions():
    rng = np.random.default_rng(11)
    scores = {"A": np.stack([rng.normal(0.5, 0.2, 30), rng.normal(50, 30, 30)], 1),
              "B": np.stack([rng.normal(0.6, 0.2, 30), rng.normal(40, 20, 30)], 1)}
    low_high = {"task0": (0.0, 1.0), "task1": (0.0, 100.0)}
    res = compare(scores, baseline="A", resamples=4000, key=1, normalize="minmax", reference_scores=low_high)
    norm = {a: s / np.array([1.0, 100.0]) for a, s in scores.items()}
    point, ci = _rliable_reference(norm, 2000)
    agg = res.aggregate
    for a in scores:
        for k in point[a]:
            assert agg["algorithms"][a][k]["estimate"] == pytest.approx(point[a][k], rel=1e-12), (a, k)
            lo, hi = agg["algorithms"][a][k]["ci"]
            width = ci[a][k][1] - ci[a][k][0]
            assert lo == pytest.approx(ci[a][k][0], abs=0.15 * width) and hi == pytest.approx(ci[a][k][1],
                                                                                                abs=0.15 * width)
    # probability of improvement: the mean over tasks of Mann-Whitney U / (n m)
    (pair,) = agg["pairs"]
    u = [stats.mannwhitneyu(norm["B"][:, j], norm["A"][:, j]).statistic / 900 for j in range(2)]
    assert pair["estimate"] == pytest.approx(np.mean(u), rel=1e-12)
    prof = agg["profiles"]
    tau = np.asarray(prof["tau"])
    np.testing.assert_allclose(prof["B"]["share"], [(norm["B"] > t).mean() for t in tau])


def test_multi_task_table_and_bad_input(tmp_path, capsys):
    rows = ["task,algo,seed,value"]
    rng = np.random.default_rng(0)
    for t in ("easy", "hard"):
        for a in ("x", "y", "z"):
            rows += [f"{t},{a},{s},{rng.normal(1 if t == 'easy' else 100, 1):.4f}" for s in range(8)]
    table = tmp_path / "t.csv"
    table.write_text("\n".join(rows) + "\n")
    assert main(["compare", "--table", str(table), "--baseline", "x", "--normalize", "baseline",
                 "--resamples", "400"]) == 0
    res = json.loads((tmp_path / "t_compare" / "stats_vs_x.json").read_text())
    assert res["tasks"] == ["easy", "hard"] and len(res["rows"]) == 4 and res["aggregate"]["pairs"]
    assert all(r["analysis"] == "paired" for r in res["rows"])  # the same seed ids on every task
    capsys.readouterr()
    bad = {
        ("--tasks", "medium"): "'medium'",
        ("--normalize", "minmax"): "reference scores",
        ("--resamples", "1"): "too few",
        ("--resamples", "1000000000000"): "of work",
    }
    for (flag, value), named in bad.items():
        assert main(["compare", "--table", str(table), "--baseline", "x", "--out", str(tmp_path / "o"),
                     flag, value]) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and err.count("\n") == 1 and named in err, (flag, err)
    assert not (tmp_path / "o").exists()
    one_seed = tmp_path / "one.csv"
    one_seed.write_text("task,algo,seed,value\na,x,0,1\na,x,1,2\na,y,0,3\na,y,1,4\nb,x,0,1\nb,x,1,2\nb,y,0,3\n")
    assert main(["compare", "--table", str(one_seed), "--resamples", "400"]) == 2
    assert "task 'b', algo 'y' has 1 seed(s)" in capsys.readouterr().err
    ragged = tmp_path / "ragged.csv"
    ragged.write_text("task,algo,seed,value\na,x,0,1\na,x,1,2\na,y,0,3\na,y,1,4\nb,x,0,1\nb,x,1,2\n")
    assert main(["compare", "--table", str(ragged), "--resamples", "400"]) == 2
    assert "task 'b' lacks algorithm(s) 'y'" in capsys.readouterr().err
    zeros = tmp_path / "zeros.csv"
    zeros.write_bytes(b"\0" * 100_000)
    assert main(["compare", "--table", str(zeros)]) == 2
    assert "binary data" in capsys.readouterr().err
    np.savez(tmp_path / "empty.npz")
    np.savez(tmp_path / "one.npz", a=np.ones((3, 2)))
    for name in ("empty.npz", "one.npz"):
        assert main(["compare", "--table", str(tmp_path / name)]) == 2
        err = capsys.readouterr().err
        assert "array(s); an rliable-style .npz needs one [runs, tasks] array per algorithm" in err
    with pytest.raises(ValueError, match="every task needs the same algorithms"):
        compare(PerSeed({"a": {"x": np.ones(3), "y": np.ones(3)}, "b": {"x": np.ones(3)}}, None, "", "arrays"))


def test_wilson_bounds_exact_at_none_and_all():
    from statsmodels.stats.proportion import proportion_confint

    from jaxeac.stats import wilson_ci

    assert wilson_ci(0, 200)[0] == 0.0 and wilson_ci(200, 200)[1] == 1.0
    for count in (0, 1, 37, 199, 200):
        ref = proportion_confint(count, 200, alpha=0.05, method="wilson")
        assert wilson_ci(count, 200) == pytest.approx(ref, abs=1e-15)


def test_plain_words_say_p_below_the_floor():
    from jaxeac.fmt import p_is
    from jaxeac.stats.report import plain_words

    def renamed(obj):
        if isinstance(obj, dict):
            return {(k[:-2] if k.endswith("_ci95") or k == "ci95" else k): renamed(v) for k, v in obj.items()}
        return obj

    stats = renamed(json.loads(PINNED.read_text()))
    assert stats["primary"]["p_holm"] == 0.0
    text = plain_words(stats)
    assert "Holm-adjusted p < 1e-4)" in text and "p = <" not in text
    assert p_is(0.0139) == "p = 0.0139" and p_is(2e-5) == "p < 1e-4" and p_is(None) == "p = —"


def test_aggregates_agree_with_rliable_itself():
    """rliable's own numbers on fixed data (tests/data/make_rliable_reference.py says how they
    were made): point estimates identical; 95 % intervals and profile bands within Monte-Carlo
    error (rliable: 50,000 stratified resamples, 10,000 for the pairs and profiles)."""
    ref = json.loads((PINNED.parent / "rliable_reference.json").read_text())
    tasks = list(ref["scores"])
    algos = list(ref["scores"][tasks[0]])
    runs = {a: np.stack([ref["scores"][t][a] for t in tasks], 1) for a in algos}  # rliable's [runs, tasks]
    reference = {f"task{j}": ref["reference"][t] for j, t in enumerate(tasks)}
    res = compare(runs, baseline="A", resamples=20_000, key=3, normalize="minmax",
                  reference_scores=reference, profile_points=ref["tau"])
    agg = res.aggregate
    assert agg["profiles"]["tau"] == ref["tau"]
    for a in algos:
        for k, want in ref["algorithms"][a].items():
            got = agg["algorithms"][a][k]
            assert got["estimate"] == pytest.approx(want["estimate"], rel=1e-12, abs=1e-15), (a, k)
            width = want["ci"][1] - want["ci"][0]
            assert got["ci"] == pytest.approx(want["ci"], abs=0.06 * width), (a, k)
        prof, want = agg["profiles"][a], ref["profiles"][a]
        assert prof["share"] == pytest.approx(want["share"], abs=1e-12)
        assert prof["low"] == pytest.approx(want["low"], abs=0.05) and prof["high"] == pytest.approx(want["high"], abs=0.05)
    for want in ref["pairs"]:
        (got,) = [p for p in agg["pairs"] if (p["x"], p["y"]) == (want["x"], want["y"])]
        assert got["estimate"] == pytest.approx(want["estimate"], rel=1e-12)
        width = want["ci"][1] - want["ci"][0]
        assert got["ci"] == pytest.approx(want["ci"], abs=0.06 * width)


def test_tables_refused_before_reading(tmp_path, capsys):
    """A text table over the size limit is refused from its size alone (nothing read), a first
    line too long to be a header is quoted only in a short excerpt, and resamples too few for
    the level's tails are refused."""
    from jaxeac.perseed import MAX_TEXT_BYTES

    big = tmp_path / "big.csv"
    with open(big, "wb") as fh:  # sparse: a header, then a hole past the limit
        fh.write(b"algo,seed,value\n")
        fh.truncate(MAX_TEXT_BYTES + (1 << 20))
    assert main(["compare", "--table", str(big)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and "1.0 GiB" in err and "Parquet" in err
    long_line = tmp_path / "line.csv"
    long_line.write_text("x" * 300_000)
    assert main(["compare", "--table", str(long_line)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and len(err) < 400 and "first line" in err
    table = tmp_path / "t.csv"
    table.write_text("algo,seed,value\n" + "".join(f"{a},{s},{s * (a == 'b')}\n" for a in "ab" for s in range(5)))
    for few in ("1", "2"):
        assert main(["compare", "--table", str(table), "--resamples", few, "--out", str(tmp_path / "o")]) == 2
        assert "too few" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_dataframe_is_the_table_read_from_a_file(tmp_path):
    """A tidy table in memory (a pandas DataFrame, as in a notebook) gives the very result of the
    same table read from CSV and from Parquet, through `compare` and through `jaxeac.compare`."""
    import pandas as pd

    import jaxeac

    rng = np.random.default_rng(4)
    rows = [(t, a, s, k) for t in ("p", "q") for a in ("x", "y", "z") for s in range(6) for k in range(3)]
    frame = pd.DataFrame(rows, columns=["task", "algo", "seed", "trial"])
    frame["value"] = rng.normal(frame.trial + (frame.algo == "y"), 1)
    frame.loc[5, "value"] = np.nan  # a failed seed, excluded and counted as from a file
    frame.to_csv(tmp_path / "t.csv", index=False)
    frame.to_parquet(tmp_path / "t.parquet")

    def numbers(res):
        d = res.to_dict()
        return json.dumps({k: d[k] for k in ("rows", "algorithms", "tasks")}, sort_keys=True, default=str)

    settings = dict(baseline="x", resamples=400, key=2)
    want = numbers(compare(tmp_path / "t.csv", **settings))
    assert numbers(compare(tmp_path / "t.parquet", **settings)) == want
    got = compare(frame, **settings)
    assert numbers(got) == want and got.source["excluded_total"] == 1
    assert list(frame.columns) == ["task", "algo", "seed", "trial", "value"]  # the caller's frame as it was
    one = frame[frame.task == "p"].drop(columns="task")
    top = jaxeac.compare(one, resamples=400, key=2)  # one task: every pair
    assert numbers(top) == numbers(compare(one, resamples=400, key=2)) and len(top.rows) == 3


def test_bad_tables_each_refused_in_one_line(tmp_path, capsys):
    """The bad inputs of the table path, each an exit code 2 and one line naming what is wrong (and
    quoting at most a short printable excerpt), with nothing written."""
    good = "".join(f"{t},{a},{s},{s + (a == 'y')}\n" for t in "pq" for a in "xy" for s in range(4))
    files = {
        "latin1.csv": "task,algo,seed,value\n".encode() + "p,caf\u00e9,0,1\n".encode("latin-1") * 3,
        "zeros.csv": b"\0" * 100_000,
        "garbage.csv": bytes(range(1, 256)) * 400,
        "one_seed.csv": ("task,algo,seed,value\n" + good + "r,x,0,1\nr,y,0,2\nr,x,1,1\n").encode(),
        "ragged.csv": ("task,algo,seed,value\n" + good + "r,x,0,1\nr,x,1,2\n").encode(),
        "good.csv": ("task,algo,seed,value\n" + good).encode(),
    }
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    np.savez(tmp_path / "empty.npz")
    np.savez(tmp_path / "one.npz", a=np.ones((3, 2)))
    cases = [
        (["latin1.csv"], "is not UTF-8 text (byte"),
        (["zeros.csv"], "holds binary data"),
        (["garbage.csv"], "is not UTF-8 text (byte"),
        (["empty.npz"], "holds 0 array(s)"),
        (["one.npz"], "holds 1 array(s)"),
        (["one_seed.csv"], "task 'r', algo 'y' has 1 seed(s)"),
        (["ragged.csv"], "task 'r' lacks algorithm(s) 'y'"),
        (["good.csv", "--resamples", "1000000000000"], "of work"),
        (["good.csv", "--resamples", "2"], "too few"),
        (["good.csv", "--normalize", "minmax"], "reference scores"),
        (["good.csv", "--tasks", "nowhere"], "--tasks names 'nowhere', which is not in"),
    ]
    for (name, *flags), named in cases:
        code = main(["compare", "--table", str(tmp_path / name), "--out", str(tmp_path / "o"), *flags])
        err = capsys.readouterr().err
        assert code == 2 and err.startswith("error: ") and err.count("\n") == 1 and named in err, (name, err)
        assert len(err) < 400 and "\\x" not in err and "column 'algo'" not in err, (name, err)
    assert not (tmp_path / "o").exists()
