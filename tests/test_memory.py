"""Memories as fixed-size masked arrays (SPEC E7): dense vs buffer, and the full-buffer policy."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from envs.grid import GridWorld, get_map
from jaxeac import memory as mem
from jaxeac.agent import algorithm
from jaxeac.runner import RunConfig, run_seeds


def test_last_occurrence():
    states = jnp.array([3, 5, 3, 7, 5])
    valid = jnp.array([True, True, True, True, False])
    np.testing.assert_array_equal(mem.last_occurrence(states, valid), [False, True, True, True, False])


@pytest.mark.parametrize("layout", ["dense", "buffer"])
def test_success_write_last_wins_e4(layout):
    m = mem.init_memory(layout, 10, 4, 16)
    m = mem.write_success(m, jnp.array([3, 5, 3, 7]), jnp.array([0, 1, 2, 3]), jnp.array([1, 1, 1, 0], bool))
    assert [int(mem.success_action(m, s)) for s in (3, 5, 7, 0)] == [2, 1, -1, -1]
    m = mem.write_success(m, jnp.array([5, 9]), jnp.array([3, 0]), jnp.array([True, True]))
    assert [int(mem.success_action(m, s)) for s in (3, 5, 9)] == [2, 3, 0]  # later success overwrites


@pytest.mark.parametrize("layout", ["dense", "buffer"])
def test_failure_write_and_flags_e6(layout):
    m = mem.init_memory(layout, 10, 4, 16)
    m = mem.write_failure(m, jnp.array([2, 2, 4, 2]), jnp.array([1, 3, 0, 1]), jnp.array([1, 1, 0, 1], bool))
    np.testing.assert_array_equal(mem.failure_flags(m, 2, 4), [False, True, False, True])
    np.testing.assert_array_equal(mem.failure_flags(m, 4, 4), [False] * 4)
    if layout == "buffer":
        assert int(m.failure_count) == 2  # the repeated pair (2, 1) is stored once


def test_buffer_full_policy_is_fifo():
    m = mem.init_memory("buffer", 100, 4, 2)
    m = mem.write_success(m, jnp.array([10, 11]), jnp.array([0, 1]), jnp.ones(2, bool))
    m = mem.write_success(m, jnp.array([10]), jnp.array([3]), jnp.ones(1, bool))  # update in place
    assert int(m.success_count) == 2
    m = mem.write_success(m, jnp.array([12]), jnp.array([2]), jnp.ones(1, bool))  # evicts 10 (oldest)
    assert [int(mem.success_action(m, s)) for s in (10, 11, 12)] == [-1, 1, 2]
    f = mem.init_memory("buffer", 100, 4, 2)
    f = mem.write_failure(f, jnp.array([1, 2, 3]), jnp.array([0, 0, 0]), jnp.ones(3, bool))
    assert [bool(mem.failure_flags(f, s, 4)[0]) for s in (1, 2, 3)] == [False, True, True]


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
    m = mem.init_memory("buffer", 10, 4, 3)
    args = (jnp.array([1, 2, 3, 4]), jnp.array([0, 1, 2, 3]), jnp.ones(4, bool))
    eager = mem.write_success(m, *args)
    jitted = jax.jit(mem.write_success)(m, *args)
    for a, b in zip(jax.tree.leaves(eager), jax.tree.leaves(jitted), strict=True):
        np.testing.assert_array_equal(a, b)
