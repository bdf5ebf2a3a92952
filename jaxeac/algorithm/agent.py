"""Actor-critic (AC) and enhanced actor-critic (EAC) as pure single-stream functions.

Debnath & Nassour (2014): equations (1)–(4) for AC and Algorithm 1 for EAC,
with every open point pinned by SPEC E1–E7. AC is EAC with both memories off;
there is one code path. Each piece is defined here once and called by the XLA loops
(`jaxeac.running.loops`), the fused GPU kernel (`jaxeac.running.kernel`, as per-lane
scalars) and bowling alike. Callers vmap over seeds.

* (1) π(a|s) ∝ exp(p(s,a)/τ), preferences start at 0 (uniform policy).
* (3) δ = r + γ·V(s') − V(s), with V(s') = 0 when s' is terminal.
* critic: V(s) ← V(s) + α·δ;  (4) actor: p(s,a) ← p(s,a) + β·δ.

The value-based baselines (X3) share the tables and the loops: Q(s, a) is kept in the
preference table (V stays 0), chosen ε-greedily (`epsilon_greedy`) and learnt by
Q-learning or SARSA (`value_learn_step`).
SPEC ids (G1…, E1…, B1…, R1…) are defined in docs/SPEC.md.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxeac.algorithm import memory as mem
from jaxeac.algorithm.config import (  # noqa: F401  (re-exported: the agent's vocabulary)
    ALGORITHMS,
    FAILURE_RULES,
    TABLE_LAYOUTS,
    AgentConfig,
    FailureRule,
    Hyper,
    Rate,
    TableLayout,
    algorithm,
    rate_at,
    resolve_tables,
)
from jaxeac.algorithm.tables import RowTables, SplitTables, Tables, init_tables
from jaxeac.pytree import pytree_dataclass


def with_actor_critic(agent: AgentState, preferences=None, values=None) -> AgentState:
    """The agent with these p(s, a) [S, A] and/or V(s) [S] in its own table layout (tests, notebooks)."""
    preferences = agent.preferences if preferences is None else jnp.asarray(preferences, agent.values.dtype)
    values = agent.values if values is None else jnp.asarray(values, agent.values.dtype)
    if isinstance(agent.tables, RowTables):
        rows = agent.tables.rows.at[:, :agent.tables.n_actions].set(preferences)
        return agent.replace(tables=agent.tables.replace(rows=rows.at[:, agent.tables.n_actions].set(values)))
    return agent.replace(tables=SplitTables(preferences, values))


@pytree_dataclass
class AgentState:
    """Everything an agent carries across the trials of one seed."""

    tables: Tables  # p(s, a) of (1), (4) and V(s) of (2)
    memory: mem.AnyMemory | None  # success/failure experience in its E7 layout (None for AC)
    goal_known: jax.Array  # bool [], E5: goal reached at least once
    trial: jax.Array  # int32 [], 0-based index of the current trial
    chance: jax.Array  # int32 [], chances taken so far in the current trial
    log: jax.Array  # int32 [T], per finished trial: chances used, negated if it failed; 0 = not yet
    rtilde: jax.Array  # float [C], the latest r̃ per chance index: trial t−1's until trial t writes it
    prev_length: jax.Array  # int32 [], chances used in the previous trial (0 before trial 2)
    next_action: jax.Array | None = None  # int32 [], SARSA (X3): the action chosen for the next chance;
    #                                       −1: none

    @property
    def preferences(self) -> jax.Array:
        """float [S, A]: p(s, a) of (1), (4)."""
        return self.tables.preferences

    @property
    def values(self) -> jax.Array:
        """float [S]: V(s) of (2)."""
        return self.tables.values

    @property
    def outcomes(self) -> jax.Array:
        """bool [T]: success of each finished trial (False while a trial is unfinished)."""
        return self.log > 0

    @property
    def lengths(self) -> jax.Array:
        """int32 [T]: chances used by each finished trial (0 while unfinished)."""
        return jnp.abs(self.log)


def init_agent(cfg: AgentConfig, n_states: int, n_actions: int, n_chances: int, n_trials: int) -> AgentState:
    """Preferences and values at 0 (uniform "random" policy, Alg. 1 line 1), empty memories.

    `cfg` must be resolved (`AgentConfig.resolve`), so that no layout is chosen while tracing.
    """
    memory = None
    if cfg.uses_memory:
        if cfg.memory == "dense":
            mem.check_dense_limits(n_actions, n_trials)
        memory = mem.init_memory(cfg.memory, n_states, n_actions, cfg.capacity, n_trials, n_chances)
    return AgentState(
        tables=init_tables(cfg.tables, n_states, n_actions),
        memory=memory,
        goal_known=jnp.bool_(False),
        trial=jnp.int32(0),
        chance=jnp.int32(0),
        log=jnp.zeros((n_trials,), jnp.int32),
        rtilde=jnp.zeros((n_chances,), float),
        prev_length=jnp.int32(0),
        next_action=jnp.int32(-1) if cfg.learner == "sarsa" else None,
    )


def _prefix_sums(x: jax.Array) -> jax.Array:
    """cumsum over a short last axis, unrolled: elementwise adds fuse with the ops around them,
    where ``jnp.cumsum`` becomes a separate reduce-window kernel (a per-step cost on CPU)."""
    if x.shape[-1] > 32:
        return jnp.cumsum(x, axis=-1)
    parts = [x[..., 0]]
    for a in range(1, x.shape[-1]):
        parts.append(parts[-1] + x[..., a])
    return jnp.stack(parts, axis=-1)


def sample_softmax(logits: jax.Array, allowed: jax.Array, u: jax.Array) -> jax.Array:
    """Inverse-CDF draw from softmax (1) restricted to `allowed`, with one uniform u ∈ [0, 1).

    Returns the smallest a with u·Σw < cumsum(w)[a], where w = exp(logits − max)·allowed.
    """
    shifted = logits - jnp.max(jnp.where(allowed, logits, -jnp.inf))
    weights = jnp.where(allowed, jnp.exp(shifted), 0.0)
    cdf = _prefix_sums(weights)
    action = jnp.sum(cdf <= u * cdf[-1])
    return jnp.minimum(action, logits.shape[0] - 1).astype(jnp.int32)


def restricts(n_flagged, n_actions: int) -> jax.Array:
    """E1(b): the failure memory restricts the choice when some but not all actions are flagged."""
    return (n_flagged > 0) & (n_flagged < n_actions)


def memory_choice(cfg: AgentConfig, sampled, remembered, restricted):
    """E1 (a) over (b)/(c), and E2. Returns (action, from_memory): the success action
    `remembered` (≥ 0) wins over the softmax draw `sampled`; `from_memory` is whether a memory
    chose or restricted the action (None: never, for AC), given `restricted` (E1 b, or None)."""
    from_memory = restricted if cfg.failure_memory else None
    action = sampled
    if cfg.success_memory:
        has_success = remembered >= 0
        action = jnp.where(has_success, remembered, sampled)
        from_memory = has_success if from_memory is None else from_memory | has_success
    return action, from_memory


def learns(cfg: AgentConfig, from_memory, active):
    """E2: an active step learns unless a memory chose or restricted its action (variant: always)."""
    if cfg.learn_on_memory_steps or from_memory is None:
        return active
    return active & ~from_memory


@pytree_dataclass
class StepRoute:
    """How E1 chose one step's action and whether the step learns (E2), for the memory
    diagnostics (E8). Every field is False where the step was not taken."""

    taken: jax.Array  # bool: the step was taken (`active`)
    remembered: jax.Array  # bool: E1(a), the success memory chose the action
    restricted: jax.Array  # bool: E1(b), no success action and the failure flags restricted the softmax
    learns: jax.Array  # bool: E2, the step updates p and V


def select_action(cfg: AgentConfig, agent: AgentState, state, u, hyper: Hyper, active=None,
                  route: bool = False):
    """E1: choose an action at `state` with the uniform `u`; returns (action, learns), where
    `learns` follows E2 (and is False where the step is not `active`). With `route` (static),
    returns (action, learns, `StepRoute`): which branch of E1 chose (E8's counters).

    (a) a success action → take it; (b) some but not all actions flagged failed →
    softmax over the unflagged ones; (c) otherwise plain AC softmax (1).
    """
    active = jnp.bool_(True) if active is None else active
    if cfg.learner != "actor_critic":  # X3: ε-greedy on Q; SARSA takes the action it bootstrapped on
        action = epsilon_greedy(agent.tables.row(state)[0], u, hyper.epsilon)
        if agent.next_action is not None:
            action = jnp.where(agent.next_action >= 0, agent.next_action, action)
        if route:
            return action, active, StepRoute(active, jnp.zeros_like(active), jnp.zeros_like(active), active)
        return action, active
    logits = agent.tables.row(state)[0] / hyper.temperature
    n_actions = logits.shape[0]
    allowed = jnp.ones((n_actions,), bool)
    restricted = remembered = None
    if cfg.failure_memory:
        flags = agent.memory.failure_flags(state, agent.trial, agent.outcomes)
        restricted = restricts(flags.sum(), n_actions)
        allowed = jnp.where(restricted, ~flags, allowed)
    if cfg.success_memory:
        remembered = agent.memory.success_action(state, agent.trial, agent.outcomes)
    action, from_memory = memory_choice(cfg, sample_softmax(logits, allowed, u), remembered, restricted)
    learn = learns(cfg, from_memory, active)
    if not route:
        return action, learn
    has_success = active & (remembered >= 0) if remembered is not None else jnp.zeros_like(active)
    by_flags = active & restricted & ~has_success if restricted is not None else jnp.zeros_like(active)
    return action, learn, StepRoute(active, has_success, by_flags, learn)


def epsilon_greedy(q: jax.Array, u: jax.Array, epsilon) -> jax.Array:
    """X3: with probability ε a uniformly random action, else a greedy one with ties broken
    uniformly at random, from the one uniform u ∈ [0, 1): u < ε explores with u/ε, the rest
    exploits with (u − ε)/(1 − ε)."""
    explore = u < epsilon
    v = jnp.where(explore, u / epsilon, (u - epsilon) / (1.0 - epsilon))
    allowed = explore | (q == jnp.max(q))
    count = jnp.maximum(allowed.sum(dtype=jnp.int32), 1)
    k = jnp.minimum((v * count).astype(jnp.int32), count - 1)  # the k-th allowed action, 0-based
    action = jnp.sum(_prefix_sums(allowed.astype(jnp.int32)) <= k)
    return jnp.minimum(action, q.shape[0] - 1).astype(jnp.int32)


def td_error(reward, value, next_value, gamma, terminated) -> jax.Array:
    """(3): δ = r + γ·V(s') − V(s), with V(s') = 0 at a terminal s'."""
    return reward + gamma * jnp.where(terminated, 0.0, next_value) - value


def learn_step(agent: AgentState, state, action, reward, next_state, terminated, learn, alpha, beta, gamma):
    """Eqs. (2)–(4) on one transition, applied when `learn` (E2)."""
    value = agent.tables.row(state)[1]
    delta = td_error(reward, value, agent.tables.value(next_state), gamma, terminated)
    return agent.replace(tables=agent.tables.learn(state, action, delta, alpha, beta, learn))


def value_learn_step(cfg: AgentConfig, agent: AgentState, state, action, reward, next_state, terminated,
                     learn, alpha, gamma, epsilon, next_uniform=None) -> AgentState:
    """X3, applied when `learn`: Q(s, a) ← Q(s, a) + α·δ with δ = r + γ·Q(s', a') − Q(s, a)
    (0 for Q(s', a') at a terminal s'): a' greedy for Q-learning (Watkins 1989), for SARSA
    (Rummery & Niranjan 1994) ε-greedy with `next_uniform`, kept as the next chance's action.
    Sutton & Barto (2018) §6.4–6.5; Q lives in the preference table and V stays 0."""
    q_next = agent.tables.row(next_state)[0]
    q = agent.tables.row(state)[0][action]
    next_action = agent.next_action
    if cfg.learner == "q_learning":
        bootstrap = jnp.max(q_next)
    else:
        chosen = epsilon_greedy(q_next, next_uniform, epsilon)
        bootstrap = q_next[chosen]
        next_action = jnp.where(learn, chosen, next_action)
    delta = td_error(reward, q, bootstrap, gamma, terminated)
    return agent.replace(tables=agent.tables.learn(state, action, delta, 0.0, alpha, learn),
                         next_action=next_action)


def failure_slot(rule: FailureRule, chance, n_chances: int):
    """E6: the r̃ slot chance `chance` is compared with: its own slot, which still holds trial
    t−1's r̃ (``previous_trial``), or the slot written one chance ago (``within_trial``)."""
    if rule == "previous_trial":
        return jnp.minimum(chance, n_chances - 1)
    return jnp.maximum(chance - 1, 0)


def failure_met(rule: FailureRule, chance, prev_length, rtilde, before) -> jax.Array:
    """E6 for the chance just taken, with immediate reward `rtilde` and the compared r̃ `before`
    (applies if the trial fails). ``previous_trial`` (paper): r̃(c|t) < r̃(c|t−1), for c that
    exists in trial t−1 too (never in the first trial). ``within_trial``: r̃(c|t) < r̃(c−1|t), c ≥ 2."""
    if rule == "previous_trial":
        return (chance < prev_length) & (rtilde < before)
    return (chance >= 1) & (rtilde < before)


def failure_condition(cfg: AgentConfig, agent: AgentState, rtilde, before=None) -> jax.Array:
    """E6 (`failure_met`) for the agent's current chance; `before` overrides the compared r̃
    read from its slot (the flat loop's memory jumps leave trial t−1's slots unwritten)."""
    c = agent.chance
    if before is None:
        before = agent.rtilde[failure_slot(cfg.failure_rule, c, agent.rtilde.shape[0])]
    return failure_met(cfg.failure_rule, c, agent.prev_length, rtilde, before)


def record_step(cfg: AgentConfig, agent: AgentState, state, action, rtilde, active,
                before=None) -> AgentState:
    """After each chance: keep r̃ (E5) and what the memories need (E4, E6); count the chance.
    `before`: the r̃ E6 compares with, when not the one in its slot (`failure_condition`)."""
    c = agent.chance
    kept = agent.rtilde
    flag = None
    if cfg.failure_memory:  # only E6 reads r̃ back
        flag = active & failure_condition(cfg, agent, rtilde, before)
        # An inactive step writes out of range (dropped). `active | flag` equals `active`, but it
        # makes the write depend on the read above, so XLA updates r̃ in place instead of copying it.
        kept = kept.at[jnp.where(active | flag, c, kept.shape[0])].set(rtilde, mode="drop")
    memory = agent.memory
    if memory is not None:
        memory = memory.record(state, action, c, agent.trial, agent.outcomes, active,
                               remember=cfg.success_memory, flag=flag)
    return agent.replace(rtilde=kept, memory=memory, chance=c + active.astype(jnp.int32))


def log_entry(success, length):
    """The trial log's entry of a finished trial: its length, negated if it failed (length ≥ 1)."""
    return jnp.where(success, length, -length)


def end_trial(cfg: AgentConfig, agent: AgentState, success, ends) -> AgentState:
    """Alg. 1 lines 15–29 when a trial ends (`ends`): record its outcome, which puts the dense
    memory's pending entries in effect; the buffer layout writes its slots now (E4 or E6)."""
    length = agent.chance
    memory = agent.memory
    if memory is not None:
        memory = memory.end_trial(length, success, ends, remember=cfg.success_memory,
                                  flag_failures=cfg.failure_memory)
    t = jnp.where(ends, agent.trial, agent.log.shape[0])  # not ending: dropped write
    log = agent.log.at[t].set(log_entry(success, length), mode="drop")
    next_action = agent.next_action
    if next_action is not None:  # SARSA: a new trial chooses afresh
        next_action = jnp.where(ends, -1, next_action)
    return agent.replace(
        memory=memory, log=log,
        prev_length=jnp.where(ends, length, agent.prev_length),
        trial=agent.trial + ends.astype(jnp.int32),
        chance=jnp.where(ends, 0, agent.chance),
        next_action=next_action,
    )


def greedy_policy(cfg: AgentConfig, agent: AgentState) -> jax.Array:
    """G7: int32 [S], the memory action where there is one, else argmax of preferences."""
    greedy = jnp.argmax(agent.preferences, axis=1).astype(jnp.int32)
    if not cfg.success_memory:
        return greedy
    remembered = agent.memory.policy_actions(agent.preferences.shape[0], agent.trial, agent.outcomes)
    return jnp.where(remembered >= 0, remembered, greedy)


def tables_finite(agent: AgentState) -> jax.Array:
    """bool []: every p(s, a) and V(s) is finite (a step size too large makes them blow up)."""
    return jnp.isfinite(agent.preferences).all() & jnp.isfinite(agent.values).all()
