"""The vectorised runner against the literal Algorithm 1 of tests/reference.py, step by step.

Both consume the same random numbers (`trial_randoms`); under float64 every
action, state, r̃, success and memory entry must match exactly, and the learned
values and preferences to rounding (SPEC E1–E7, G1–G5).
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest
from conftest import random_map_text
from reference import reference_run

from jaxeac.algorithm.config import algorithm
from jaxeac.algorithm.memory import BufferMemory, dense_tables
from jaxeac.envs.grid import GridWorld, get_map, parse_map
from jaxeac.rng import seed_key
from jaxeac.running.config import RunConfig
from jaxeac.running.loops import trace_run

VARIANTS = {
    "ac": algorithm("ac"),
    "eac": algorithm("eac"),
    "ac_rows": algorithm("ac", tables="rows"),
    "eac_rows": algorithm("eac", tables="rows"),
    "eac_buffer": algorithm("eac", memory="buffer", capacity=512),
    "eac_buffer_small": algorithm("eac", memory="buffer", capacity=3),  # FIFO eviction in use
    "eac_learn_on_memory": algorithm("eac", learn_on_memory_steps=True),
    "eac_within_trial": algorithm("eac", failure_rule="within_trial"),
    "eac_success_only": algorithm("eac_success_only"),
    "eac_failure_only": algorithm("eac_failure_only"),
}


def check_against_reference(grid, agent_cfg, *, trials, chances, seed, root=7, **rates):
    rates = {"alpha": 0.1, "beta": 0.3, "gamma": 0.9, "temperature": 1.0} | rates
    with jax.enable_x64(True):
        env = GridWorld(grid, chances)
        cfg = RunConfig(trials=trials, agent=agent_cfg, **rates)
        key = seed_key(jax.random.key(root), seed)
        agent, records = jax.jit(lambda k, h: trace_run(env, cfg, k, h))(key, cfg.hyper())
        agent, records = jax.device_get((agent, records))
        ref = reference_run(
            grid, agent_cfg, trials=trials, chances=chances, alpha=rates["alpha"], beta=rates["beta"],
            gamma=rates["gamma"], tau=rates["temperature"], key=key,
        )
    for t, rt in enumerate(ref.trials):
        n = len(rt.states)
        assert records.length[t] == n, f"trial {t}: length"
        assert bool(records.success[t]) == rt.success, f"trial {t}: success"
        np.testing.assert_array_equal(records.states[t, :n], rt.states, err_msg=f"trial {t}: states")
        np.testing.assert_array_equal(records.actions[t, :n], rt.actions, err_msg=f"trial {t}: actions")
        np.testing.assert_allclose(records.rtilde[t, :n], rt.rtilde, rtol=0, atol=1e-12)
    np.testing.assert_allclose(agent.values, ref.values, rtol=0, atol=1e-10)
    np.testing.assert_allclose(agent.preferences, ref.preferences, rtol=0, atol=1e-10)
    if agent_cfg.uses_memory:
        assert memory_contents(agent, grid.n_cells) == (ref.success_memory, ref.failure_memory)
    return ref


def memory_contents(agent, n_states):
    """(success dict, failure set) of either layout, for comparison with the reference."""
    memory = agent.memory
    if isinstance(memory, BufferMemory):
        k = memory.success_states.shape[0]
        ns, nf = min(int(memory.success_count), k), min(int(memory.failure_count), k)
        pairs = zip(memory.success_states[:ns], memory.success_actions[:ns], strict=True)
        success = {int(s): int(a) for s, a in pairs}
        pairs = zip(memory.failure_states[:nf], memory.failure_actions[:nf], strict=True)
        failure = {(int(s), int(a)) for s, a in pairs}
        return success, failure
    success, failed = jax.device_get(dense_tables(memory, agent.trial, agent.outcomes))
    return ({s: int(a) for s, a in enumerate(success) if a >= 0},
            {(int(s), int(a)) for s, a in zip(*np.nonzero(failed), strict=True)})


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_paper_map_matches_reference(variant):
    ref = check_against_reference(get_map("paper"), VARIANTS[variant], trials=25, chances=40, seed=3)
    assert len(ref.trials) == 25


@pytest.mark.parametrize("seed", range(12))
def test_random_small_maps_match_reference(seed):
    rng = np.random.default_rng(seed)
    grid = parse_map(random_map_text(rng))
    name = sorted(VARIANTS)[seed % len(VARIANTS)]
    chances = int(rng.integers(1, 9))
    rates = {"alpha": float(rng.uniform(0.01, 1)), "beta": float(rng.uniform(0.01, 1)),
             "gamma": float(rng.uniform(0, 1)), "temperature": float(rng.uniform(0.2, 3))}
    check_against_reference(grid, VARIANTS[name], trials=30, chances=chances, seed=seed, **rates)


def test_reference_exercises_every_branch():
    """The comparison above is only meaningful if the memories actually fire."""
    grid = get_map("paper")
    ref = check_against_reference(grid, VARIANTS["eac"], trials=25, chances=40, seed=3)
    assert any(t.success for t in ref.trials) and not all(t.success for t in ref.trials)
    assert ref.success_memory and ref.failure_memory


def test_small_buffer_evicts_fifo():
    """With K = 3 the buffer holds at most three entries per memory (E7 full-buffer policy)."""
    small = dataclasses.replace(VARIANTS["eac_buffer_small"])
    ref = check_against_reference(get_map("paper"), small, trials=25, chances=40, seed=3)
    assert len(ref.success_memory) <= 3 and len(ref.failure_memory) <= 3


@pytest.mark.parametrize("variant", ["eac", "eac_within_trial", "eac_success_only", "eac_failure_only"])
def test_three_word_dense_layout_matches_reference(variant, monkeypatch):
    """E7: with packing refused, the grid runs on the three-word dense layout (as bowling's
    21 actions always do), and it too matches the reference step by step."""
    import jaxeac.algorithm.memory as mem

    monkeypatch.setattr(mem, "packed_fits", lambda n_actions, n_trials: False)
    agent = jax.eval_shape(lambda: mem.init_memory("dense", 4, 4, 1, n_trials=10))
    assert isinstance(agent, mem.DenseMemory)
    check_against_reference(get_map("paper"), VARIANTS[variant], trials=25, chances=40, seed=5)


def test_grid_uses_one_packed_word_per_state():
    """E7: four actions and a few hundred trials fit one word; 21 actions (bowling) do not."""
    import jaxeac.algorithm.memory as mem

    assert isinstance(mem.init_memory("dense", 3, 4, 1, n_trials=200), mem.PackedMemory)
    assert mem.packed_fits(4, 100_000) and not mem.packed_fits(4, 200_000)
    assert mem.packed_fits(5, 32_766) and not mem.packed_fits(5, 32_767)
    assert not mem.packed_fits(6, 10) and not mem.packed_fits(21, 10)
    assert isinstance(mem.init_memory("dense", 3, 4, 1), mem.DenseMemory)  # trial count unknown
