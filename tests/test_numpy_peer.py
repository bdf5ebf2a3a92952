"""The hand-vectorised NumPy peer (`scripts/peers/numpy_peer.py`) against the SPEC and the JAX runner.

* by hand, with injected random numbers, on 1×2 and 1×3 maps (G4, E1, E2, E4, E5, E6);
* invariants that hold for any random numbers (E1(a), E4 on a map where one move wins);
* step for step against the JAX runner when both consume the runner's random numbers;
* in distribution against `run_seeds` with their own random numbers (Welch's test, per seed);
* reproducibility (R2, peer reading: same seed and seed count → same output).
"""

from __future__ import annotations

import jax
import numpy as np
import pytest
from peers.numpy_peer import run_numpy, simulate
from scipy import stats

from jaxeac.algorithm.config import algorithm
from jaxeac.envs.grid import GridWorld, get_map, parse_map
from jaxeac.errors import UsageError
from jaxeac.experiments.presets import make
from jaxeac.rng import seed_key, trial_randoms
from jaxeac.running.batch import run_seeds
from jaxeac.running.config import RunConfig

PAPER = make("paper")
RATES = {"alpha": PAPER.alpha, "beta": PAPER.beta, "gamma": PAPER.gamma, "temperature": PAPER.temperature}


def fixed_draw(uniforms_per_trial, n_seeds=1):
    """A draw that starts in free cell 0 and uses the given chance uniforms of each trial."""

    def draw(t):
        u = np.asarray(uniforms_per_trial[t], np.float32)
        return np.zeros(n_seeds, np.int64), np.broadcast_to(u, (n_seeds, u.size))

    return draw


def peer(map_text, algo, draw, *, trials, chances, n_seeds=1):
    world = GridWorld(parse_map(map_text), chances)
    return simulate(world, algorithm(algo), draw, n_seeds=n_seeds, trials=trials, **RATES)


# --- by hand -----------------------------------------------------------------------------------


def test_ac_one_by_two_map_by_hand():
    """Map "G.": from cell 1, u = 0.3 picks action 1 (left, into the goal) under any p(1,1) ≥ 0."""
    trials = 6
    out = peer("G.", "ac", fixed_draw([[0.3] * 4] * trials), trials=trials, chances=4)
    assert out["success"].all() and (out["steps"] == 1).all()
    v = 1 - 0.9**trials  # V_t = V_{t−1} + α(1 − V_{t−1}), V_0 = 0
    np.testing.assert_allclose(out["values"][0], [0.0, v], rtol=1e-6)
    np.testing.assert_allclose(out["preferences"][0, 1], [0.0, 3 * v, 0.0, 0.0], rtol=1e-6)  # β·Σδ = 3V
    assert out["policy"][0, 1] == 1


def test_ac_stays_put_forever_by_hand():
    """u = 0.1 picks action 0 (right: off the grid, stay, r = 0, δ = 0): every trial fails."""
    out = peer("G.", "ac", fixed_draw([[0.1] * 5] * 3), trials=3, chances=5)
    assert not out["success"].any() and (out["steps"] == 5).all()
    assert not out["values"].any() and not out["preferences"].any()


def test_eac_success_memory_keeps_last_action_by_hand():
    """E4: cell 1 visited twice (right, then left into the goal) remembers left; E2: no learning after."""
    draw = fixed_draw([[0.1, 0.3, 0.1], [0.1, 0.1, 0.1], [0.1, 0.1, 0.1]])
    out = peer("G.", "eac", draw, trials=3, chances=3)
    np.testing.assert_array_equal(out["steps"][0], [2, 1, 1])
    assert out["success"].all()
    np.testing.assert_allclose(out["values"][0], [0.0, 0.1], rtol=1e-6)
    np.testing.assert_allclose(out["preferences"][0, 1], [0.0, 0.3, 0.0, 0.0], rtol=1e-6)


def test_eac_failure_memory_by_hand():
    """Map "G.#": bump right twice in trial 2 (r̃ −1 < 0 of trial 1) → (1, right) flagged (E6);
    trial 3 samples among left/up/down only (E1(b)), u = 0.1 → left → goal, without learning (E2)."""
    draw = fixed_draw([[0.6, 0.6], [0.1, 0.1], [0.1, 0.1], [0.9, 0.9]])
    out = peer("G.#", "eac", draw, trials=4, chances=2)
    np.testing.assert_array_equal(out["success"][0], [False, False, True, True])
    np.testing.assert_array_equal(out["steps"][0], [2, 2, 1, 1])
    # trial 2: δ = −1 then −1 + 0.9·(−0.1) + 0.1 = −0.99
    np.testing.assert_allclose(out["values"][0], [0.0, -0.199, 0.0], rtol=1e-6)
    np.testing.assert_allclose(out["preferences"][0, 1], [-0.597, 0.0, 0.0, 0.0], rtol=1e-6)
    assert out["policy"][0, 1] == 1  # E4 wrote left after trial 3


def test_without_flag_trial_three_would_bump():
    """Control for the test above: AC (no failure memory) bumps again with the same numbers."""
    draw = fixed_draw([[0.6, 0.6], [0.1, 0.1], [0.1, 0.1], [0.9, 0.9]])
    out = peer("G.#", "ac", draw, trials=4, chances=2)
    assert not out["success"][0, 2]


# --- invariants for any random numbers --------------------------------------------------------


def test_eac_one_move_map_invariants():
    """Map "G.": before the first success every trial fails after C chances; from the trial after
    it, the remembered action 'left' (E1(a), E4) wins in one chance, whatever the random numbers."""
    c = 3
    out = run_numpy(parse_map("G."), algo="eac", trials=30, chances=c, n_seeds=400, seed=5, **RATES)
    success, steps = out["success"], out["steps"]
    trial = np.arange(success.shape[1])[None, :]
    first = np.where(success.any(1), success.argmax(1), success.shape[1])[:, None]
    assert (~success[trial < first]).all() and (steps[trial < first] == c).all()
    assert success[trial > first].all() and (steps[trial > first] == 1).all()
    assert (steps[trial == first] <= c).all()
    assert (out["policy"][success.any(1), 1] == 1).all()
    assert 0 < (first[:, 0] > 0).mean() < 1  # some seeds fail first, some succeed at once


# --- step for step against the JAX runner --------------------------------------------------


def jax_draw(root: int, n_seeds: int, world: GridWorld):
    """The JAX runner's own random numbers for seeds 0..N−1 (R1), as a peer `draw`."""
    keys = jax.vmap(seed_key, in_axes=(None, 0))(jax.random.key(root), np.arange(n_seeds))

    def one(key, t):
        r = trial_randoms(key, t, world.n_chances, world.n_starts)
        return r.start_index, r.action_uniforms

    batch = jax.jit(jax.vmap(one, in_axes=(0, None)))
    return lambda t: tuple(np.asarray(x) for x in batch(keys, t))


@pytest.mark.parametrize("algo", ["ac", "eac", "eac_success_only", "eac_failure_only"])
def test_same_random_numbers_same_run_as_jax(algo):
    world = GridWorld(get_map("paper"), PAPER.chances)
    n, trials = 24, 60
    cfg = RunConfig(trials=trials, agent=algorithm(algo), **RATES)
    ref = run_seeds(world, cfg, root_key=5, n_seeds=n)
    out = simulate(world, algorithm(algo), jax_draw(5, n, world), n_seeds=n, trials=trials, **RATES)
    np.testing.assert_array_equal(out["success"], ref.success)
    np.testing.assert_array_equal(out["steps"], ref.steps)
    np.testing.assert_array_equal(out["policy"], ref.policy)


# --- in distribution against the JAX runner ----------------------------------------------------


@pytest.fixture(scope="module")
def distributions():
    """Per-seed totals (successes, chances used) of both implementations, own random numbers each."""
    n, trials = 300, 60  # fewer trials than the preset's 200 for speed; agreement holds for any T
    world = GridWorld(get_map(PAPER.map), PAPER.chances)
    out = {}
    for algo in ("ac", "eac"):
        cfg = RunConfig(trials=trials, agent=algorithm(algo), **RATES)
        j = run_seeds(world, cfg, root_key=2014, n_seeds=n)
        p = run_numpy(PAPER.map, algo=algo, trials=trials, chances=PAPER.chances, n_seeds=n, seed=2014,
                      **RATES)
        out[algo] = {
            "jax": (j.success.sum(1), j.steps.sum(1)),
            "numpy": (p["success"].sum(1), p["steps"].sum(1)),
        }
    return out


@pytest.mark.parametrize("algo", ["ac", "eac"])
@pytest.mark.parametrize("measure", [0, 1], ids=["successes", "steps"])
def test_agrees_in_distribution_with_jax(distributions, algo, measure):
    """Welch's t-test on per-seed totals (the seed is the unit, SPEC §6) must not reject at 0.001."""
    a, b = distributions[algo]["jax"][measure], distributions[algo]["numpy"][measure]
    p = stats.ttest_ind(a, b, equal_var=False).pvalue
    assert p > 1e-3, f"{algo}: jax mean {a.mean():.3f}, numpy mean {b.mean():.3f}, p = {p:.2g}"


def test_distribution_check_has_power(distributions):
    """The same test does reject a real difference: NumPy AC against JAX EAC."""
    a, b = distributions["eac"]["jax"][0], distributions["ac"]["numpy"][0]
    assert stats.ttest_ind(a, b, equal_var=False).pvalue < 1e-6


# --- reproducibility and input checks ----------------------------------------------------------


@pytest.mark.parametrize("algo", ["ac", "eac"])
def test_same_seed_same_output(algo):
    kw = dict(algo=algo, trials=15, chances=PAPER.chances, n_seeds=64, **RATES)
    a, b = run_numpy("paper", seed=3, **kw), run_numpy("paper", seed=3, **kw)
    c = run_numpy("paper", seed=4, **kw)
    for key in a:
        np.testing.assert_array_equal(a[key], b[key])
    assert a["success"].dtype == bool and a["steps"].dtype == np.int32
    assert a["success"].shape == a["steps"].shape == (64, 15)
    assert not np.array_equal(a["steps"], c["steps"])
    assert ((a["steps"] >= 1) & (a["steps"] <= PAPER.chances)).all()
    assert (a["steps"][~a["success"]] == PAPER.chances).all()


@pytest.mark.parametrize(
    ("kw", "match"),
    [({"algo": "sarsa"}, "unknown algorithm"), ({"n_seeds": 0}, "seeds"), ({"trials": 0}, "trials")],
)
def test_bad_input(kw, match):
    args = dict(algo="ac", trials=2, chances=3, n_seeds=2) | kw
    with pytest.raises(UsageError, match=match):
        run_numpy("paper", **args)
