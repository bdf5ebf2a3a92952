"""Success and failure memories as fixed-size masked arrays (SPEC E7).

The ACC's success-failure experience of Algorithm 1, in two layouts with the
same semantics, so a whole run is one jit-compiled function that vmaps over seeds:

* ``dense``: a success table ``int32 [S]`` (−1 = no action) and failure flags
  ``bool [S, A]``. Exact, O(S·A) bytes per seed.
* ``buffer``: K slots of (state, action) per memory with an insertion counter;
  slot ``i`` is valid while ``i < count``. O(K) bytes per seed, for state spaces
  too large for a table per seed.

**Buffer policy when full (documented, tested):** first-in, first-out. A new
entry goes to slot ``count mod K``, overwriting the oldest insertion. Updating
the action of a state already in the success buffer (E4's "last write wins")
changes that slot in place and does not count as an insertion. A failure pair
already in the buffer is not inserted again. With K at least the number of
distinct entries a run writes, the buffer behaves exactly like the dense table.

All functions are pure and single-stream (one seed); callers vmap.
"""

from __future__ import annotations

from typing import Literal

import jax
import jax.numpy as jnp

from jaxeac.pytree import pytree_dataclass

Layout = Literal["dense", "buffer"]
LAYOUTS = ("dense", "buffer")


@pytree_dataclass
class DenseMemory:
    """E7 dense layout: success action per state (−1 none) and failure flags."""

    success: jax.Array  # int32 [S]
    failure: jax.Array  # bool [S, A]


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
        return DenseMemory(
            success=jnp.full((n_states,), -1, jnp.int32),
            failure=jnp.zeros((n_states, n_actions), bool),
        )
    if layout == "buffer":
        empty = jnp.full((capacity,), -1, jnp.int32)
        zero = jnp.int32(0)
        return BufferMemory(empty, empty, zero, empty, empty, zero)
    raise ValueError(f"unknown memory layout {layout!r}; choose one of {LAYOUTS}")


def _slot_valid(count: jax.Array, capacity: int) -> jax.Array:
    return jnp.arange(capacity) < count


def success_action(memory: Memory, state: jax.Array) -> jax.Array:
    """E1(a): the remembered successful action at `state`, or −1."""
    if isinstance(memory, DenseMemory):
        return memory.success[state]
    capacity = memory.success_states.shape[0]
    match = _slot_valid(memory.success_count, capacity) & (memory.success_states == state)
    return jnp.where(match.any(), memory.success_actions[jnp.argmax(match)], -1)


def failure_flags(memory: Memory, state: jax.Array, n_actions: int) -> jax.Array:
    """E1(b): bool [A], the actions flagged failed at `state`."""
    if isinstance(memory, DenseMemory):
        return memory.failure[state]
    capacity = memory.failure_states.shape[0]
    match = _slot_valid(memory.failure_count, capacity) & (memory.failure_states == state)
    actions = jnp.arange(n_actions)
    return (match[:, None] & (memory.failure_actions[:, None] == actions[None, :])).any(0)


def last_occurrence(states: jax.Array, valid: jax.Array) -> jax.Array:
    """bool [C]: step c is valid and no later valid step visits the same state."""
    c = states.shape[0]
    later = jnp.arange(c)[None, :] > jnp.arange(c)[:, None]
    same = (states[:, None] == states[None, :]) & valid[None, :] & later
    return valid & ~same.any(axis=1)


def write_success(memory: Memory, states: jax.Array, actions: jax.Array, valid: jax.Array):
    """E4: write a successful trial's (state, action) pairs in chronological order.

    A state visited twice keeps the action taken last; entries from earlier
    successful trials are overwritten the same way.
    """
    if isinstance(memory, DenseMemory):
        keep = last_occurrence(states, valid)
        index = jnp.where(keep, states, memory.success.shape[0])  # out of range → dropped
        success = memory.success.at[index].set(actions, mode="drop", unique_indices=True)
        return memory.replace(success=success)

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

    memory, _ = jax.lax.scan(put, memory, (states, actions, valid))
    return memory


def write_failure(memory: Memory, states: jax.Array, actions: jax.Array, flag: jax.Array):
    """E6: flag each (state(c), action(c)) with ``flag[c]`` as failed."""
    if isinstance(memory, DenseMemory):
        n_states = memory.failure.shape[0]
        index = jnp.where(flag, states, n_states)  # unflagged → dropped
        return memory.replace(failure=memory.failure.at[index, actions].set(True, mode="drop"))

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

    memory, _ = jax.lax.scan(put, memory, (states, actions, flag))
    return memory


def policy_actions(memory: Memory, n_states: int) -> jax.Array:
    """int32 [S]: the success-memory action per state (−1 where none), for G7."""
    if isinstance(memory, DenseMemory):
        return memory.success
    return jax.vmap(lambda s: success_action(memory, s))(jnp.arange(n_states))
