"""Success and failure memories as fixed-size masked arrays (SPEC E7).

The ACC's success-failure experience of Algorithm 1 in two layouts with the same
semantics, so a whole run is one jit-compiled function that vmaps over seeds.

**dense** (tables, O(1) work per step). Algorithm 1 writes memories after a
trial (E4, E6), which would cost O(C) per trial end; under vmap, masked trial
ends cost that on *every* step. The dense layout instead records each step as a
*pending* entry stamped with its trial index, and a pending entry takes effect
once the trial's outcome (``outcomes[trial]``) says so:

* success: ``pending[s]`` is the last action taken at s in trial ``pending_trial[s]``;
  it is the remembered action iff that trial is over and succeeded (E4: a state
  visited twice keeps its last action). Before overwriting it, a step commits
  it to ``success[s]`` if it was effective, so older successes survive failed trials.
* failure: ``candidate_trial[s, a]`` is the latest trial in which (s, a) met the
  E6 condition; the flag is effective iff that trial is over and failed.

Lookups during trial t see exactly the memory after trial t − 1, as in Algorithm 1.

**buffer** (K slots, O(K) bytes per seed): (state, action) slots written at the
end of a trial in chronological order. *Policy when full:* first-in, first-out —
a new entry goes to slot ``count mod K``, evicting the oldest insertion. Updating
the action of a state already in the success buffer changes its slot in place
(not an insertion); a failure pair already present is not inserted again. With K
at least the number of distinct entries a run writes, both layouts give
bit-identical runs.

All functions are pure and single-stream (one seed); callers vmap.
"""

from __future__ import annotations

from typing import Literal

import jax
import jax.numpy as jnp

from jaxeac.pytree import pytree_dataclass

Layout = Literal["dense", "buffer"]
LAYOUTS = ("dense", "buffer")


def action_dtype(n_actions: int):
    """Smallest signed integer type holding −1 … A−1."""
    return jnp.int8 if n_actions <= 127 else jnp.int32


@pytree_dataclass
class DenseMemory:
    """E7 dense layout with lazily committed pending entries (see module docstring)."""

    success: jax.Array  # int8 [S], committed success action, −1 = none
    pending: jax.Array  # int8 [S], last action at s in trial pending_trial[s]
    pending_trial: jax.Array  # int32 [S], −1 = none
    failed: jax.Array  # bool [S, A], committed failure flags
    candidate_trial: jax.Array  # int32 [S, A], latest trial where (s, a) met E6, −1 = none


@pytree_dataclass
class BufferMemory:
    """E7 buffer layout: K (state, action) slots per memory, FIFO when full."""

    success_states: jax.Array  # int32 [K]
    success_actions: jax.Array  # int32 [K]
    success_count: jax.Array  # int32 [], insertions so far
    failure_states: jax.Array  # int32 [K]
    failure_actions: jax.Array  # int32 [K]
    failure_count: jax.Array  # int32 []


Memory = DenseMemory | BufferMemory


def init_memory(layout: Layout, n_states: int, n_actions: int, capacity: int) -> Memory:
    """Empty memories: no success action anywhere, no failure flag."""
    if layout == "dense":
        none = jnp.full((n_states,), -1, action_dtype(n_actions))
        never = jnp.full((n_states,), -1, jnp.int32)
        return DenseMemory(
            success=none, pending=none, pending_trial=never,
            failed=jnp.zeros((n_states, n_actions), bool),
            candidate_trial=jnp.full((n_states, n_actions), -1, jnp.int32),
        )
    if layout == "buffer":
        empty = jnp.full((capacity,), -1, jnp.int32)
        zero = jnp.int32(0)
        return BufferMemory(empty, empty, zero, empty, empty, zero)
    raise ValueError(f"unknown memory layout {layout!r}; choose one of {LAYOUTS}")


def _ended(stamp: jax.Array, trial: jax.Array, outcomes: jax.Array, success: bool) -> jax.Array:
    """Whether entries stamped with trial `stamp` are in effect during `trial`."""
    outcome = outcomes[jnp.maximum(stamp, 0)]
    return (stamp >= 0) & (stamp < trial) & (outcome if success else ~outcome)


def _slot_valid(count: jax.Array, capacity: int) -> jax.Array:
    return jnp.arange(capacity) < count


# --- lookups (E1) -------------------------------------------------------------------------


def success_action(memory: Memory, state, trial, outcomes) -> jax.Array:
    """E1(a): the remembered successful action at `state` during `trial`, or −1."""
    if isinstance(memory, DenseMemory):
        live = _ended(memory.pending_trial[state], trial, outcomes, success=True)
        return jnp.where(live, memory.pending[state], memory.success[state]).astype(jnp.int32)
    capacity = memory.success_states.shape[0]
    match = _slot_valid(memory.success_count, capacity) & (memory.success_states == state)
    return jnp.where(match.any(), memory.success_actions[jnp.argmax(match)], -1)


def failure_flags(memory: Memory, state, trial, outcomes, n_actions: int) -> jax.Array:
    """E1(b): bool [A], the actions flagged failed at `state` during `trial`."""
    if isinstance(memory, DenseMemory):
        live = _ended(memory.candidate_trial[state], trial, outcomes, success=False)
        return memory.failed[state] | live
    capacity = memory.failure_states.shape[0]
    match = _slot_valid(memory.failure_count, capacity) & (memory.failure_states == state)
    actions = jnp.arange(n_actions)
    return (match[:, None] & (memory.failure_actions[:, None] == actions[None, :])).any(0)


# --- dense layout: per-step pending writes ---------------------------------------------------


def record_visit(memory: DenseMemory, state, action, trial, outcomes, active) -> DenseMemory:
    """E4, lazily: make `action` the pending success action of `state` for `trial`."""
    commit = _ended(memory.pending_trial[state], trial, outcomes, success=True)
    committed = jnp.where(active & commit, memory.pending[state], memory.success[state])
    return memory.replace(
        success=memory.success.at[state].set(committed, unique_indices=True),
        pending=memory.pending.at[state].set(
            jnp.where(active, action, memory.pending[state]).astype(memory.pending.dtype),
            unique_indices=True),
        pending_trial=memory.pending_trial.at[state].set(
            jnp.where(active, trial, memory.pending_trial[state]), unique_indices=True),
    )


def record_failure_candidate(memory: DenseMemory, state, action, trial, outcomes, flag) -> DenseMemory:
    """E6, lazily: (state, action) met the failure condition in `trial` (effective if it fails)."""
    stamp = memory.candidate_trial[state, action]
    commit = flag & _ended(stamp, trial, outcomes, success=False)
    return memory.replace(
        failed=memory.failed.at[state, action].set(memory.failed[state, action] | commit,
                                                   unique_indices=True),
        candidate_trial=memory.candidate_trial.at[state, action].set(
            jnp.where(flag, trial, stamp), unique_indices=True),
    )


def dense_tables(memory: DenseMemory, trial, outcomes) -> tuple[jax.Array, jax.Array]:
    """(success int32 [S], failed bool [S, A]): the memory in effect during `trial`."""
    memory, outcomes = jax.tree.map(jnp.asarray, (memory, outcomes))
    states = jnp.arange(memory.success.shape[0])
    success = jax.vmap(lambda s: success_action(memory, s, trial, outcomes))(states)
    live = _ended(memory.candidate_trial, trial, outcomes, success=False)
    return success, memory.failed | live


# --- buffer layout: end-of-trial writes -----------------------------------------------------


def write_success(memory: BufferMemory, states, actions, valid) -> BufferMemory:
    """E4 for the buffer: write a successful trial's pairs in chronological order (last wins)."""
    capacity = memory.success_states.shape[0]

    def put(mem: BufferMemory, step):
        state, action, ok = step
        match = _slot_valid(mem.success_count, capacity) & (mem.success_states == state)
        found = match.any()
        slot = jnp.where(found, jnp.argmax(match), mem.success_count % capacity)
        slot = jnp.where(ok, slot, capacity)  # invalid step → dropped write
        mem = mem.replace(
            success_states=mem.success_states.at[slot].set(state, mode="drop"),
            success_actions=mem.success_actions.at[slot].set(action, mode="drop"),
            success_count=mem.success_count + (ok & ~found),
        )
        return mem, None

    return jax.lax.scan(put, memory, (states, actions, valid))[0]


def write_failure(memory: BufferMemory, states, actions, flag) -> BufferMemory:
    """E6 for the buffer: flag each (state(c), action(c)) with ``flag[c]``, in order."""
    capacity = memory.failure_states.shape[0]

    def put(mem: BufferMemory, step):
        state, action, ok = step
        valid = _slot_valid(mem.failure_count, capacity)
        found = (valid & (mem.failure_states == state) & (mem.failure_actions == action)).any()
        insert = ok & ~found
        slot = jnp.where(insert, mem.failure_count % capacity, capacity)
        mem = mem.replace(
            failure_states=mem.failure_states.at[slot].set(state, mode="drop"),
            failure_actions=mem.failure_actions.at[slot].set(action, mode="drop"),
            failure_count=mem.failure_count + insert,
        )
        return mem, None

    return jax.lax.scan(put, memory, (states, actions, flag))[0]


def policy_actions(memory: Memory, n_states: int, trial, outcomes) -> jax.Array:
    """int32 [S]: the success-memory action per state (−1 where none), for G7."""
    return jax.vmap(lambda s: success_action(memory, s, trial, outcomes))(jnp.arange(n_states))
