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

**buffer** (K slots, O(K) bytes per seed; `jaxeac.algorithm.buffer`): (state, action)
slots written at the end of a trial, first-in first-out when full. With K at least the
number of distinct entries a run writes, both layouts give bit-identical runs.

The agent sees one small interface whatever the layout (`Memory`): `success_action`
and `failure_flags` for E1, `record` after every chance (E4/E6 entries), `end_trial`
when a trial ends, and `policy_actions` for G7. The layout-specific functions below
implement it. All functions are pure and single-stream (one seed); callers vmap.
SPEC ids (G1…, E1…, B1…, R1…) are defined in docs/SPEC.md.
"""

from __future__ import annotations

from typing import Literal, NamedTuple, Protocol

import jax
import jax.numpy as jnp

from jaxeac.algorithm.buffer import BufferMemory, write_failure, write_success  # noqa: F401  (E7 buffer)
from jaxeac.algorithm.config import MEMORY_LAYOUTS
from jaxeac.errors import UsageError
from jaxeac.pytree import pytree_dataclass, static_field

Layout = Literal["dense", "buffer"]
LAYOUTS = MEMORY_LAYOUTS


class Memory(Protocol):
    """What the agent asks of a memory layout (E1, E4, E6, G7), whichever it is."""

    def success_action(self, state, trial, outcomes) -> jax.Array:
        """E1(a): the remembered successful action at `state` during `trial`, or −1."""

    def failure_flags(self, state, trial, outcomes) -> jax.Array:
        """E1(b): bool [A], the actions flagged failed at `state` during `trial`."""

    def record(self, state, action, chance, trial, outcomes, active, *, remember: bool,
               flag: jax.Array | None) -> Memory:
        """After chance `chance` of `trial` (if `active`): note (state, action) for E4 (if
        `remember`) and, where `flag` (E6 met; None: no failure memory), as a failure candidate."""

    def end_trial(self, length, success, ends, *, remember: bool, flag_failures: bool) -> Memory:
        """When a trial of `length` chances ends (`ends`), with outcome `success` (E4/E6)."""

    def policy_actions(self, n_states: int, trial, outcomes) -> jax.Array:
        """int32 [S]: the success action per state in effect during `trial` (−1 where none), G7."""


MAX_DENSE_ACTIONS = 24


def _success_per_state(memory, n_states: int, trial, outcomes) -> jax.Array:
    return jax.vmap(lambda s: memory.success_action(s, trial, outcomes))(jnp.arange(n_states))


@pytree_dataclass
class DenseMemory:
    """E7 dense layout with lazily committed pending entries (see module docstring)."""

    success: jax.Array  # int32 [S]: (stamp + 1) << 16 | (pending + 1) << 8 | (committed + 1)
    failed: jax.Array  # int32 [S]: bit a set ⇔ action a committed as failed
    failure_pending: jax.Array  # int32 [S]: (stamp + 1) << A | pending failure bits
    n_actions: int = static_field()

    def success_action(self, state, trial, outcomes) -> jax.Array:
        stamp, pending, committed = _unpack_success(self.success[state])
        return jnp.where(_ended(stamp, trial, outcomes, success=True), pending, committed)

    def failure_flags(self, state, trial, outcomes) -> jax.Array:
        return _bits_to_flags(_failure_bits(self, state, trial, outcomes), self.n_actions)

    def path_action(self, state) -> jax.Array:
        """The success action of a state on a success-memory path (see `PackedMemory.path_action`)."""
        return _unpack_success(self.success[state])[1]

    def record(self, state, action, chance, trial, outcomes, active, *, remember, flag) -> DenseMemory:
        memory = self
        if remember:
            memory = record_visit(memory, state, action, trial, outcomes, active)
        if flag is not None:
            memory = record_failure_candidate(memory, state, action, trial, outcomes, flag)
        return memory

    def end_trial(self, length, success, ends, *, remember, flag_failures) -> DenseMemory:
        return self  # pending entries take effect through the trial log's outcome

    policy_actions = _success_per_state


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

    def unpack(self, word) -> PackedFields:
        """The fields of one state's word."""
        b, n = self.action_bits, self.n_actions
        amask, fmask = (1 << b) - 1, (1 << n) - 1
        return PackedFields(
            stamp=(word >> (2 * b + 2 * n)) - 1,
            pending=((word >> b) & amask) - 1,
            committed=(word & amask) - 1,
            failed=(word >> (2 * b)) & fmask,
            failed_pending=(word >> (2 * b + n)) & fmask,
        )

    def pack(self, f: PackedFields):
        """One state's word from its fields."""
        b, n = self.action_bits, self.n_actions
        return (((f.stamp + 1) << (2 * b + 2 * n)) | (f.failed_pending << (2 * b + n))
                | (f.failed << (2 * b)) | ((f.pending + 1) << b) | (f.committed + 1))

    def _settled(self, state, trial, outcomes):
        f = self.unpack(self.words[state])
        return f, settled(f.stamp, trial, outcomes[jnp.maximum(f.stamp, 0)])

    def success_action(self, state, trial, outcomes) -> jax.Array:
        f, (succeeded, failed) = self._settled(state, trial, outcomes)
        return packed_in_effect(f, succeeded, failed)[0]

    def failure_flags(self, state, trial, outcomes) -> jax.Array:
        f, (succeeded, failed) = self._settled(state, trial, outcomes)
        return _bits_to_flags(packed_in_effect(f, succeeded, failed)[1], self.n_actions)

    def path_action(self, state) -> jax.Array:
        """The success action of a state with one, read without the trial log: its pending
        action. Such a state's last visit was in the successful trial that gave it the action
        (E4 keeps the last action of that trial) or a later step E1(a) took (the same action)."""
        return self.unpack(self.words[state]).pending

    def record(self, state, action, chance, trial, outcomes, active, *, remember, flag) -> PackedMemory:
        return record_packed(self, state, action, trial, outcomes, active, remember,
                             flag if flag is not None else False)

    def end_trial(self, length, success, ends, *, remember, flag_failures) -> PackedMemory:
        return self  # pending entries take effect through the trial log's outcome

    policy_actions = _success_per_state


AnyMemory = DenseMemory | PackedMemory | BufferMemory


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
                n_trials: int | None = None, n_chances: int = 1) -> AnyMemory:
    """Empty memories: no success action anywhere, no failure flag.

    The dense layout packs both memories into one word per state when the run's trial
    count `n_trials` is given and fits (`packed_fits`), else uses three words per state.
    The buffer layout keeps `capacity` slots per memory and a path of `n_chances` entries.
    """
    if layout == "dense" and n_trials is not None and packed_fits(n_actions, n_trials):
        return PackedMemory(words=jnp.zeros((n_states,), jnp.int32), n_actions=n_actions)
    if layout == "dense":
        zeros = jnp.zeros((n_states,), jnp.int32)  # every field stored + 1: 0 = none
        return DenseMemory(success=zeros, failed=zeros, failure_pending=zeros, n_actions=n_actions)
    if layout == "buffer":
        empty = jnp.full((capacity,), -1, jnp.int32)
        zero = jnp.int32(0)
        path = jnp.zeros((n_chances,), jnp.int32)
        return BufferMemory(empty, empty, zero, empty, empty, zero, path, path,
                            jnp.zeros((n_chances,), bool), n_actions=n_actions)
    raise ValueError(f"unknown memory layout {layout!r}; choose one of {LAYOUTS}")


def settled(stamp, trial, stamp_succeeded) -> tuple[jax.Array, jax.Array]:
    """(succeeded, failed): whether entries stamped with trial `stamp` are in effect during
    `trial` because that trial is over and succeeded (E4) or failed (E6); `stamp_succeeded`
    is that trial's outcome (ignored while the stamp is −1, never visited)."""
    over = (stamp >= 0) & (stamp < trial)
    return over & stamp_succeeded, over & ~stamp_succeeded


def _ended(stamp: jax.Array, trial: jax.Array, outcomes: jax.Array, success: bool) -> jax.Array:
    """Whether entries stamped with trial `stamp` are in effect during `trial`."""
    return settled(stamp, trial, outcomes[jnp.maximum(stamp, 0)])[0 if success else 1]


def _bits_to_flags(bits, n_actions: int) -> jax.Array:
    return (bits >> jnp.arange(n_actions)) & 1 == 1


# --- lookups (E1), whatever the layout ------------------------------------------------------


def success_action(memory: AnyMemory, state, trial, outcomes) -> jax.Array:
    """E1(a): the remembered successful action at `state` during `trial`, or −1."""
    return memory.success_action(state, trial, outcomes)


def failure_flags(memory: AnyMemory, state, trial, outcomes) -> jax.Array:
    """E1(b): bool [A], the actions flagged failed at `state` during `trial`."""
    return memory.failure_flags(state, trial, outcomes)


def policy_actions(memory: AnyMemory, n_states: int, trial, outcomes) -> jax.Array:
    """int32 [S]: the success-memory action per state (−1 where none), for G7."""
    return memory.policy_actions(n_states, trial, outcomes)


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


class PackedFields(NamedTuple):
    """The fields of one `PackedMemory` word."""

    stamp: jax.Array  # trial of the last visit, −1 = never
    pending: jax.Array  # success action taken at the last visit in that trial, −1 = none
    committed: jax.Array  # success action in effect before that trial, −1 = none
    failed: jax.Array  # bits of the actions flagged failed before that trial
    failed_pending: jax.Array  # bits of the actions that met E6 in that trial


def packed_in_effect(f: PackedFields, succeeded, failed) -> tuple[jax.Array, jax.Array]:
    """(success action or −1, failed-action bits) in effect, given whether the stamped trial
    is over and `succeeded` / `failed` (`settled`): E1 (a) and (b) for one state."""
    return jnp.where(succeeded, f.pending, f.committed), f.failed | jnp.where(failed, f.failed_pending, 0)


def packed_visit(f: PackedFields, trial, succeeded, failed, pending, failure_bit) -> PackedFields:
    """A visit in `trial`: E4 and E6 lazily. The state's stamped entries are settled (a success
    commits its action, a failure its flagged actions); `pending` (the action, or −1 without a
    success memory) becomes the pending success action and `failure_bit` (1 << action where
    E6 was met, else 0) joins this trial's pending failed bits."""
    committed, failed_bits = packed_in_effect(f, succeeded, failed)
    return PackedFields(
        stamp=trial,
        pending=pending,
        committed=committed,
        failed=failed_bits,
        failed_pending=jnp.where(f.stamp == trial, f.failed_pending, 0) | failure_bit,
    )


def record_packed(
    memory: PackedMemory, state, action, trial, outcomes, active, remember, flag
) -> PackedMemory:
    """E4 and E6 lazily for one step of `trial` (if `active`): `action` becomes the state's
    pending success action (if `remember`) and, if `flag` (E6 met), a pending failed action
    (`packed_visit`)."""
    f = memory.unpack(memory.words[state])
    succeeded, failed = settled(f.stamp, trial, outcomes[jnp.maximum(f.stamp, 0)])
    new = packed_visit(f, jnp.asarray(trial, jnp.int32), succeeded, failed, jnp.where(remember, action, -1),
                       jnp.where(flag, 1 << action, 0))
    row = jnp.where(active, state, memory.words.shape[0])  # inactive: dropped write
    return memory.replace(words=memory.words.at[row].set(memory.pack(new), mode="drop", unique_indices=True))


def with_committed(memory: DenseMemory | PackedMemory, success, failed) -> DenseMemory | PackedMemory:
    """The memory holding exactly these committed entries and nothing pending (tests, notebooks).

    success: int [S], the remembered action per state (−1 = none); failed: bool [S, A].
    """
    success = jnp.asarray(success, jnp.int32)
    bits = (jnp.asarray(failed, jnp.int32) << jnp.arange(memory.n_actions)).sum(axis=1)
    if isinstance(memory, PackedMemory):
        none = jnp.full_like(success, -1)
        f = PackedFields(stamp=none, pending=none, committed=success, failed=bits,
                         failed_pending=jnp.zeros_like(bits))
        return memory.replace(words=memory.pack(f))
    return memory.replace(success=success + 1, failed=bits, failure_pending=jnp.zeros_like(bits))


def dense_tables(memory: DenseMemory | PackedMemory, trial, outcomes) -> tuple[jax.Array, jax.Array]:
    """(success int32 [S], failed bool [S, A]): the memory in effect during `trial`."""
    memory, outcomes = jax.tree.map(jnp.asarray, (memory, outcomes))
    states = jnp.arange((memory.words if isinstance(memory, PackedMemory) else memory.success).shape[0])
    success = jax.vmap(lambda s: memory.success_action(s, trial, outcomes))(states)
    failed = jax.vmap(lambda s: memory.failure_flags(s, trial, outcomes))(states)
    return success, failed
