"""The C peer (`scripts/peers/c_peer.c`) and the numba peer (`scripts/peers/numba_peer.py`).

Both are speed peers of jaxeac that follow SPEC with their own random numbers, so:

* golden facts by hand on 1×2 and 1×3 maps, exact or with known probabilities (G3, G4, E1(a),
  E2, E3, E4, (2)–(4) replayed in float32);
* in distribution against jaxeac's `run_seeds` (per-seed totals, Welch and KS, SPEC §6: the
  seed is the unit), paper preset with T = 40;
* reproducibility: same seed → same output, per-seed results independent of the seed count
  and of the threads;
* the two peers share one RNG stream design and float32 arithmetic: they agree seed for seed.

Each peer's tests skip cleanly without a C compiler / without numba (the `bench` extra).
"""

from __future__ import annotations

import numpy as np
import pytest
from peers import c_peer, numba_peer
from scipy import stats

from jaxeac.algorithm.agent import algorithm
from jaxeac.envs.grid import GridWorld, get_map, parse_map
from jaxeac.errors import UsageError
from jaxeac.experiments.presets import make
from jaxeac.running.batch import RunConfig, run_seeds

PAPER = make("paper")
RATES = {"alpha": PAPER.alpha, "beta": PAPER.beta, "gamma": PAPER.gamma, "temperature": PAPER.temperature}
F32 = np.float32

PEERS = [
    pytest.param("c", marks=pytest.mark.skipif(not c_peer.available(), reason="no working C compiler")),
    pytest.param("numba", marks=pytest.mark.skipif(not numba_peer.available(), reason="numba not installed")),
]
RUNNERS = {"c": c_peer.run_c, "numba": numba_peer.run_numba}


@pytest.fixture(params=PEERS)
def run(request):
    return RUNNERS[request.param]


def tiny(run, text, algo, *, chances, trials, n_seeds, seed=7, **kw):
    return run(GridWorld(parse_map(text), chances), algo=algo, trials=trials, n_seeds=n_seeds, seed=seed,
               tables=True, **(RATES | kw))


def record_invariants(out, chances, trials):
    """G5/G7 shape facts that hold for any run."""
    success, steps = out["success"], out["steps"]
    assert success.dtype == bool and steps.dtype == np.int32 and success.shape[1] == trials
    assert ((steps >= 1) & (steps <= chances)).all()
    assert (steps[~success] == chances).all()  # G5: a failed trial used every chance
    np.testing.assert_array_equal(out["successes"], success.sum(1))
    np.testing.assert_array_equal(out["agent_steps"], steps.sum(1))
    first = np.where(success.any(1), success.argmax(1), -1)
    np.testing.assert_array_equal(out["first_success"], first)


# --- golden facts by hand --------------------------------------------------------------------------


def test_eac_one_by_two_map_by_hand(run):
    """Map ".G", C = 1, start cell 0 only. Before the first success, off-grid moves (r = 0, V = 0)
    give δ = 0: the policy stays uniform, so the first success is geometric with p = 1/4 (G3, G4).
    The winning step learns δ = 1 (V = 0.1, p(0, right) = 0.3, E2 on an E1(c) step), and from then
    on the remembered 'right' wins every trial in one step without learning (E1(a), E2, E4)."""
    trials, n = 30, 4000
    out = tiny(run, ".G", "eac", chances=1, trials=trials, n_seeds=n)
    record_invariants(out, 1, trials)
    success, first = out["success"], out["first_success"]
    t = np.arange(trials)[None, :]
    won = first >= 0
    assert (success == (won[:, None] & (t >= first[:, None]))).all()
    np.testing.assert_array_equal(out["values"][won], np.tile([F32(0.1), 0], (won.sum(), 1)))
    np.testing.assert_array_equal(out["preferences"][won, 0], np.tile([F32(0.3), 0, 0, 0], (won.sum(), 1)))
    assert not out["values"][~won].any() and not out["preferences"][~won].any()
    assert (out["policy"][won, 0] == 0).all()
    # the first success is geometric(1/4): goodness of fit over t = 0..5 and "later or never"
    observed = np.array([*(np.sum(first == k) for k in range(6)), np.sum((first >= 6) | (first < 0))])
    p = 0.25 * 0.75 ** np.arange(6)
    expected = n * np.append(p, 1 - p.sum())
    assert stats.chisquare(observed, expected).pvalue > 1e-3


def test_ac_one_by_two_map_replays_in_float32(run):
    """Map ".G", C = 1: AC's critic follows the success sequence alone: a success gives
    δ = (1 + γ·0) − V, a failure (an off-grid stay) δ = (0 + γ·V) − V; V += α·δ and
    p(0, right) += β·δ on successes. Replayed in float32, V(0) and p(0, right) match exactly."""
    trials, n = 40, 1000
    out = tiny(run, ".G", "ac", chances=1, trials=trials, n_seeds=n)
    record_invariants(out, 1, trials)
    alpha, beta, gamma = F32(RATES["alpha"]), F32(RATES["beta"]), F32(RATES["gamma"])
    v, p_right, p_other = np.zeros(n, F32), np.zeros(n, F32), np.zeros(n, np.float64)
    for t in range(trials):
        won = out["success"][:, t]
        delta = np.where(won, (F32(1) + gamma * F32(0)) - v, (F32(0) + gamma * v) - v).astype(F32)
        v = (v + alpha * delta).astype(F32)
        p_right = np.where(won, p_right + beta * delta, p_right).astype(F32)
        p_other += np.where(won, 0.0, float(beta) * delta)
    np.testing.assert_array_equal(out["values"][:, 0], v)
    np.testing.assert_array_equal(out["preferences"][:, 0, 0], p_right)
    np.testing.assert_allclose(out["preferences"][:, 0, 1:].sum(1), p_other, atol=1e-5)
    # trial 0 from a uniform policy: P(success) = 1/4 exactly
    assert stats.binomtest(int(out["success"][:, 0].sum()), n, 0.25).pvalue > 1e-3


def test_eac_one_by_three_map_facts(run):
    """Map "..G" (start cells 0 and 1, G3). Any success ends with 'right' from cell 1, so the success
    memory holds right at cell 1 (E4) and the final policy there is right. After a seed's first
    success a trial takes one step exactly when it starts in cell 1 (E1(a) there; cell 0 needs two
    moves): probability 1/2. On trial 0 (uniform policy) a one-step success has probability 1/8."""
    trials, n, chances = 25, 1500, 40
    out = tiny(run, "..G", "eac", chances=chances, trials=trials, n_seeds=n)
    record_invariants(out, chances, trials)
    won = out["first_success"] >= 0
    assert won.mean() > 0.9
    assert (out["policy"][won, 1] == 0).all()
    after = np.arange(trials)[None, :] > out["first_success"][:, None]
    after &= won[:, None]
    one_step = (out["steps"][after] == 1) & out["success"][after]
    assert stats.binomtest(int(one_step.sum()), int(after.sum()), 0.5).pvalue > 1e-3
    first_trial_one_step = out["success"][:, 0] & (out["steps"][:, 0] == 1)
    assert stats.binomtest(int(first_trial_one_step.sum()), n, 1 / 8).pvalue > 1e-3
    ac = tiny(run, "..G", "ac", chances=chances, trials=trials, n_seeds=n)
    record_invariants(ac, chances, trials)
    ac_one_step = ac["success"][:, 0] & (ac["steps"][:, 0] == 1)
    assert stats.binomtest(int(ac_one_step.sum()), n, 1 / 8).pvalue > 1e-3


# --- in distribution against jaxeac ------------------------------------------------------------------

N_DIST, T_DIST = 400, 40  # fewer trials than the preset's 200 for speed; agreement holds for any T
DIST_CASES = [("ac", 1.0), ("eac", 1.0), ("eac_failure_only", 1.0), ("eac_within_trial", 1.0), ("ac", 0.5)]


@pytest.fixture(scope="module")
def jax_totals():
    """jaxeac's per-seed totals (successes, chances used) on the paper preset, computed once."""
    world = GridWorld(get_map(PAPER.map), PAPER.chances)
    out = {}
    for algo, tau in DIST_CASES:
        cfg = RunConfig(trials=T_DIST, agent=algorithm(algo), **(RATES | {"temperature": tau}))
        r = run_seeds(world, cfg, root_key=2014, n_seeds=N_DIST)
        out[algo, tau] = (r.success.sum(1), r.steps.sum(1))
    return out


@pytest.mark.parametrize(("algo", "tau"), DIST_CASES, ids=[f"{a}-tau{t}" for a, t in DIST_CASES])
def test_agrees_in_distribution_with_jaxeac(run, jax_totals, algo, tau):
    """Welch's t-test on per-seed successes and steps, and KS on successes, must not reject at 0.001."""
    out = run(PAPER.map, algo=algo, trials=T_DIST, chances=PAPER.chances, n_seeds=N_DIST, seed=2014,
              per_trial=False, **(RATES | {"temperature": tau}))
    mine = (out["successes"], out["agent_steps"])
    for name, a, b in zip(("successes", "steps"), jax_totals[algo, tau], mine, strict=True):
        p = stats.ttest_ind(a, b, equal_var=False).pvalue
        assert p > 1e-3, f"{algo} {name}: jaxeac mean {a.mean():.3f}, peer mean {b.mean():.3f}, p = {p:.2g}"
    assert stats.ks_2samp(jax_totals[algo, tau][0], mine[0]).pvalue > 1e-3


def test_distribution_check_has_power(run, jax_totals):
    """The same checks do reject real differences: peer AC against jaxeac EAC, and τ = 1 against τ = 0.5."""
    ac = run(PAPER.map, algo="ac", trials=T_DIST, chances=PAPER.chances, n_seeds=N_DIST, seed=1, **RATES)
    assert stats.ttest_ind(jax_totals["eac", 1.0][0], ac["successes"], equal_var=False).pvalue < 1e-6
    assert stats.ttest_ind(jax_totals["ac", 0.5][0], ac["successes"], equal_var=False).pvalue < 1e-3


# --- reproducibility ---------------------------------------------------------------------------------


@pytest.mark.parametrize("algo", ["ac", "eac"])
def test_same_seed_same_output(run, algo):
    kw = dict(algo=algo, trials=15, chances=PAPER.chances, **RATES)
    a = run("paper", n_seeds=64, seed=3, tables=True, **kw)
    b = run("paper", n_seeds=64, seed=3, tables=True, **kw)
    for key in a:
        np.testing.assert_array_equal(a[key], b[key])
    record_invariants(a, PAPER.chances, 15)
    assert a["policy"].shape == (64, 121) and a["preferences"].shape == (64, 121, 4)
    c = run("paper", n_seeds=64, seed=4, **kw)
    assert not np.array_equal(a["steps"], c["steps"])
    # a seed's results depend neither on the seeds beside it nor on the threads
    d = run("paper", n_seeds=40, seed=3, threads=1, tables=True, **kw)
    for key in d:
        np.testing.assert_array_equal(d[key], a[key][:40])


@pytest.mark.skipif(not (c_peer.available() and numba_peer.available()), reason="needs both peers")
@pytest.mark.parametrize("algo", ["ac", "eac", "eac_success_only", "eac_failure_only", "eac_learn_on_memory",
                                  "eac_within_trial"])
def test_c_and_numba_agree_seed_for_seed(algo):
    """Same RNG stream design, same float32 arithmetic (no FMA contraction): the same runs. Allowed:
    a rare seed whose libm exp differs by an ulp exactly at a sampling boundary (none seen here)."""
    kw = dict(algo=algo, trials=60, chances=PAPER.chances, n_seeds=200, seed=11, tables=True, **RATES)
    a, b = c_peer.run_c("paper", **kw), numba_peer.run_numba("paper", **kw)
    same = (a["success"] == b["success"]).all(1) & (a["steps"] == b["steps"]).all(1)
    same &= (a["preferences"] == b["preferences"]).all((1, 2))
    assert same.mean() >= 0.99, f"{algo}: {(~same).sum()} seeds differ"


@pytest.mark.parametrize(
    ("kw", "match"),
    [({"algo": "sarsa"}, "unknown algorithm"), ({"n_seeds": 0}, "seeds"), ({"trials": 0}, "trials"),
     ({"temperature": 0.0}, "temperature"), ({"threads": 0}, "threads")],
)
def test_bad_input(run, kw, match):
    args = dict(algo="ac", trials=2, chances=3, n_seeds=2) | kw
    with pytest.raises(UsageError, match=match):
        run("paper", **args)


def test_c_peer_reports_its_build():
    if not c_peer.available():
        pytest.skip("no working C compiler")
    info = c_peer.info()
    assert info["flags"].startswith("-O") and isinstance(info["openmp"], bool) and info["max_threads"] >= 1


# --- the benchmark's peer columns ----------------------------------------------------------------


def test_bench_times_the_peers_beside_jaxeac(tmp_path):
    """`scripts/bench.py --c-peer --numba-peer` adds each available peer's rate and jaxeac / peer to
    every jaxeac row (same seeds, same run), and `--render` shows them as columns; unavailable peers
    are skipped."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    out = tmp_path / "grid.json"
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    proc = subprocess.run([sys.executable, "scripts/bench.py", "--seeds", "40", "--numpy-seeds", "--chunk",
                           "64", "--repeats", "1", "--c-peer", "--numba-peer", "--out", str(out)],
                          capture_output=True, text=True, cwd=root, env=env, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    rec = json.loads(out.read_text())
    names = [n for n, ok in (("c", c_peer.available()), ("numba", numba_peer.available())) if ok]
    assert sorted(rec["peers"]) == sorted(names)
    assert [(r["impl"], r["algo"]) for r in rec["rows"]] == [("jaxeac", "ac"), ("jaxeac", "eac")]
    for r in rec["rows"]:
        for n in names:
            assert r[f"{n}_agent_steps"] > 0
            rate = r[f"{n}_steps_per_s"]
            assert abs(rate - r[f"{n}_agent_steps"] / r[f"{n}_run_s"]) < 1e-6 * rate
            assert abs(r[f"jaxeac_over_{n}"] - r["steps_per_s"] / rate) < 1e-9 * r[f"jaxeac_over_{n}"]
    table = subprocess.run([sys.executable, "scripts/bench.py", "--render", str(out)], capture_output=True,
                           text=True, cwd=root, env=env, timeout=600)
    assert table.returncode == 0, table.stderr[-2000:]
    for n, label in (("c", "C"), ("numba", "numba")):
        assert (f"| jaxeac / {label} |" in table.stdout) == (n in names)
        summary = f"jaxeac / {label} peer (same run, same seeds): AC at 40 seeds:"
        assert (summary in table.stdout) == (n in names)
