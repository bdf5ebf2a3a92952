"""Success and failure memories as fixed-size masked arrays (SPEC E7).

The ACC's success-failure experience of Algorithm 1 in two layouts with the same
semantics, so a whole run is one jit-compiled function that vmaps over seeds.

**dense** (tables, O(1) work per step). Algorithm 1 writes memories after a
trial (E4, E6), which would cost O(C) per trial end; under vmap, masked trial
ends cost that on *every* step. The dense layout instead records each step as a
*pending* entry stamped with its trial index, and a pending entry takes effect
once the trial's outcome (``outcomes[trial]``) says so:

* success: per state, the committed action, the last action taken there in trial
  ``stamp`` (pending) and ``stamp``; the pending action is the remembered one iff
  that trial is over and succeeded (E4: a state visited twice keeps its last
  action). Before a newer trial overwrites it, an effective pending action is
  committed, so older successes survive failed trials.
* failure: per state, the committed failed actions (a bit set), the actions that
  met the E6 condition in trial ``stamp`` (pending bits) and ``stamp``; pending
  bits count iff that trial is over and failed.

Each is packed into one int32 word per state, so a step costs one gather and one
scatter per memory. Limits: A ≤ 24 actions, fewer than 2^(31 − A) trials, and at
most 254 actions and 32,766 trials for the success word (checked at init).
Lookups during trial t see exactly the memory after trial t − 1, as in Algorithm 1.

With few actions (A ≤ 5, as on the grid) and a run's trial count known, both
memories share **one word per state** (`PackedMemory`): every visit stamps the
state with its trial and settles the previous stamp's pending entries, whose
trial is over by then. Same semantics, one gather and one scatter per step for
both memories (each write is a separate kernel on CPU, so this is what EAC's
per-step cost is made of); chosen automatically by `init_memory`.

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

from typing import Literal, NamedTuple

import jax
import jax.numpy as jnp

from jaxeac.errors import UsageError
from jaxeac.pytree import pytree_dataclass, static_field

Layout = Literal["dense", "buffer"]
LAYOUTS = ("dense", "buffer")


MAX_DENSE_ACTIONS = 24


@pytree_dataclass
class DenseMemory:
    """E7 dense layout with lazily committed pending entries (see module docstring)."""

    success: jax.Array  # int32 [S]: (stamp + 1) << 16 | (pending + 1) << 8 | (committed + 1)
    failed: jax.Array  # int32 [S]: bit a set ⇔ action a committed as failed
    failure_pending: jax.Array  # int32 [S]: (stamp + 1) << A | pending failure bits
    n_actions: int = static_field()
@pytree_dataclass
class PackedMemory:
    """E7 dense layout, both memories in one int32 word per state (A ≤ 5; see module docstring).

    Fields from the low bits: committed success action + 1 and pending success action
    + 1 (`action_bits` each), committed failed bits and pending failed bits (A each),
    and the trial stamp + 1 of the last visit in the remaining high bits.
    """

    words: jax.Array  # int32 [S]
    n_actions: int = static_field()

    @property
    def action_bits(self) -> int:
        return packed_action_bits(self.n_actions)


@pytree_dataclass
class BufferMemory:
    """E7 buffer layout: K (state, action) slots per memory, FIFO when full."""

    success_states: jax.Array  # int32 [K]
    success_actions: jax.Array  # int32 [K]
    success_count: jax.Array  # int32 [], insertions so far
    failure_states: jax.Array  # int32 [K]
    failure_actions: jax.Array  # int32 [K]
    failure_count: jax.Array  # int32 []


Memory = DenseMemory | PackedMemory | BufferMemory


def check_dense_limits(n_actions: int, n_trials: int) -> None:
    """The dense layout's packed words hold A ≤ 24 actions and a bounded trial count."""
    if n_actions > MAX_DENSE_ACTIONS or n_trials >= min(1 << (31 - n_actions), 32_767):
        raise UsageError(
            f"the dense memory layout holds at most {MAX_DENSE_ACTIONS} actions and fewer than "
            f"min(2^(31-A), 32767) trials (got A={n_actions}, T={n_trials}); use the buffer layout"
        )


MAX_PACKED_ACTIONS = 5


def packed_action_bits(n_actions: int) -> int:
    """Bits of one stored action + 1 (0 = none) in a `PackedMemory` word."""
    return int(n_actions).bit_length()


def packed_fits(n_actions: int, n_trials: int) -> bool:
    """Whether one int32 word per state holds both memories for A actions and T trials."""
    free = 31 - 2 * packed_action_bits(n_actions) - 2 * n_actions
    return n_actions <= MAX_PACKED_ACTIONS and n_trials + 1 < (1 << free)


def init_memory(layout: Layout, n_states: int, n_actions: int, capacity: int,
                n_trials: int | None = None) -> Memory:
    """Empty memories: no success action anywhere, no failure flag.

    The dense layout packs both memories into one word per state when the run's trial
    count `n_trials` is given and fits (`packed_fits`), else uses three words per state.
    """
    if layout == "dense" and n_trials is not None and packed_fits(n_actions, n_trials):
        return PackedMemory(words=jnp.zeros((n_states,), jnp.int32), n_actions=n_actions)
    if layout == "dense":
        zeros = jnp.zeros((n_states,), jnp.int32)  # every field stored + 1: 0 = none
        return DenseMemory(success=zeros, failed=zeros, failure_pending=zeros, n_actions=n_actions)
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
    if isinstance(memory, PackedMemory):
        f = _unpack_packed(memory, memory.words[state])
        return jnp.where(_ended(f.stamp, trial, outcomes, success=True), f.pending, f.committed)
    if isinstance(memory, DenseMemory):
        stamp, pending, committed = _unpack_success(memory.success[state])
        return jnp.where(_ended(stamp, trial, outcomes, success=True), pending, committed)
    capacity = memory.success_states.shape[0]
    match = _slot_valid(memory.success_count, capacity) & (memory.success_states == state)
    return jnp.where(match.any(), memory.success_actions[jnp.argmax(match)], -1)


def failure_flags(memory: Memory, state, trial, outcomes, n_actions: int) -> jax.Array:
    """E1(b): bool [A], the actions flagged failed at `state` during `trial`."""
    if isinstance(memory, PackedMemory):
        f = _unpack_packed(memory, memory.words[state])
        bits = f.failed | jnp.where(_ended(f.stamp, trial, outcomes, success=False), f.failed_pending, 0)
        return (bits >> jnp.arange(n_actions)) & 1 == 1
    if isinstance(memory, DenseMemory):
        bits = _failure_bits(memory, state, trial, outcomes)
        return (bits >> jnp.arange(n_actions)) & 1 == 1
    capacity = memory.failure_states.shape[0]
    match = _slot_valid(memory.failure_count, capacity) & (memory.failure_states == state)
    actions = jnp.arange(n_actions)
    return (match[:, None] & (memory.failure_actions[:, None] == actions[None, :])).any(0)


# --- dense layout: packed words and per-step pending writes ---------------------------------


def _unpack_success(word):
    """(stamp, pending action, committed action) of a success word; −1 = none."""
    return (word >> 16) - 1, ((word >> 8) & 0xFF) - 1, (word & 0xFF) - 1


def _pack_success(stamp, pending, committed):
    return ((stamp + 1) << 16) | ((pending + 1) << 8) | (committed + 1)


def _unpack_pending(word, n_actions: int):
    """(stamp, pending failure bits) of a failure_pending word."""
    return (word >> n_actions) - 1, word & ((1 << n_actions) - 1)


def _failure_bits(memory: DenseMemory, state, trial, outcomes):
    """int32 bit set of the actions flagged failed at `state` during `trial`."""
    stamp, pending = _unpack_pending(memory.failure_pending[state], memory.n_actions)
    live = _ended(stamp, trial, outcomes, success=False)
    return memory.failed[state] | jnp.where(live, pending, 0)


def record_visit(memory: DenseMemory, state, action, trial, outcomes, active) -> DenseMemory:
    """E4, lazily: make `action` the pending success action of `state` for `trial`."""
    word = memory.success[state]
    stamp, pending, committed = _unpack_success(word)
    committed = jnp.where(_ended(stamp, trial, outcomes, success=True), pending, committed)
    row = jnp.where(active, state, memory.success.shape[0])  # inactive: dropped write
    return memory.replace(success=memory.success.at[row].set(
        _pack_success(trial, action, committed), mode="drop", unique_indices=True))


def record_failure_candidate(memory: DenseMemory, state, action, trial, outcomes, flag) -> DenseMemory:
    """E6, lazily: (state, action) met the failure condition in `trial` (effective if it fails)."""
    n_actions = memory.n_actions
    word = memory.failure_pending[state]
    stamp, pending = _unpack_pending(word, n_actions)
    commit = flag & _ended(stamp, trial, outcomes, success=False)
    failed = memory.failed[state] | jnp.where(commit, pending, 0)
    pending = jnp.where(stamp == trial, pending, 0) | (1 << action)
    row = jnp.where(flag, state, memory.failed.shape[0])  # no candidate: dropped writes
    return memory.replace(
        failed=memory.failed.at[row].set(failed, mode="drop", unique_indices=True),
        failure_pending=memory.failure_pending.at[row].set(
            ((trial + 1) << n_actions) | pending, mode="drop", unique_indices=True),
    )


class _Packed(NamedTuple):
    stamp: jax.Array  # trial of the last visit, −1 = never
    pending: jax.Array  # success action taken at the last visit in that trial, −1 = none
    committed: jax.Array  # success action in effect before that trial, −1 = none
    failed: jax.Array  # bits of the actions flagged failed before that trial
    failed_pending: jax.Array  # bits of the actions that met E6 in that trial


def _unpack_packed(memory: PackedMemory, word) -> _Packed:
    b, n = memory.action_bits, memory.n_actions
    amask, fmask = (1 << b) - 1, (1 << n) - 1
    return _Packed(
        stamp=(word >> (2 * b + 2 * n)) - 1,
        pending=((word >> b) & amask) - 1,
        committed=(word & amask) - 1,
        failed=(word >> (2 * b)) & fmask,
        failed_pending=(word >> (2 * b + n)) & fmask,
    )


def _pack_packed(memory: PackedMemory, f: _Packed):
    b, n = memory.action_bits, memory.n_actions
    return (((f.stamp + 1) << (2 * b + 2 * n)) | (f.failed_pending << (2 * b + n))
            | (f.failed << (2 * b)) | ((f.pending + 1) << b) | (f.committed + 1))


def record_packed(
    memory: PackedMemory, state, action, trial, outcomes, active, remember, flag
) -> PackedMemory:
    """E4 and E6 lazily for one step of `trial` (if `active`): `action` becomes the state's
    pending success action (if `remember`) and, if `flag` (E6 met), a pending failed action.

    A first visit in a new trial settles the previous stamp's entries, whose trial is over:
    a success commits its action, a failure its flagged actions.
    """
    f = _unpack_packed(memory, memory.words[state])
    same = f.stamp == trial
    succeeded = _ended(f.stamp, trial, outcomes, success=True)
    failed_before = _ended(f.stamp, trial, outcomes, success=False)
    new = _Packed(
        stamp=jnp.asarray(trial, jnp.int32),
        pending=jnp.where(remember, action, -1),
        committed=jnp.where(succeeded, f.pending, f.committed),
        failed=f.failed | jnp.where(failed_before, f.failed_pending, 0),
        failed_pending=jnp.where(same, f.failed_pending, 0) | jnp.where(flag, 1 << action, 0),
    )
    row = jnp.where(active, state, memory.words.shape[0])  # inactive: dropped write
    return memory.replace(words=memory.words.at[row].set(
        _pack_packed(memory, new), mode="drop", unique_indices=True))


def with_committed(memory: DenseMemory | PackedMemory, success, failed) -> DenseMemory | PackedMemory:
    """The memory holding exactly these committed entries and nothing pending (tests, notebooks).

    success: int [S], the remembered action per state (−1 = none); failed: bool [S, A].
    """
    success = jnp.asarray(success, jnp.int32)
    bits = (jnp.asarray(failed, jnp.int32) << jnp.arange(memory.n_actions)).sum(axis=1)
    if isinstance(memory, PackedMemory):
        none = jnp.full_like(success, -1)
        f = _Packed(stamp=none, pending=none, committed=success, failed=bits,
                    failed_pending=jnp.zeros_like(bits))
        return memory.replace(words=_pack_packed(memory, f))
    return memory.replace(success=success + 1, failed=bits, failure_pending=jnp.zeros_like(bits))


def dense_tables(memory: DenseMemory | PackedMemory, trial, outcomes) -> tuple[jax.Array, jax.Array]:
    """(success int32 [S], failed bool [S, A]): the memory in effect during `trial`."""
    memory, outcomes = jax.tree.map(jnp.asarray, (memory, outcomes))
    states = jnp.arange((memory.words if isinstance(memory, PackedMemory) else memory.success).shape[0])
    success = jax.vmap(lambda s: success_action(memory, s, trial, outcomes))(states)
    failed = jax.vmap(lambda s: failure_flags(memory, s, trial, outcomes, memory.n_actions))(states)
    return success, failed


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
