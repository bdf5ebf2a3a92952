"""Memories as fixed-size masked arrays (SPEC E7): dense vs buffer, and the full-buffer policy."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxeac.algorithm import memory as mem
from jaxeac.algorithm.config import algorithm
from jaxeac.envs.grid import GridWorld, get_map
from jaxeac.running.batch import run_seeds
from jaxeac.running.config import RunConfig


def buffer(capacity=16):
    return mem.init_memory("buffer", 100, 4, capacity)


def test_buffer_success_write_last_wins_e4():
    m = mem.write_success(buffer(), jnp.array([3, 5, 3, 7]), jnp.array([0, 1, 2, 3]),
                          jnp.array([1, 1, 1, 0], bool))
    look = [int(mem.success_action(m, s, 0, jnp.zeros(1, bool))) for s in (3, 5, 7, 0)]
    assert look == [2, 1, -1, -1]
    m = mem.write_success(m, jnp.array([5, 9]), jnp.array([3, 0]), jnp.array([True, True]))
    assert [int(mem.success_action(m, s, 0, jnp.zeros(1, bool))) for s in (3, 5, 9)] == [2, 3, 0]


def test_buffer_failure_write_and_flags_e6():
    m = mem.write_failure(buffer(), jnp.array([2, 2, 4, 2]), jnp.array([1, 3, 0, 1]),
                          jnp.array([1, 1, 0, 1], bool))
    flags = mem.failure_flags(m, 2, 0, jnp.zeros(1, bool))
    np.testing.assert_array_equal(flags, [False, True, False, True])
    assert int(m.failure_count) == 2  # the repeated pair (2, 1) is stored once


def test_buffer_full_policy_is_fifo():
    none = jnp.zeros(1, bool)
    m = mem.write_success(buffer(2), jnp.array([10, 11]), jnp.array([0, 1]), jnp.ones(2, bool))
    m = mem.write_success(m, jnp.array([10]), jnp.array([3]), jnp.ones(1, bool))  # update in place
    assert int(m.success_count) == 2
    m = mem.write_success(m, jnp.array([12]), jnp.array([2]), jnp.ones(1, bool))  # evicts 10 (oldest)
    assert [int(mem.success_action(m, s, 0, none)) for s in (10, 11, 12)] == [-1, 1, 2]
    f = mem.write_failure(buffer(2), jnp.array([1, 2, 3]), jnp.array([0, 0, 0]), jnp.ones(3, bool))
    assert [bool(mem.failure_flags(f, s, 0, none)[0]) for s in (1, 2, 3)] == [False, True, True]


def test_dense_pending_entries_follow_trial_outcomes():
    m = mem.init_memory("dense", 10, 4, 0)
    outcomes = jnp.array([True, False, False])
    yes = jnp.bool_(True)
    # trial 0 (a success) visits state 3 with actions 1 then 2: pending, effective from trial 1
    m = mem.record_visit(m, 3, 1, 0, outcomes, yes)
    m = mem.record_visit(m, 3, 2, 0, outcomes, yes)
    assert int(mem.success_action(m, 3, 0, outcomes)) == -1  # not during its own trial
    assert int(mem.success_action(m, 3, 1, outcomes)) == 2
    # trial 1 (fails) visits state 3 with action 0: the committed 2 survives
    m = mem.record_visit(m, 3, 0, 1, outcomes, yes)
    assert int(mem.success_action(m, 3, 2, outcomes)) == 2
    assert int(m.success[3]) == (2 << 16) | (1 << 8) | 3  # stamp 1, pending 0, committed 2 (all + 1)
    # an inactive step writes nothing
    m2 = mem.record_visit(m, 4, 1, 1, outcomes, jnp.bool_(False))
    assert int(m2.success[4]) == 0
    # failure candidates count only for failed trials
    f = mem.record_failure_candidate(m, 5, 2, 0, outcomes, yes)  # trial 0 succeeded
    f = mem.record_failure_candidate(f, 6, 1, 1, outcomes, yes)  # trial 1 failed
    f = mem.record_failure_candidate(f, 6, 3, 1, outcomes, yes)
    np.testing.assert_array_equal(mem.failure_flags(f, 5, 2, outcomes), [False] * 4)
    np.testing.assert_array_equal(mem.failure_flags(f, 6, 2, outcomes), [False, True, False, True])
    np.testing.assert_array_equal(mem.failure_flags(f, 6, 1, outcomes), [False] * 4)
    # a later candidate at state 6 commits trial 1's flags before replacing the pending ones
    f = mem.record_failure_candidate(f, 6, 0, 2, outcomes, yes)
    assert int(f.failed[6]) == 0b1010
    np.testing.assert_array_equal(mem.failure_flags(f, 6, 3, jnp.array([True, False, False, False])),
                                  [True, True, False, True])


def test_dense_limits():
    from jaxeac.errors import UsageError

    mem.check_dense_limits(21, 1000)
    with pytest.raises(UsageError, match="use the buffer layout"):
        mem.check_dense_limits(25, 10)
    with pytest.raises(UsageError, match="use the buffer layout"):
        mem.check_dense_limits(21, 1024)


def paper_results(layout, capacity=1024, seeds=16):
    env = GridWorld(get_map("paper"), 40)
    cfg = RunConfig(trials=60, agent=algorithm("eac", memory=layout, capacity=capacity))
    return run_seeds(env, cfg, root_key=3, n_seeds=seeds, chunk_size=seeds)


def test_dense_and_large_buffer_bit_identical_e7():
    dense, buffer = paper_results("dense"), paper_results("buffer", capacity=484)  # 121 cells × 4
    np.testing.assert_array_equal(dense.success, buffer.success)
    np.testing.assert_array_equal(dense.steps, buffer.steps)
    np.testing.assert_array_equal(dense.policy, buffer.policy)


def test_small_buffer_changes_runs():
    """A tiny buffer must actually forget (otherwise the policy above is untested)."""
    dense, tiny = paper_results("dense"), paper_results("buffer", capacity=2)
    assert not np.array_equal(dense.steps, tiny.steps)
    assert tiny.success.mean() < dense.success.mean()


def test_memory_jit_matches_eager():
    m = buffer(3)
    args = (jnp.array([1, 2, 3, 4]), jnp.array([0, 1, 2, 3]), jnp.ones(4, bool))
    eager = mem.write_success(m, *args)
    jitted = jax.jit(mem.write_success)(m, *args)
    for a, b in zip(jax.tree.leaves(eager), jax.tree.leaves(jitted), strict=True):
        np.testing.assert_array_equal(a, b)


def test_packed_word_golden():
    """One word per state (A = 4): the bits by hand, and settling on the next visit (E4, E6)."""
    m = mem.init_memory("dense", 10, 4, 0, n_trials=5)
    assert isinstance(m, mem.PackedMemory) and m.action_bits == 3
    outcomes = jnp.array([False, True, False, False, False])
    yes = jnp.bool_(True)
    m = mem.record_packed(m, 6, 1, 0, outcomes, yes, yes, yes)  # trial 0: a1 flagged at s6
    m = mem.record_packed(m, 6, 3, 0, outcomes, yes, yes, jnp.bool_(False))  # then a3, unflagged
    # stamp 0 (+1) << 14 | pending failed {1} << 10 | failed {} << 6 | pending a3 (+1) << 3 | none
    assert int(m.words[6]) == (1 << 14) | (0b0010 << 10) | (4 << 3)
    np.testing.assert_array_equal(mem.failure_flags(m, 6, 0, outcomes), [False] * 4)  # own trial
    np.testing.assert_array_equal(mem.failure_flags(m, 6, 1, outcomes), [False, True, False, False])
    assert int(mem.success_action(m, 6, 1, outcomes)) == -1  # trial 0 failed: a3 not remembered
    # trial 1 (a success) visits s6 with a2: trial 0's flag is settled into the failed bits
    m = mem.record_packed(m, 6, 2, 1, outcomes, yes, yes, jnp.bool_(False))
    assert int(m.words[6]) == (2 << 14) | (0b0010 << 6) | (3 << 3)
    assert int(mem.success_action(m, 6, 2, outcomes)) == 2
    np.testing.assert_array_equal(mem.failure_flags(m, 6, 2, outcomes), [False, True, False, False])
    # trial 2 visits with a0: trial 1's success commits a2; an inactive step writes nothing
    m = mem.record_packed(m, 6, 0, 2, outcomes, yes, yes, jnp.bool_(False))
    assert int(mem.success_action(m, 6, 3, outcomes)) == 2  # trial 2 failed: a2 stays
    same = mem.record_packed(m, 6, 1, 3, outcomes, jnp.bool_(False), yes, yes)
    np.testing.assert_array_equal(same.words, m.words)
