"""`jaxeac compare --table`: tidy tables, SB3 monitor folders and rliable arrays (jaxeac.stats.engine)."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from jaxeac.cli import main
from jaxeac.perseed import read_npz, read_tidy
from jaxeac.sb3 import read_sb3
from jaxeac.stats import a12, holm, iqm
from jaxeac.stats.engine import compare
from jaxeac.stats.tasks import prob_improvement

FAST = ["--resamples", "400"]


def write_csv(path, rows, header="algo,seed,value"):
    path.write_text(header + "\n" + "".join(",".join(map(str, r)) + "\n" for r in rows))
    return path


def tiny_rows():
    return [("a", s, v) for s, v in enumerate([1.0, 2.0, 4.0, 3.0])] + \
           [("b", s, v) for s, v in enumerate([2.0, 5.0, 3.0, 6.0, 7.0])] + \
           [("c", s, v) for s, v in enumerate([0.0, 1.0, 1.0])]


# ---------------------------------------------------------------- golden values by hand
def test_probability_of_improvement_by_hand():
    # pairs (1,0) (1,3) (2,0) (2,3): wins 1, 0, 1, 0 -> 2/4
    assert prob_improvement([1, 2], [0, 3]) == 0.5
    # pairs (1,1) tie = 1/2, (1,3) 0, (2,1) 1, (2,3) 0 -> 1.5/4
    assert prob_improvement([1, 2], [1, 3]) == 0.375
    assert prob_improvement([5, 6], [1, 2]) == 1.0
    x, y = np.array([3.0, 1, 4, 1, 5]), np.array([2.0, 7, 1, 8])
    assert prob_improvement(x, y) == pytest.approx(a12(y, x).estimate)


def test_iqm_and_holm_by_hand():
    assert iqm([1, 2, 3, 4, 5, 6, 7, 100]) == 4.5  # middle half: 3, 4, 5, 6
    # sorted 0.01, 0.03, 0.04 -> 3·0.01, max(0.03, 2·0.03), max(0.06, 1·0.04)
    np.testing.assert_allclose(holm([0.01, 0.04, 0.03]), [0.03, 0.06, 0.06])


def test_all_pairs_table_by_hand(tmp_path):
    table = write_csv(tmp_path / "runs.csv", tiny_rows())
    assert main(["compare", "--table", str(table), *FAST]) == 0
    out = tmp_path / "runs_compare"
    assert sorted(p.name for p in out.iterdir()) == ["report_table.md", "stats_table.json"]
    res = json.loads((out / "stats_table.json").read_text())
    assert res["family"] == "all pairs" and res["family_size"] == 3 and res["level"] == 0.95
    rows = res["rows"]
    assert [(r["x"], r["y"]) for r in rows] == [("b", "a"), ("c", "a"), ("c", "b")]
    assert all(r["analysis"] == "unpaired" and r["paired"] is None for r in rows)  # different seed ids
    vals = {"a": [1.0, 2, 4, 3], "b": [2.0, 5, 3, 6, 7], "c": [0.0, 1, 1]}
    welch = [stats.ttest_ind(vals[r["x"]], vals[r["y"]], equal_var=False).pvalue for r in rows]
    ba = rows[0]
    assert (ba["n_x"], ba["n_y"], ba["mean_x"], ba["mean_y"]) == (5, 4, 4.6, 2.5)
    assert ba["diff"] == pytest.approx(2.1)
    # b vs a: a's 1 loses to all 5, 2: 4 wins + tie, 4: 3 wins, 3: 3 wins + tie -> 16/20 for b
    assert ba["p_improvement"] == pytest.approx(1 - (0 + 0.5 + 2 + 1.5) / 20)
    iqm_a = next(a for a in res["algorithms"] if a["algo"] == "a")
    assert iqm_a["iqm"] == pytest.approx(2.5)  # a sorted 1 2 3 4: middle 2, 3
    for r, p, adj in zip(rows, welch, holm(welch), strict=True):
        assert r["p_welch"] == pytest.approx(p) and r["p_holm"] == pytest.approx(adj)
        for name in ("diff", "p_improvement"):
            lo, hi = r[f"{name}_ci"]
            assert lo <= r[name] <= hi
    report = (out / "report_table.md").read_text()
    assert "| b | a | unpaired |" in report and "Holm" in report


def test_baseline_family(tmp_path, capsys):
    table = write_csv(tmp_path / "runs.csv", tiny_rows())
    out = tmp_path / "mine"
    assert main(["compare", "--table", str(table), "--baseline", "b", "--out", str(out), *FAST]) == 0
    res = json.loads((out / "stats_vs_b.json").read_text())
    assert [(r["x"], r["y"]) for r in res["rows"]] == [("a", "b"), ("c", "b")]
    assert res["family"] == "all vs baseline b"
    assert "per-seed value: its row's 'value'" in capsys.readouterr().out


def test_trials_aggregate(tmp_path, capsys):
    per_seed = {"a": [[1, 2, 3], [0, 0, 6], [2, 2, 2]], "b": [[5, 1, 0], [1, 1, 1]]}
    rows = [(a, s, t, v) for a, seeds in per_seed.items()
            for s, vs in enumerate(seeds) for t, v in enumerate(vs)]
    table = write_csv(tmp_path / "t.csv", rows, "algo,seed,trial,value")
    per = read_tidy(table, aggregate="sum")
    assert per.values[""]["a"].tolist() == [6, 6, 6] and per.values[""]["b"].tolist() == [6, 3] and "sum" in per.what
    assert read_tidy(table, aggregate="mean").values[""]["a"].tolist() == [2, 2, 2]
    assert read_tidy(table, aggregate="last").values[""]["a"].tolist() == [3, 6, 2]
    assert main(["compare", "--table", str(table), "--aggregate", "mean", *FAST]) == 0
    assert "the mean of the value column over its trials" in capsys.readouterr().out
    res = json.loads((tmp_path / "t_compare" / "stats_table.json").read_text())
    assert res["source"]["aggregate"] == "mean"


def test_csv_and_parquet_agree(tmp_path):
    rng = np.random.default_rng(3)
    frame = pd.DataFrame({"algo": np.repeat(["x", "y", "z"], 30), "seed": np.tile(np.arange(30), 3),
                          "value": rng.normal(size=90)})
    frame.to_csv(tmp_path / "t.csv", index=False)
    frame.to_parquet(tmp_path / "t.parquet", index=False)
    outs = []
    for name in ("t.csv", "t.parquet"):
        out = tmp_path / f"out_{name}"
        assert main(["compare", "--table", str(tmp_path / name), "--out", str(out), *FAST]) == 0
        res = json.loads((out / "stats_table.json").read_text())
        res["source"].pop("source")
        outs.append(res)
    assert outs[0] == outs[1]


def test_sb3_importer(tmp_path):
    head = '#{"t_start": 1700000000.0, "env_id": "CartPole-v1"}\nr,l,t\n'

    def monitor(path, rewards):
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(head + "".join(f"{r},10,{i * 0.1:.1f}\n" for i, r in enumerate(rewards)))

    # 20 episodes: the last 10 % are the last 2
    monitor(tmp_path / "sb3" / "ppo" / "0" / "monitor.csv", list(range(18)) + [10, 20])
    monitor(tmp_path / "sb3" / "ppo" / "1" / "monitor.csv", [0] * 18 + [30, 30])
    monitor(tmp_path / "sb3" / "a2c_0.monitor.csv", [1, 2, 3])  # 3 episodes: the last one
    monitor(tmp_path / "sb3" / "a2c_1.monitor.csv", [4, 5])
    per = read_sb3(tmp_path / "sb3")
    assert per.values[""]["ppo"].tolist() == [15.0, 30.0] and per.values[""]["a2c"].tolist() == [3.0, 5.0]
    assert "last 10%" in per.what
    assert main(["compare", "--table", str(tmp_path / "sb3"), *FAST]) == 0
    res = json.loads((tmp_path / "sb3_compare" / "stats_table.json").read_text())
    assert res["source"]["format"] == "sb3" and res["rows"][0]["n_x"] == 2


def test_rliable_importer(tmp_path):
    scores = {"dqn": np.array([[1.0, 3.0], [2.0, 2.0], [0.0, 1.0]]),
              "c51": np.array([[4.0, 4.0], [5.0, 3.0]])}
    np.savez(tmp_path / "atari.npz", **scores)
    per = read_npz(tmp_path / "atari.npz")
    assert per.tasks == ["task0", "task1"] and per.values["task1"]["dqn"].tolist() == [3.0, 2.0, 1.0]
    assert main(["compare", "--table", str(tmp_path / "atari.npz"), "--baseline", "dqn", *FAST]) == 0
    res = json.loads((tmp_path / "atari_compare" / "stats_vs_dqn.json").read_text())
    assert [(r["task"], r["x"], r["y"]) for r in res["rows"]] == [("task0", "c51", "dqn"), ("task1", "c51", "dqn")]
    # task1: c51 [4, 3] against dqn [3, 2, 1]: 4 beats all three; 3 ties 3 and beats 2 and 1
    assert [r["p_improvement"] for r in res["rows"]] == [1.0, pytest.approx(5.5 / 6)]
    assert res["aggregate"] is None  # no normalisation stated: no aggregate across tasks


def test_many_algorithms_smaller_size():
    """The 10 × 1,000 × 10,000-resample case (timed in BENCHMARKS.md) at a smaller size."""
    rng = np.random.default_rng(0)
    samples = {f"algo{i}": rng.normal(0.1 * i, 1.0, 200) for i in range(5)}
    res = compare(samples, resamples=2000, key=1)
    assert len(res.rows) == 10
    last = res.rows[-1]  # algo4 vs algo3
    assert (last["x"], last["y"]) == ("algo4", "algo3")
    lo, hi = last["p_improvement_ci"]
    assert lo < last["p_improvement"] < hi and hi - lo < 0.25
    again = compare(samples, resamples=2000, key=1)
    assert again.to_dict() == res.to_dict()  # reproducible from the key


# ---------------------------------------------------------------- bad input
BAD = {
    "missing column": ("algo,seed,score\na,0,1\nb,0,2\n", "'value'"),
    "non-numeric": ("algo,seed,value\na,0,1\na,1,2\nb,0,oops\nb,1,3\n", "row 3"),
    "NaN": ("algo,seed,value\na,0,1\na,1,NaN\nb,0,2\nb,1,3\n", "1 failed seed(s) excluded"),
    "empty value": ("algo,seed,value\na,0,1\na,1,2\nb,0,\nb,1,3\n", "algo 'b' has 1 seed(s)"),
    "one algorithm": ("algo,seed,value\na,0,1\na,1,2\n", "'algo'"),
    "one seed": ("algo,seed,value\na,0,1\na,1,2\nb,0,3\n", "'b'"),
    "repeated seed": ("algo,seed,value\na,0,1\na,0,2\nb,0,3\nb,1,3\n", "row 2"),
    "unequal trials": ("algo,seed,trial,value\na,0,0,1\na,0,1,1\na,1,0,2\nb,0,0,1\nb,1,0,1\n", "seed '1'"),
    "non-numeric trial": ("algo,seed,trial,value\na,0,x,1\na,1,0,2\nb,0,0,1\nb,1,0,1\n", "'trial'"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_table(tmp_path, capsys, case):
    text, named = BAD[case]
    table = tmp_path / "bad.csv"
    table.write_text(text)
    assert main(["compare", "--table", str(table), *FAST]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and named in err
    assert not (tmp_path / "bad_compare").exists()


def test_bad_baseline_and_npz(tmp_path, capsys):
    table = write_csv(tmp_path / "runs.csv", tiny_rows())
    assert main(["compare", "--table", str(table), "--baseline", "zz", *FAST]) == 2
    assert "'zz'" in capsys.readouterr().err
    np.savez(tmp_path / "r.npz", a=np.ones((3, 2)), b=np.ones((3, 4)))
    assert main(["compare", "--table", str(tmp_path / "r.npz"), *FAST]) == 2
    assert "tasks" in capsys.readouterr().err
    np.savez(tmp_path / "n.npz", a=np.array([[1.0], [np.nan]]), b=np.ones((3, 1)))
    assert main(["compare", "--table", str(tmp_path / "n.npz"), *FAST]) == 2
    assert "algo 'a' has 1 seed(s) (1 failed seed(s) excluded)" in capsys.readouterr().err
    assert not any(p.name.endswith("_compare") for p in tmp_path.iterdir())
