"""Hand-computed golden values for each update of AC/EAC (eqs. 1-4, SPEC E1-E6), jitted and not."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxeac.algorithm.agent import (
    end_trial,
    greedy_policy,
    init_agent,
    learn_step,
    record_step,
    sample_softmax,
    select_action,
    td_error,
    with_actor_critic,
)
from jaxeac.algorithm.config import AgentConfig, Hyper, algorithm, rate_at
from jaxeac.algorithm.memory import dense_tables, with_committed
from jaxeac.algorithm.tables import SplitTables, learning_increments
from jaxeac.errors import UsageError

JIT = pytest.mark.parametrize("jit", [False, True], ids=["eager", "jit"])
TABLES = pytest.mark.parametrize("tables", ["split", "rows"])


def maybe_jit(f, jit, **kw):
    return jax.jit(f, **kw) if jit else f


@JIT
def test_td_error_golden(jit):
    f = maybe_jit(td_error, jit)
    # (3): δ = 1 + 0.9·0.2 − 0.5 = 0.68; terminal s' → V(s') = 0: δ = 1 − 0.5 = 0.5
    assert float(f(1.0, 0.5, 0.2, 0.9, False)) == pytest.approx(0.68)
    assert float(f(1.0, 0.5, 0.2, 0.9, True)) == pytest.approx(0.5)
    assert float(f(-1.0, 0.0, 0.0, 0.9, False)) == pytest.approx(-1.0)


@JIT
def test_critic_and_actor_updates_golden(jit):
    actor, critic = maybe_jit(learning_increments, jit)(0.68, True, 0.1, 0.3)
    assert (float(actor), float(critic)) == pytest.approx((0.204, 0.068))  # (4) β·δ, (2) α·δ
    actor, critic = maybe_jit(learning_increments, jit)(0.68, False, 0.1, 0.3)
    assert (float(actor), float(critic)) == (0.0, 0.0)  # E2: no learning on memory steps

    def learn(t, *args):
        return t.learn(*args)

    tables = SplitTables(jnp.zeros((3, 4)), jnp.array([0.0, 0.5, -0.25]))
    t = maybe_jit(learn, jit)(tables, 1, 0, 0.68, 0.1, 0.3, True)
    np.testing.assert_allclose(t.values, [0.0, 0.568, -0.25], rtol=1e-6)  # V(s) += α·δ
    t = maybe_jit(learn, jit)(tables, 2, 3, -0.5, 0.1, 0.3, True)
    expected = np.zeros((3, 4))
    expected[2, 3] = -0.15  # (4): only the taken action moves, by β·δ
    np.testing.assert_allclose(t.preferences, expected, rtol=1e-6)
    t = maybe_jit(learn, jit)(tables, 1, 0, 0.68, 0.1, 0.3, False)
    np.testing.assert_array_equal(t.values, tables.values)  # E2


@TABLES
def test_learn_step_golden_sequence(tables):
    """Two transitions by hand: 0 --a1--> 1 (r=0), then 1 --a0--> goal (r=1, terminal)."""
    agent = init_agent(algorithm("ac", tables=tables).resolve(), 3, 2, 4, 10)
    agent = with_actor_critic(agent, values=[0.0, 0.2, 0.7])
    a1 = learn_step(agent, 0, 1, 0.0, 1, False, True, 0.5, 0.2, 0.9)
    # δ = 0 + 0.9·0.2 − 0 = 0.18 → V0 = 0.09, p(0,1) = 0.036
    np.testing.assert_allclose(a1.values, [0.09, 0.2, 0.7], rtol=1e-6)
    np.testing.assert_allclose(a1.preferences[0], [0.0, 0.036], rtol=1e-6)
    a2 = learn_step(a1, 1, 0, 1.0, 2, True, True, 0.5, 0.2, 0.9)
    # δ = 1 + 0 − 0.2 = 0.8 (terminal ignores V(goal) = 0.7) → V1 = 0.6, p(1,0) = 0.16
    np.testing.assert_allclose(a2.values, [0.09, 0.6, 0.7], rtol=1e-6)
    np.testing.assert_allclose(a2.preferences[1], [0.16, 0.0], rtol=1e-6)


@JIT
def test_sample_softmax_inverse_cdf(jit):
    f = maybe_jit(sample_softmax, jit)
    logits = jnp.array([0.0, math.log(3.0)])  # (1): π = [0.25, 0.75]
    everything = jnp.array([True, True])
    assert int(f(logits, everything, 0.0)) == 0
    assert int(f(logits, everything, 0.24)) == 0
    assert int(f(logits, everything, 0.26)) == 1
    assert int(f(logits, everything, 0.999999)) == 1
    # restricted to {0, 2}: weights e^0, e^ln3 → [0.25, 0, 0.75, 0]; flagged actions never drawn
    logits = jnp.array([0.0, 5.0, math.log(3.0), 9.0])
    allowed = jnp.array([True, False, True, False])
    assert int(f(logits, allowed, 0.24)) == 0
    assert int(f(logits, allowed, 0.26)) == 2
    assert int(f(logits, allowed, 0.9999)) == 2
    # only the last action allowed
    assert int(f(logits, jnp.array([False, False, False, True]), 0.0)) == 3


def test_sample_softmax_frequencies_match_equation_1():
    logits = jnp.array([0.5, -1.0, 2.0, 0.0])
    u = jax.random.uniform(jax.random.key(0), (200_000,))
    draws = jax.vmap(lambda x: sample_softmax(logits, jnp.ones(4, bool), x))(u)
    freq = np.bincount(np.asarray(draws), minlength=4) / u.size
    np.testing.assert_allclose(freq, jax.nn.softmax(logits), atol=4e-3)


def hyper(temperature=1.0):
    return Hyper(jnp.float32(0.1), jnp.float32(0.3), jnp.float32(0.9), jnp.float32(temperature))


def with_tables(agent, success, failed):
    """An EAC agent whose dense memory holds these committed entries."""
    return agent.replace(memory=with_committed(agent.memory, success, failed))


def test_select_action_e1_order():
    cfg = algorithm("eac")
    failed = np.zeros((4, 4), bool)
    failed[1, 0] = True
    failed[2, :2] = True
    failed[3, :] = True
    agent = with_tables(init_agent(cfg.resolve(), 4, 4, 5, 10), [-1, 3, -1, -1], failed)
    # (a) success memory wins even over failure flags at the same state
    assert tuple(map(int, select_action(cfg, agent, 1, 0.0, hyper()))) == (3, 0)
    # (b) two of four flagged at state 2 → uniform over {2, 3}; no learning (E2)
    a, learns = select_action(cfg, agent, 2, 0.49, hyper())
    assert (int(a), bool(learns)) == (2, False)
    assert int(select_action(cfg, agent, 2, 0.51, hyper())[0]) == 3
    # (c) all four flagged at state 3 → plain softmax over all, learns
    assert [int(select_action(cfg, agent, 3, u, hyper())[0]) for u in (0.1, 0.3, 0.6, 0.9)] == [0, 1, 2, 3]
    assert bool(select_action(cfg, agent, 3, 0.1, hyper())[1])
    # (c) nothing remembered at state 0 → plain softmax, learns
    assert bool(select_action(cfg, agent, 0, 0.1, hyper())[1])
    # E2 variant: learns on memory steps too
    variant = algorithm("eac", learn_on_memory_steps=True)
    assert bool(select_action(variant, agent, 1, 0.0, hyper())[1])
    assert bool(select_action(variant, agent, 2, 0.0, hyper())[1])


@TABLES
def test_select_action_temperature(tables):
    cfg = algorithm("ac", tables=tables)
    agent = with_actor_critic(init_agent(cfg.resolve(), 1, 2, 1, 1), preferences=[[0.0, math.log(3.0)]])
    # τ = 1: π = [.25, .75]; τ → large: π → [.5, .5]
    assert int(select_action(cfg, agent, 0, 0.3, hyper(1.0))[0]) == 1
    assert int(select_action(cfg, agent, 0, 0.3, hyper(1e6))[0]) == 0


def play_trial(cfg, agent, states, actions, rtilde, success):
    """Feed one trial's chances through record_step and close it with end_trial."""
    for s_, a_, r_ in zip(states, actions, rtilde, strict=True):
        agent = record_step(cfg, agent, s_, a_, r_, jnp.bool_(True))
    return end_trial(cfg, agent, jnp.bool_(success), jnp.bool_(True))


def tables(agent):
    success, failed = dense_tables(agent.memory, agent.trial, agent.outcomes)
    rows, cols = np.nonzero(np.asarray(failed))
    return np.asarray(success), {(int(s), int(a)) for s, a in zip(rows, cols, strict=True)}


def test_failure_rule_previous_trial_golden_e6():
    cfg = algorithm("eac")
    agent = init_agent(cfg.resolve(), 8, 4, 5, 10)
    # trial 1 fails: no previous trial, nothing flagged (t >= 2 only)
    agent = play_trial(cfg, agent, [0, 1, 2, 3, 4], [0] * 5, [0.5, 0.4, -1.0, 0.2, 0.0], False)
    assert tables(agent)[1] == set()
    # trial 2 fails: r̃(c|2) < r̃(c|1) at c = 1 and 4 (1-based) → flag (5,1) and (7,1)
    agent = play_trial(cfg, agent, [5, 6, 6, 7, 6], [1] * 5, [0.4, 0.4, -1.0, 0.1, 0.0], False)
    assert tables(agent)[1] == {(5, 1), (7, 1)}
    assert (tables(agent)[0] == -1).all()
    # trial 3 succeeds in 2 chances: its lower r̃ flags nothing (E6 is for failed trials)
    agent = play_trial(cfg, agent, [2, 3], [2, 3], [-1.0, -1.0], True)
    assert tables(agent)[1] == {(5, 1), (7, 1)}
    # trial 4 fails: only c = 1, 2 exist in trial 3 too; r̃ below trial 3's nowhere → no new flag
    agent = play_trial(cfg, agent, [4, 4, 4, 4, 4], [3] * 5, [-1.0, -1.0, -5.0, -5.0, -5.0], False)
    assert tables(agent)[1] == {(5, 1), (7, 1)}


def test_failure_rule_within_trial_golden_e6():
    cfg = algorithm("eac", failure_rule="within_trial")
    agent = init_agent(cfg.resolve(), 8, 4, 5, 10)
    # r̃ = [.4, .4, −1, .1, 0]: drops at c = 3 (−1 < .4) and c = 5 (0 < .1), already in trial 1
    agent = play_trial(cfg, agent, [0, 1, 2, 3, 4], [2] * 5, [0.4, 0.4, -1.0, 0.1, 0.0], False)
    assert tables(agent)[1] == {(2, 2), (4, 2)}


def test_success_write_golden_e4():
    cfg = algorithm("eac")
    agent = init_agent(cfg.resolve(), 6, 4, 4, 10)
    # success: chronological, the last action at a state wins (state 0: 1 then 3)
    agent = play_trial(cfg, agent, [0, 1, 0], [1, 2, 3], [0.0, 0.0, 1.0], True)
    np.testing.assert_array_equal(tables(agent)[0], [3, 2, -1, -1, -1, -1])
    # a failed trial through the same states changes nothing
    agent = play_trial(cfg, agent, [0, 1, 4, 5], [0, 0, 0, 0], [0.0, 0.0, 0.0, 0.0], False)
    np.testing.assert_array_equal(tables(agent)[0], [3, 2, -1, -1, -1, -1])
    # a later success overwrites what it visits and keeps the rest
    agent = play_trial(cfg, agent, [1, 5], [0, 1], [0.0, 1.0], True)
    np.testing.assert_array_equal(tables(agent)[0], [3, 0, -1, -1, -1, 1])
    assert int(agent.trial) == 3 and np.asarray(agent.outcomes)[:3].tolist() == [True, False, True]


def test_memory_applies_only_after_the_trial():
    """Algorithm 1 writes memories after a trial: within the trial, lookups see the old memory."""
    cfg = algorithm("eac")
    agent = init_agent(cfg.resolve(), 6, 4, 4, 10)
    agent = record_step(cfg, agent, 2, 1, 0.0, jnp.bool_(True))
    assert int(select_action(cfg, agent, 2, 0.9, hyper())[0]) == 3  # softmax, not the pending 1
    agent = end_trial(cfg, agent, jnp.bool_(True), jnp.bool_(True))
    assert int(select_action(cfg, agent, 2, 0.9, hyper())[0]) == 1


@TABLES
def test_ac_has_no_memory_and_greedy_policy(tables):
    ac = algorithm("ac", tables=tables)
    agent = init_agent(ac.resolve(), 2, 3, 1, 1)
    assert agent.memory is None and not ac.uses_memory
    agent = with_actor_critic(agent, preferences=[[0.0, 2.0, 1.0], [3.0, 0.0, 0.0]])
    np.testing.assert_array_equal(greedy_policy(ac, agent), [1, 0])
    eac = algorithm("eac", tables=tables)
    e = with_actor_critic(init_agent(eac.resolve(), 2, 3, 1, 1), preferences=agent.preferences)
    e = with_tables(e, [-1, 2], np.zeros((2, 3), bool))
    np.testing.assert_array_equal(greedy_policy(eac, e), [1, 2])  # G7: memory first


def test_rate_schedule():
    import optax

    sched = optax.linear_schedule(1.0, 0.0, 10)
    assert float(rate_at(sched, jnp.float32(0.5), 5)) == pytest.approx(0.5)
    assert float(rate_at(0.3, jnp.float32(0.7), 5)) == pytest.approx(0.7)


@pytest.mark.parametrize(("kw", "msg"), [
    ({"failure_rule": "sideways"}, "unknown failure_rule"),
    ({"memory": "sparse"}, "unknown memory layout"),
    ({"tables": "packed"}, "unknown table layout"),
    ({"capacity": 0}, "capacity must be a positive integer"),
    ({"capacity": 2.5}, "capacity must be a positive integer"),
])
def test_agent_config_rejects_bad_values(kw, msg):
    with pytest.raises(UsageError, match=msg):
        AgentConfig(**kw)


def test_unknown_algorithm():
    with pytest.raises(UsageError, match="unknown algorithm 'dqn'"):
        algorithm("dqn")


def test_row_tables_layout():
    """Rows of p(s, ·), V(s) padded to 32 bytes; updates (2), (4) leave the padding at zero."""
    from jaxeac.algorithm.config import resolve_tables
    from jaxeac.algorithm.tables import RowTables, SplitTables

    assert resolve_tables("auto") == ("split" if jax.default_backend() == "cpu" else "rows")
    assert isinstance(init_agent(algorithm("ac", tables="split").resolve(), 3, 4, 1, 1).tables, SplitTables)
    agent = init_agent(algorithm("ac", tables="rows").resolve(), 3, 4, 1, 1)
    assert isinstance(agent.tables, RowTables) and agent.tables.rows.shape == (3, 8)
    assert init_agent(algorithm("ac", tables="rows").resolve(), 3, 21, 1, 1).tables.rows.shape == (3, 24)
    agent = learn_step(agent, 1, 3, 1.0, 2, True, True, 0.5, 0.2, 0.9)  # δ = 1
    expected = np.zeros((3, 8))
    expected[1, 3], expected[1, 4] = 0.2, 0.5  # β·δ at (1, 3); α·δ in the value column
    np.testing.assert_allclose(agent.tables.rows, expected, rtol=1e-6)
    np.testing.assert_allclose(agent.values, [0.0, 0.5, 0.0], rtol=1e-6)
