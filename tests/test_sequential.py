"""Sequential comparisons (`jaxeac.stats.sequential`): boundaries against published values and
by simulation, error rates at their nominal level, the stopping rule, and `jaxeac grid --sequential`."""

from __future__ import annotations

import json

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from jaxeac.cli import main
from jaxeac.errors import UsageError
from jaxeac.stats.sequential import SequentialDesign, boundaries, look, run_sequential, simulate, spending


def test_boundaries_match_published_values():
    """Lan-DeMets spending, 5 equally spaced looks, two-sided α = 0.05 (Jennison & Turnbull 2000,
    Table 7.6; the values of R's ldbounds and gsDesign): O'Brien-Fleming and Pocock type."""
    t = np.arange(1, 6) / 5
    published = [4.8769, 3.3569, 2.6803, 2.2898, 2.0310]
    np.testing.assert_allclose(boundaries(t, 0.05, "obrien_fleming"), published, atol=2e-4)
    np.testing.assert_allclose(boundaries(t, 0.05, "pocock"), [2.4380, 2.4268, 2.4101, 2.3966, 2.3859],
                               atol=2e-4)
    np.testing.assert_allclose(boundaries([1.0], 0.05), [1.959964], atol=1e-6)  # one look: the fixed test


@pytest.mark.parametrize("spend", ["obrien_fleming", "pocock"])
def test_boundaries_spend_alpha_as_declared_by_simulation(spend):
    """Brownian motion seen at uneven looks: the share of paths first crossing at look k is
    2·(f(t_k) − f(t_{k−1})) within Monte Carlo error."""
    t = np.array([0.15, 0.4, 0.55, 0.8, 1.0])
    c = boundaries(t, 0.1, spend)
    rng = np.random.default_rng(3)
    paths = 400_000
    s = np.cumsum(rng.standard_normal((paths, t.size)) * np.sqrt(np.diff(t, prepend=0.0)), axis=1)
    crossed = np.abs(s / np.sqrt(t)) >= c
    first = np.where(crossed.any(1), crossed.argmax(1), -1)
    spent = np.array([spending(spend, x, 0.1) for x in t])
    expected = 2 * np.diff(spent, prepend=0.0)
    observed = np.bincount(first[first >= 0], minlength=t.size) / paths
    se = np.sqrt(expected * (1 - expected) / paths)
    assert np.all(np.abs(observed - expected) < 4 * se + 1e-6), (observed, expected)


def test_error_rates_at_most_nominal_by_simulation():
    """≥ 1,000 simulated sequential experiments: a false "difference" under no difference, and a
    false "no difference" at a true difference of the declared effect, each ≤ α + 2 SE."""
    design = SequentialDesign(effect=0.3, max_seeds=400, looks=4, alpha=0.05)
    rng = np.random.default_rng(11)
    pool = rng.normal(0.0, 1.0, 100_000)
    null = simulate(design, pool, None, 2000, rng)
    assert not null["with_replacement"]
    fp = null["decisions"]["difference"]
    assert fp["rate"] <= 0.05 + 2 * fp["se"], null
    shifted = simulate(design, pool, pool + 0.3, 2000, rng)
    miss = shifted["decisions"]["no difference"]
    assert miss["rate"] <= 0.05 + 2 * miss["se"], shifted
    assert shifted["decisions"]["difference"]["rate"] > 0.5  # and it finds the difference mostly
    assert sum(v["count"] for v in null["decisions"].values()) == 2000


def test_look_decisions_by_hand():
    b = np.array([0.0, 2.0, 4.0, 6.0])  # mean 3, var 20/3
    t = b + 10.0
    r = look(b, t, 2.0, effect=1.0, last=False)
    se = np.sqrt(2 * (20 / 3) / 4)
    assert r["diff"] == 10.0 and np.isclose(r["se"], se)
    np.testing.assert_allclose(r["rci"], [10 - 2 * se, 10 + 2 * se])
    assert r["decision"] == "difference"
    assert look(b, b + 0.01, 2.0, effect=100.0, last=False)["decision"] == "no difference"
    assert look(b, b + 0.01, 2.0, effect=1.0, last=False)["decision"] == "continue"
    assert look(b, b + 0.01, 2.0, effect=1.0, last=True)["decision"] == "undecided"


def test_run_sequential_stops_at_the_first_decision_with_consecutive_batches():
    calls = []
    rng = np.random.default_rng(0)

    def measure(first, n):
        calls.append((first, n))
        return rng.normal(0, 1, n), rng.normal(0.8 if first >= 60 else 0.0, 1, n)

    design = SequentialDesign(effect=50.0, max_seeds=100, looks=5)
    out = run_sequential(design, measure)
    assert out["decision"] == "no difference" and len(out["looks_taken"]) == 1 and calls == [(0, 20)]
    calls.clear()
    out = run_sequential(SequentialDesign(effect=0.01, max_seeds=100, looks=5, spend="pocock"), measure)
    assert calls == [(20 * k, 20) for k in range(len(calls))]
    assert [x["seeds"] for x in out["looks_taken"]] == [20 * (k + 1) for k in range(len(calls))]
    assert out["seeds_used"] == out["looks_taken"][-1]["seeds"]


@pytest.mark.parametrize("kwargs, message", [
    ({"effect": 0.0, "max_seeds": 100}, "--effect must be a positive number"),
    ({"effect": float("nan"), "max_seeds": 100}, "--effect must be a positive number"),
    ({"effect": 1.0, "max_seeds": 30, "looks": 5}, "too few for 5 looks"),
    ({"effect": 1.0, "max_seeds": 100, "spend": "linear"}, "unknown alpha spending 'linear'"),
    ({"effect": 1.0, "max_seeds": 100, "alpha": 0.7}, "--error-rate must lie in"),
])
def test_bad_designs_are_one_clear_error(kwargs, message):
    with pytest.raises(UsageError, match=message):
        SequentialDesign(**kwargs)


SMALL = ["--trials", "8", "--chances", "12", "--quiet"]


def test_grid_sequential_end_to_end(tmp_path, capsys):
    """`jaxeac grid --sequential`: stops at a look, keeps exactly the seeds run (those of a fixed
    run, R1), records the design, looks and simulated error rates, and reports the decision."""
    out = tmp_path / "seq"
    assert main(["grid", *SMALL, "--seeds", "60", "--looks", "3", "--sequential", "--effect", "0.5",
                 "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    seq = summary["sequential"]
    assert seq["sizes"] == [20, 40, 60] and seq["decision"] in ("difference", "no difference", "undecided")
    n = seq["seeds_used"]
    assert n == seq["looks_taken"][-1]["seeds"] and summary["seeds"] == n
    assert seq["paired"] and seq["calibration"]["null"]["experiments"] == 1000
    fixed = tmp_path / "fixed"
    assert main(["grid", *SMALL, "--seeds", str(n), "--no-compare", "--out", str(fixed)]) == 0
    def rows(folder):  # one algorithm's rows after the other's, as a fixed run writes them
        table = pq.read_table(folder / "results.parquet")
        table = table.set_column(0, "algo", table["algo"].cast(pa.string()))
        return table.sort_by([("algo", "ascending"), ("seed", "ascending")])

    assert rows(out).equals(rows(fixed))
    report = (out / "report.md").read_text()
    assert "## Sequential decision" in report and f"**{seq['decision']}**" in report
    printed = capsys.readouterr().out
    assert f"sequential decision: {seq['decision']}" in printed


@pytest.mark.parametrize("extra, message", [
    (["--effect", "2"], "--effect only applies with --sequential"),
    (["--looks", "3"], "--looks only applies with --sequential"),
    (["--spending", "bogus"], "--spending only applies with --sequential"),
    (["--error-rate", "0.1"], "--error-rate only applies with --sequential"),
    (["--sequential", "--effect", "2", "--looks", "51"], "--looks must be an integer from 1 to 50"),
    (["--sequential"], "--sequential needs --effect"),
    (["--sequential", "--effect", "2", "--looks", "9"], "too few for 9 looks"),
    (["--sequential", "--effect", "-1"], "--effect must be a positive number"),
    (["--sequential", "--effect", "2", "--algos", "eac", "eac_success_only"], "--algos must include both"),
    (["--sequential", "--effect", "2", "--spending", "steep"], "unknown alpha spending 'steep'"),
])
def test_grid_sequential_bad_flags_exit_2_nothing_written(tmp_path, capsys, extra, message):
    out = tmp_path / "run"
    assert main(["grid", *SMALL, "--seeds", "50", "--out", str(out), *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and len(err.splitlines()) == 1 and message in err
    assert not out.exists() or not any(out.iterdir())


def test_paired_looks_and_their_null_simulation(rng):
    """Paired looks use the SE of the mean per-seed difference; random signs of the differences
    give a null whose false "difference" rate stays ≤ α + 2 SE."""
    from jaxeac.stats.sequential import simulate_paired

    b = np.array([10.0, 12.0, 9.0, 15.0])
    t = b + np.array([1.0, 2.0, 0.0, 1.0])
    r = look(b, t, 2.0, effect=5.0, last=False, paired=True)
    d = t - b
    assert np.isclose(r["se"], d.std(ddof=1) / 2) and r["diff"] == 1.0
    design = SequentialDesign(effect=0.2, max_seeds=300, looks=3)
    pool = rng.normal(0.5, 1.0, 20_000)  # a true mean difference of 0.5
    null = simulate_paired(design, pool, 2000, rng, null=True)
    fp = null["decisions"]["difference"]
    assert fp["rate"] <= 0.05 + 2 * fp["se"], null
    observed = simulate_paired(design, pool, 500, rng, null=False)
    assert observed["decisions"]["difference"]["rate"] > 0.95


def test_bowling_sequential_keeps_the_seeds_of_a_fixed_run(tmp_path, capsys):
    """`jaxeac bowling --sequential` (C physics): paired looks on total pins, the seeds used are
    those of a fixed run of that many seeds (R1), and the report leads with the decision."""
    pytest.importorskip("mujoco")
    out = tmp_path / "seq"
    small = ["--trials", "2", "--angles", "5", "--quiet"]
    assert main(["bowling", *small, "--seeds", "20", "--sequential", "--effect", "4", "--looks", "2",
                 "--out", str(out)]) == 0
    seq = json.loads((out / "summary.json").read_text())["sequential"]
    assert seq["paired"] and seq["sizes"] == [10, 20] and seq["seeds_used"] in (10, 20)
    fixed = tmp_path / "fixed"
    n = str(seq["seeds_used"])
    assert main(["bowling", *small, "--seeds", n, "--no-compare", "--out", str(fixed)]) == 0
    assert (out / "per_seed.csv").read_text() == (fixed / "per_seed.csv").read_text()
    assert "## Sequential decision" in (out / "report.md").read_text()
    assert f"sequential decision: {seq['decision']}" in capsys.readouterr().out


def test_tiny_error_rates_and_many_looks_give_finite_boundaries():
    """A look whose share of α rounds to zero gets a finite boundary (no overflow, no hang)."""
    for alpha, looks in ((1e-300, 5), (0.05, 50)):
        c = SequentialDesign(effect=1.0, max_seeds=looks * 10, looks=looks, alpha=alpha).boundaries()
        assert np.all(np.isfinite(c)) and np.all(c > 0)
