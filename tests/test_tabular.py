"""Tabular tasks under the run loops (X1, X2) and the value-based baselines (X3), against the
literal reference (tests/reference.py) and by hand."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from reference import TaskReference, epsilon_greedy_choice, reference_run

from jaxeac.algorithm.agent import epsilon_greedy
from jaxeac.algorithm.config import algorithm
from jaxeac.envs.grid import get_map
from jaxeac.envs.tabular import TabularEnv
from jaxeac.envs.tasks import TabularTask
from jaxeac.errors import UsageError
from jaxeac.rng import seed_key
from jaxeac.running.config import RunConfig
from jaxeac.running.loops import trace_run


def corridor(slip: float = 0.2) -> TabularTask:
    """A 1×5 corridor: a hole at x = 0 (terminal, a failure), the goal at x = 4 (+1); start at
    x = 1 or 2; actions 0 left, 1 right; with probability `slip` the move goes the other way;
    moving into the wall at x = 4 never happens (the goal is terminal)."""
    n = 5
    nxt = np.zeros((n, 2, 2), np.int32)
    for s in range(n):
        left, right = max(s - 1, 0), min(s + 1, n - 1)
        nxt[s, 0], nxt[s, 1] = (left, right), (right, left)
    probs = np.broadcast_to([1 - slip, slip], (n, 2, 2)).copy()
    rewards = (nxt == 4).astype(float)
    bumped = nxt == 0
    terminal = np.array([True, False, False, False, True])
    success = np.array([False, False, False, False, True])
    return TabularTask("corridor", nxt, probs, rewards, bumped, terminal, success, np.array([1, 2], np.int32),
                       max_steps=8, source="a test corridor", action_names=("left", "right"), shape=(1, 5),
                       action_deltas=((-1, 0), (1, 0)), goal=4)


def check_task_against_reference(task, name, *, trials=30, chances=None, seed=3, rtilde="shaped", **rates):
    rates = {"alpha": 0.2, "beta": 0.3, "gamma": 0.9, "temperature": 1.0, "epsilon": 0.2} | rates
    with jax.enable_x64(True):
        env = TabularEnv(task, chances, rtilde=rtilde)
        cfg = RunConfig(trials=trials, agent=algorithm(name), **rates)
        key = seed_key(jax.random.key(11), seed)
        agent, records = jax.device_get(jax.jit(lambda k, h: trace_run(env, cfg, k, h))(key, cfg.hyper()))
        ref = reference_run(TaskReference(task, rtilde), algorithm(name), trials=trials, chances=env.n_chances,
                            alpha=rates["alpha"], beta=rates["beta"], gamma=rates["gamma"],
                            tau=rates["temperature"], epsilon=rates["epsilon"], key=key)
    for t, rt in enumerate(ref.trials):
        n = len(rt.states)
        assert (int(records.length[t]), bool(records.success[t])) == (n, rt.success), f"trial {t}"
        np.testing.assert_array_equal(records.states[t, :n], rt.states, err_msg=f"trial {t}: states")
        np.testing.assert_array_equal(records.actions[t, :n], rt.actions, err_msg=f"trial {t}: actions")
        np.testing.assert_allclose(records.rtilde[t, :n], rt.rtilde, rtol=0, atol=1e-12)
    np.testing.assert_allclose(agent.preferences, ref.preferences, rtol=0, atol=1e-10)
    np.testing.assert_allclose(agent.values, ref.values, rtol=0, atol=1e-10)
    return ref


@pytest.mark.parametrize("name", ["ac", "eac", "eac_within_trial", "q_learning", "sarsa"])
def test_stochastic_corridor_matches_reference(name):
    ref = check_task_against_reference(corridor(), name)
    outcomes = {t.success for t in ref.trials}
    assert outcomes == {True, False}, "the run should see both successes and failures"


@pytest.mark.parametrize("name", ["eac", "q_learning"])
def test_reward_rtilde_variant_matches_reference(name):
    check_task_against_reference(corridor(0.3), name, rtilde="reward")


@pytest.mark.parametrize("name", ["q_learning", "sarsa"])
def test_baselines_on_the_paper_grid_match_reference(name):
    from reference import GridReference

    from jaxeac.envs.grid import GridWorld
    from jaxeac.running.loops import trace_run as run

    grid = get_map("paper7")
    rates = {"alpha": 0.5, "beta": 0.3, "gamma": 0.9, "temperature": 1.0, "epsilon": 0.3}
    with jax.enable_x64(True):
        env = GridWorld(grid, 20)
        cfg = RunConfig(trials=25, agent=algorithm(name), **rates)
        key = seed_key(jax.random.key(5), 2)
        agent, records = jax.device_get(jax.jit(lambda k, h: run(env, cfg, k, h))(key, cfg.hyper()))
        ref = reference_run(GridReference(grid), algorithm(name), trials=25, chances=20, alpha=0.5, beta=0.3,
                            gamma=0.9, tau=1.0, epsilon=0.3, key=key)
    assert [t.success for t in ref.trials] == records.success.tolist()
    assert sum(t.success for t in ref.trials) >= 3  # the comparison covers successful trials
    np.testing.assert_allclose(agent.preferences, ref.preferences, rtol=0, atol=1e-10)


def test_epsilon_greedy_by_hand():
    q = jnp.array([0.0, 2.0, 2.0, 1.0])
    pick = lambda u, eps: int(epsilon_greedy(q, jnp.float32(u), eps))  # noqa: E731
    # u < ε explores: ⌊(u/ε)·4⌋
    assert [pick(u, 0.2) for u in (0.0, 0.06, 0.11, 0.19)] == [0, 1, 2, 3]
    # else the greedy ties {1, 2}, split by (u − ε)/(1 − ε) at 1/2
    assert [pick(u, 0.2) for u in (0.2, 0.59, 0.61, 0.999)] == [1, 1, 2, 2]
    assert pick(0.49, 0.0) == 1 and pick(0.5, 0.0) == 2  # ε = 0: greedy only, ties split at 1/2
    assert pick(0.99, 1.0) == 3  # ε = 1: uniform
    for u in np.linspace(0, 0.999, 37):
        assert pick(u, 0.3) == epsilon_greedy_choice(np.asarray(q), 0.3, float(np.float32(u)))


def test_outcome_frequencies_follow_the_probabilities():
    env = TabularEnv(corridor(0.25))
    state = env.reset_from(jnp.float32(0.0))  # x = 1
    u = (jnp.arange(1 << 14) + 0.5) / (1 << 14)
    moved = jax.vmap(lambda x: env.transition(state, 1, x).state.position)(u)
    assert float((moved == 2).mean()) == pytest.approx(0.75, abs=1e-3)
    assert float((moved == 0).mean()) == pytest.approx(0.25, abs=1e-3)


def test_deterministic_task_draws_nothing_and_hole_is_a_failure():
    env = TabularEnv(corridor(0.0), n_chances=3)
    assert env.deterministic
    state = env.reset_from(jnp.float32(0.0))
    t = env.transition(state, 0)  # into the hole
    assert (int(t.state.position), bool(t.terminated), bool(t.success), bool(t.bumped)) == (0, True, False, True)
    assert float(env.rtilde(t, jnp.bool_(True))) == -1.0
    t = env.transition(env.reset_from(jnp.float32(0.99)), 1)  # x = 2 → 3
    assert float(env.rtilde(t, jnp.bool_(True))) == pytest.approx(0.5)
    assert float(env.rtilde(t, jnp.bool_(False))) == 0.0


def test_bad_options():
    with pytest.raises(UsageError, match="chances must be a positive integer"):
        TabularEnv(corridor(), 0)
    with pytest.raises(UsageError, match="unknown r̃ rule 'pins'"):
        TabularEnv(corridor(), rtilde="pins")
    with pytest.raises(UsageError, match="keeps no success/failure memory"):
        algorithm("q_learning", success_memory=True)


def _same_runs(env_a, env_b, name, **cfg):
    from jaxeac.running.batch import run_seeds

    cfg = RunConfig(trials=60, agent=algorithm(name), **cfg)
    a = run_seeds(env_a, cfg, root_key=4, n_seeds=24)
    b = run_seeds(env_b, cfg, root_key=4, n_seeds=24)
    np.testing.assert_array_equal(a.success, b.success)
    np.testing.assert_array_equal(a.steps, b.steps)
    np.testing.assert_array_equal(a.policy, b.policy)
    return a


@pytest.mark.parametrize("name", ["ac", "eac", "q_learning"])
def test_paper_grid_as_a_table_is_the_grid_world(name):
    """X1: the paper's grid written as a TabularTask runs exactly as the GridWorld (memory jumps
    resolve on both)."""
    from jaxeac.envs.grid import GridWorld
    from jaxeac.envs.tasks import grid_task

    grid = get_map("paper")
    table = TabularEnv(grid_task(grid, 40), 40)
    assert table.deterministic and table.n_states == 121
    run = _same_runs(GridWorld(grid, 40), table, name)
    assert run.success.mean() > 0.1  # both worlds see successes (AC: ~0.19 in 60 trials)


@pytest.mark.parametrize("task", ["CliffWalking-v1", "FourRooms-v0", "FrozenLake-8x8-v1"])
def test_memory_jumps_are_exact_on_deterministic_tasks(task):
    import jaxeac

    env = jaxeac.make(task, chances=60)
    assert RunConfig(trials=60, agent=algorithm("eac")).resolve(env, 24).jump == "on"
    a = _same_runs(env, env, "eac", jump="on")
    from jaxeac.running.batch import run_seeds

    b = run_seeds(env, RunConfig(trials=60, agent=algorithm("eac"), jump="off"), root_key=4, n_seeds=24)
    np.testing.assert_array_equal(a.success, b.success)
    np.testing.assert_array_equal(a.steps, b.steps)
    np.testing.assert_array_equal(a.policy, b.policy)


def test_registry_names_the_classic_tasks():
    import jaxeac
    from jaxeac.envs import CLASSIC

    for name in CLASSIC:
        env = jaxeac.make(name)
        assert env.name == name and env.n_chances == env.task.max_steps
        assert env.deterministic == ("slippery" not in name and "stochastic" not in name)
    slippery = jaxeac.make("grid-paper-v0", slip=0.1)
    assert isinstance(slippery, TabularEnv) and not slippery.deterministic and slippery.n_chances == 40
    assert slippery.name == "grid-paper-v0-slip0.1"
    assert jaxeac.make("CliffWalking-v1", rtilde="reward").rtilde_rule == "reward"
    with pytest.raises(UsageError, match="'grid-paper-v0' has no option 'rtilde'; its options are chances, slip"):
        jaxeac.make("grid-paper-v0", rtilde="reward")


@pytest.mark.parametrize("name", ["eac", "q_learning", "sarsa"])
def test_flat_loop_equals_trials_loop_on_a_stochastic_task(name):
    """R1/R2 on a stochastic task: the flat loop fed from a queue gives the trials loop's results."""
    import jaxeac
    from jaxeac.running.batch import run_seeds

    env = jaxeac.make("FrozenLake-4x4-slippery-v1", chances=30)
    runs = [run_seeds(env, RunConfig(trials=40, agent=algorithm(name), loop=loop, lanes=lanes), root_key=6,
                      n_seeds=20, chunk_size=chunk)
            for loop, lanes, chunk in (("trials", None, 20), ("flat", 3, 7), ("flat", 64, 20))]
    for other in runs[1:]:
        np.testing.assert_array_equal(other.success, runs[0].success)
        np.testing.assert_array_equal(other.steps, runs[0].steps)
        np.testing.assert_array_equal(other.policy, runs[0].policy)
    assert runs[0].success.any()
