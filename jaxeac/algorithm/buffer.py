"""E7's buffer layout: K (state, action) slots per memory, for state spaces too large for tables.

Slots are written at the end of a trial in chronological order (Alg. 1 lines 15–28).
*Policy when full:* first-in, first-out — a new entry goes to slot ``count mod K``,
evicting the oldest insertion. Updating the action of a state already in the success
buffer changes its slot in place (not an insertion); a failure pair already present
is not inserted again. With K at least the number of distinct entries a run writes,
it gives bit-identical runs to the dense layout (`jaxeac.algorithm.memory`), whose
interface (`Memory`) it implements.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxeac.pytree import pytree_dataclass, static_field


def _slot_valid(count: jax.Array, capacity: int) -> jax.Array:
    return jnp.arange(capacity) < count


@pytree_dataclass
class BufferMemory:
    """E7 buffer layout: K (state, action) slots per memory, FIFO when full.

    The trial in progress is kept as a path of C (state, action, E6 flag) entries,
    written to the slots when the trial ends (Alg. 1 lines 15–28).
    """

    success_states: jax.Array  # int32 [K]
    success_actions: jax.Array  # int32 [K]
    success_count: jax.Array  # int32 [], insertions so far
    failure_states: jax.Array  # int32 [K]
    failure_actions: jax.Array  # int32 [K]
    failure_count: jax.Array  # int32 []
    path_states: jax.Array  # int32 [C], the trial in progress
    path_actions: jax.Array  # int32 [C]
    path_flags: jax.Array  # bool [C], E6 met at that chance
    n_actions: int = static_field()

    def success_action(self, state, trial, outcomes) -> jax.Array:
        capacity = self.success_states.shape[0]
        match = _slot_valid(self.success_count, capacity) & (self.success_states == state)
        return jnp.where(match.any(), self.success_actions[jnp.argmax(match)], -1)

    def failure_flags(self, state, trial, outcomes) -> jax.Array:
        capacity = self.failure_states.shape[0]
        match = _slot_valid(self.failure_count, capacity) & (self.failure_states == state)
        actions = jnp.arange(self.n_actions)
        return (match[:, None] & (self.failure_actions[:, None] == actions[None, :])).any(0)

    def record(self, state, action, chance, trial, outcomes, active, *, remember, flag) -> BufferMemory:
        index = jnp.where(active, chance, chance.dtype.type(self.path_states.shape[0]))  # inactive → dropped
        return self.replace(
            path_states=self.path_states.at[index].set(state, mode="drop"),
            path_actions=self.path_actions.at[index].set(action, mode="drop"),
            path_flags=self.path_flags.at[index].set(flag if flag is not None else False, mode="drop"),
        )

    def end_trial(self, length, success, ends, *, remember, flag_failures) -> BufferMemory:
        valid = (jnp.arange(self.path_states.shape[0]) < length) & ends
        memory = self
        if remember:
            memory = write_success(memory, self.path_states, self.path_actions, valid & success)
        if flag_failures:
            memory = write_failure(memory, self.path_states, self.path_actions,
                                   self.path_flags & valid & ~success)
        return memory

    def policy_actions(self, n_states: int, trial, outcomes) -> jax.Array:
        return jax.vmap(lambda s: self.success_action(s, trial, outcomes))(jnp.arange(n_states))


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
