"""Actor-critic (AC) and enhanced actor-critic (EAC) as pure single-stream functions.

Debnath & Nassour (2014): equations (1)–(4) for AC and Algorithm 1 for EAC,
with every open point pinned by SPEC E1–E7. AC is EAC with both memories off;
there is one code path. Callers vmap over seeds.

* (1) π(a|s) ∝ exp(p(s,a)/τ), preferences start at 0 (uniform policy).
* (3) δ = r + γ·V(s') − V(s), with V(s') = 0 when s' is terminal.
* critic: V(s) ← V(s) + α·δ;  (4) actor: p(s,a) ← p(s,a) + β·δ.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Literal

import jax
import jax.numpy as jnp

from jaxeac.algorithm import memory as mem
from jaxeac.errors import UsageError
from jaxeac.pytree import pytree_dataclass, static_field

FailureRule = Literal["previous_trial", "within_trial"]
FAILURE_RULES = ("previous_trial", "within_trial")
TableLayout = Literal["auto", "split", "rows"]
TABLE_LAYOUTS = ("auto", "split", "rows")

#: A step size: a constant, or an optax schedule over the 0-based trial index.
Rate = float | Callable[[jax.Array], jax.Array]


@dataclasses.dataclass(frozen=True)
class AgentConfig:
    """Static choices of the agent (shapes and code paths; hashed by jit).

    `success_memory` / `failure_memory` switch the two memories of Algorithm 1;
    both off is the classic AC. `learn_on_memory_steps` is the E2 variant and
    `failure_rule` the E6 variant. `memory` (E7) and `tables` (`SplitTables` or
    `RowTables`; `auto` picks by backend) are storage layouts: same results, different speed.
    """

    success_memory: bool = True
    failure_memory: bool = True
    learn_on_memory_steps: bool = False
    failure_rule: FailureRule = "previous_trial"
    memory: mem.Layout = "dense"
    capacity: int = 1024
    tables: TableLayout = "auto"

    def __post_init__(self):
        if self.failure_rule not in FAILURE_RULES:
            raise UsageError(
                f"unknown failure_rule {self.failure_rule!r}; choose one of {FAILURE_RULES}"
            )
        if self.tables not in TABLE_LAYOUTS:
            raise UsageError(f"unknown table layout {self.tables!r}; choose one of {TABLE_LAYOUTS}")
        if self.memory not in mem.LAYOUTS:
            raise UsageError(f"unknown memory layout {self.memory!r}; choose one of {mem.LAYOUTS}")
        if isinstance(self.capacity, bool) or not isinstance(self.capacity, int) or self.capacity <= 0:
            raise UsageError(f"capacity must be a positive integer (got {self.capacity!r})")

    @property
    def uses_memory(self) -> bool:
        return self.success_memory or self.failure_memory


#: The two algorithms of the paper, plus memory ablations (issue: which part of EAC works?).
ALGORITHMS: dict[str, AgentConfig] = {
    "ac": AgentConfig(success_memory=False, failure_memory=False),
    "eac": AgentConfig(),
    "eac_success_only": AgentConfig(failure_memory=False),
    "eac_failure_only": AgentConfig(success_memory=False),
    "eac_learn_on_memory": AgentConfig(learn_on_memory_steps=True),  # E2 variant
    "eac_within_trial": AgentConfig(failure_rule="within_trial"),  # E6 variant
}


def algorithm(name: str, **overrides) -> AgentConfig:
    """The `AgentConfig` of a named algorithm, with overrides (e.g. memory layout)."""
    if name not in ALGORITHMS:
        raise UsageError(f"unknown algorithm {name!r}; choose from {sorted(ALGORITHMS)}")
    return dataclasses.replace(ALGORITHMS[name], **overrides)


@pytree_dataclass
class Hyper:
    """Traced numeric settings (vmappable for sweeps): rates, discount, temperature."""

    alpha: jax.Array  # critic step size
    beta: jax.Array  # actor step size
    gamma: jax.Array  # discount
    temperature: jax.Array  # softmax temperature τ of (1)


def critic_update(values: jax.Array, state, delta, alpha, learn) -> jax.Array:
    """(2): V(s) ← V(s) + α·δ (only when `learn`)."""
    return values.at[state].add(jnp.where(learn, alpha * delta, 0.0), unique_indices=True)


def actor_update(preferences: jax.Array, state, action, delta, beta, learn) -> jax.Array:
    """(4): p(s,a) ← p(s,a) + β·δ for the taken action only (only when `learn`)."""
    return preferences.at[state, action].add(jnp.where(learn, beta * delta, 0.0), unique_indices=True)


@pytree_dataclass
class SplitTables:
    """p(s, a) and V(s) as two arrays: the fewest bytes per seed (CPU default)."""

    preferences: jax.Array  # float [S, A]
    values: jax.Array  # float [S]

    def row(self, state) -> tuple[jax.Array, jax.Array]:
        """(p(s, ·) [A], V(s))."""
        return self.preferences[state], self.values[state]

    def value(self, state) -> jax.Array:
        return self.values[state]

    def learn(self, state, action, delta, alpha, beta, learn) -> SplitTables:
        """(2) and (4) at (state, action), applied when `learn`."""
        return SplitTables(actor_update(self.preferences, state, action, delta, beta, learn),
                           critic_update(self.values, state, delta, alpha, learn))


ROW_FLOATS = 8  # rows padded to a multiple of 8 floats: 32 bytes, one memory sector on GPUs


@pytree_dataclass
class RowTables:
    """p(s, ·) and V(s) side by side, one padded row per state (GPU default).

    Row s is ``[p(s, 0) … p(s, A−1), V(s), 0 …]`` with W = A + 1 rounded up to a multiple of
    8. A step reads row s once (softmax (1), δ of (3)) and writes it back once with both
    updates (2) and (4), where split tables take two scattered writes; on GPUs, where each
    scattered access costs a memory transaction, that is the cheaper layout. Same
    arithmetic, so both layouts give bit-identical runs.
    """

    rows: jax.Array  # float [S, W]
    n_actions: int = static_field()

    @property
    def preferences(self) -> jax.Array:
        return self.rows[:, :self.n_actions]

    @property
    def values(self) -> jax.Array:
        return self.rows[:, self.n_actions]

    def row(self, state) -> tuple[jax.Array, jax.Array]:
        r = self.rows[state]
        return r[:self.n_actions], r[self.n_actions]

    def value(self, state) -> jax.Array:
        return self.rows[state, self.n_actions]

    def learn(self, state, action, delta, alpha, beta, learn) -> RowTables:
        """(2) and (4) at (state, action) as one row write, applied when `learn`."""
        step = jnp.where(learn, delta, 0.0)
        column = jnp.arange(self.rows.shape[1])
        change = jnp.where(column == self.n_actions, alpha * step,
                           jnp.where(column == action, beta * step, 0.0))
        return self.replace(rows=self.rows.at[state].set(self.rows[state] + change, unique_indices=True))


Tables = SplitTables | RowTables


def resolve_tables(layout: TableLayout) -> Literal["split", "rows"]:
    """`auto`: rows on accelerators, split tables on the CPU (measured in BENCHMARKS.md)."""
    if layout != "auto":
        return layout
    return "split" if jax.default_backend() == "cpu" else "rows"


def init_tables(layout: TableLayout, n_states: int, n_actions: int) -> Tables:
    """p = 0 and V = 0 everywhere (the uniform policy of Alg. 1 line 1)."""
    if resolve_tables(layout) == "rows":
        width = -(-(n_actions + 1) // ROW_FLOATS) * ROW_FLOATS
        return RowTables(rows=jnp.zeros((n_states, width), float), n_actions=n_actions)
    return SplitTables(preferences=jnp.zeros((n_states, n_actions), float),
                       values=jnp.zeros((n_states,), float))


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
    memory: mem.Memory | None  # success/failure experience (None for AC)
    goal_known: jax.Array  # bool [], E5: goal reached at least once
    trial: jax.Array  # int32 [], 0-based index of the current trial
    chance: jax.Array  # int32 [], chances taken so far in the current trial
    log: jax.Array  # int32 [T], per finished trial: chances used, negated if it failed; 0 = not yet
    rtilde: jax.Array  # float [C], the latest r̃ per chance index: trial t−1's until trial t writes it
    prev_length: jax.Array  # int32 [], chances used in the previous trial (0 before trial 2)
    path: tuple[jax.Array, jax.Array, jax.Array] | None  # buffer layout: states, actions, E6 flags [C]

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
    """Preferences and values at 0 (uniform "random" policy, Alg. 1 line 1), empty memories."""
    memory = None
    if cfg.uses_memory:
        if cfg.memory == "dense":
            mem.check_dense_limits(n_actions, n_trials)
        memory = mem.init_memory(cfg.memory, n_states, n_actions, cfg.capacity, n_trials)
    path = None
    if cfg.uses_memory and cfg.memory == "buffer":
        path = (jnp.zeros((n_chances,), jnp.int32), jnp.zeros((n_chances,), jnp.int32),
                jnp.zeros((n_chances,), bool))
    return AgentState(
        tables=init_tables(cfg.tables, n_states, n_actions),
        memory=memory,
        goal_known=jnp.bool_(False),
        trial=jnp.int32(0),
        chance=jnp.int32(0),
        log=jnp.zeros((n_trials,), jnp.int32),
        rtilde=jnp.zeros((n_chances,), float),
        prev_length=jnp.int32(0),
        path=path,
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


def select_action(cfg: AgentConfig, agent: AgentState, state, u, hyper: Hyper):
    """E1: choose an action at `state`; returns (action, learns) where `learns` follows E2.

    (a) a success action → take it; (b) some but not all actions flagged failed →
    softmax over the unflagged ones; (c) otherwise plain AC softmax (1).
    """
    logits = agent.tables.row(state)[0] / hyper.temperature
    n_actions = logits.shape[0]
    allowed = jnp.ones((n_actions,), bool)
    from_memory = jnp.bool_(False)
    if cfg.failure_memory:
        flags = mem.failure_flags(agent.memory, state, agent.trial, agent.outcomes, n_actions)
        n_flagged = flags.sum()
        restrict = (n_flagged > 0) & (n_flagged < n_actions)
        allowed = jnp.where(restrict, ~flags, allowed)
        from_memory = restrict
    action = sample_softmax(logits, allowed, u)
    if cfg.success_memory:
        remembered = mem.success_action(agent.memory, state, agent.trial, agent.outcomes)
        has_success = remembered >= 0
        action = jnp.where(has_success, remembered, action)
        from_memory = from_memory | has_success
    learns = jnp.bool_(True) if cfg.learn_on_memory_steps else ~from_memory
    return action, learns


def td_error(reward, value, next_value, gamma, terminated) -> jax.Array:
    """(3): δ = r + γ·V(s') − V(s), with V(s') = 0 at a terminal s'."""
    return reward + gamma * jnp.where(terminated, 0.0, next_value) - value


def learn_step(agent: AgentState, state, action, reward, next_state, terminated, learn, alpha, beta, gamma):
    """Eqs. (2)–(4) on one transition, applied when `learn` (E2)."""
    value = agent.tables.row(state)[1]
    delta = td_error(reward, value, agent.tables.value(next_state), gamma, terminated)
    return agent.replace(tables=agent.tables.learn(state, action, delta, alpha, beta, learn))


def failure_condition(cfg: AgentConfig, agent: AgentState, rtilde) -> jax.Array:
    """E6 for the chance just taken, with immediate reward `rtilde` (applies if the trial fails).

    ``previous_trial`` (paper): r̃(c|t) < r̃(c|t−1), for c that exists in trial t−1 too
    (never in the first trial). ``within_trial`` (variant): r̃(c|t) < r̃(c−1|t), c ≥ 2.
    """
    c = agent.chance
    if cfg.failure_rule == "previous_trial":  # slot c still holds trial t−1's r̃ (if it got that far)
        return (c < agent.prev_length) & (rtilde < agent.rtilde[jnp.minimum(c, agent.rtilde.shape[0] - 1)])
    return (c >= 1) & (rtilde < agent.rtilde[jnp.maximum(c - 1, 0)])  # written one chance ago


def record_step(cfg: AgentConfig, agent: AgentState, state, action, rtilde, active) -> AgentState:
    """After each chance: keep r̃ (E5) and what the memories need (E4, E6); count the chance."""
    c, trial = agent.chance, agent.trial
    kept = agent.rtilde
    flag = None
    if cfg.failure_memory:  # only E6 reads r̃ back
        flag = active & failure_condition(cfg, agent, rtilde)
        # An inactive step writes out of range (dropped). `active | flag` equals `active`, but it
        # makes the write depend on the read above, so XLA updates r̃ in place instead of copying it.
        kept = kept.at[jnp.where(active | flag, c, kept.shape[0])].set(rtilde, mode="drop")
    memory, path = agent.memory, agent.path
    if isinstance(memory, mem.PackedMemory):
        memory = mem.record_packed(memory, state, action, trial, agent.outcomes, active,
                                   cfg.success_memory, flag if flag is not None else False)
    elif isinstance(memory, mem.DenseMemory):
        if cfg.success_memory:
            memory = mem.record_visit(memory, state, action, trial, agent.outcomes, active)
        if cfg.failure_memory:
            memory = mem.record_failure_candidate(memory, state, action, trial, agent.outcomes, flag)
    elif path is not None:
        index = jnp.where(active, c, c.dtype.type(path[0].shape[0]))  # inactive → dropped
        path = (path[0].at[index].set(state, mode="drop"),
                path[1].at[index].set(action, mode="drop"),
                path[2].at[index].set(flag if flag is not None else False, mode="drop"))
    return agent.replace(
        rtilde=kept, memory=memory, path=path,
        chance=c + active.astype(jnp.int32),
    )


def end_trial(cfg: AgentConfig, agent: AgentState, success, ends) -> AgentState:
    """Alg. 1 lines 15–29 when a trial ends (`ends`): record its outcome, which puts the dense
    memory's pending entries in effect; the buffer layout writes its slots now (E4 or E6)."""
    length = agent.chance
    memory = agent.memory
    if isinstance(memory, mem.BufferMemory):
        states, actions, flags = agent.path
        valid = (jnp.arange(states.shape[0]) < length) & ends
        if cfg.success_memory:
            memory = mem.write_success(memory, states, actions, valid & success)
        if cfg.failure_memory:
            memory = mem.write_failure(memory, states, actions, flags & valid & ~success)
    t = jnp.where(ends, agent.trial, agent.log.shape[0])  # not ending: dropped write
    log = agent.log.at[t].set(jnp.where(success, length, -length), mode="drop")  # a trial takes ≥ 1 chance
    return agent.replace(
        memory=memory, log=log,
        prev_length=jnp.where(ends, length, agent.prev_length),
        trial=agent.trial + ends.astype(jnp.int32),
        chance=jnp.where(ends, 0, agent.chance),
    )


def greedy_policy(cfg: AgentConfig, agent: AgentState) -> jax.Array:
    """G7: int32 [S], the memory action where there is one, else argmax of preferences."""
    greedy = jnp.argmax(agent.preferences, axis=1).astype(jnp.int32)
    if not cfg.success_memory:
        return greedy
    remembered = mem.policy_actions(agent.memory, agent.preferences.shape[0], agent.trial, agent.outcomes)
    return jnp.where(remembered >= 0, remembered, greedy)


def rate_at(rate: Rate, traced: jax.Array, trial: jax.Array) -> jax.Array:
    """A step size at a 0-based trial: the optax schedule's value, else the traced constant."""
    return rate(trial) if callable(rate) else traced
