"""Environments of other libraries under the run loops (X1): the gymnax-shaped adapter."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxeac.algorithm.config import algorithm
from jaxeac.envs.adapters import GymnaxEnv
from jaxeac.errors import UsageError
from jaxeac.running.batch import run_seeds
from jaxeac.running.config import RunConfig


@dataclasses.dataclass(frozen=True)
class Discrete:
    n: int
    shape: tuple = ()


@dataclasses.dataclass(frozen=True)
class Params:
    max_steps_in_episode: int = 12


class NoisyChain:
    """A gymnax-shaped chain of 6 states written for this test: start at 0, action 1 moves right
    with probability 0.8 (else stays), action 0 moves left; state 5 ends the episode with +1."""

    name = "NoisyChain"
    num_actions = 2
    default_params = Params()

    def observation_space(self, params):
        return Discrete(6)

    def reset_env(self, key, params):
        return jnp.int32(0), {"pos": jnp.int32(0)}

    def step_env(self, key, state, action, params):
        ok = jax.random.uniform(key) < 0.8
        pos = jnp.where(action == 1, jnp.where(ok, state["pos"] + 1, state["pos"]), jnp.maximum(state["pos"] - 1, 0))
        done = pos == 5
        return pos, {"pos": pos}, done.astype(jnp.float32), done, {}


@pytest.mark.parametrize("name", ["ac", "eac", "q_learning", "sarsa"])
def test_adapted_env_runs_and_keeps_r1_across_chunk_sizes(name):
    env = GymnaxEnv(NoisyChain())
    assert (env.n_states, env.n_actions, env.n_chances) == (6, 2, 12)
    cfg = RunConfig(trials=15, agent=algorithm(name), epsilon=0.2)
    a = run_seeds(env, cfg, root_key=3, n_seeds=10, chunk_size=3)
    b = run_seeds(env, cfg, root_key=3, n_seeds=10, chunk_size=7)
    np.testing.assert_array_equal(a.success, b.success)
    np.testing.assert_array_equal(a.steps, b.steps)
    assert 0 < a.success.mean() < 1
    # a success takes ≥ 5 chances; failures use all 12 (G5)
    assert (a.steps[a.success] >= 5).all() and (a.steps[~a.success] == 12).all()


def test_adapter_needs_a_discrete_observation():
    class Box(NoisyChain):
        def observation_space(self, params):
            return Discrete(0, shape=(2,))

    with pytest.raises(UsageError, match="NoisyChain has no discrete observation space; pass n_states"):
        GymnaxEnv(Box())
    env = GymnaxEnv(Box(), n_states=6, state_index=lambda obs: obs)
    assert env.n_states == 6
    with pytest.raises(UsageError, match="chances must be a positive integer"):
        GymnaxEnv(NoisyChain(), n_chances=0)


def test_gymnax_frozen_lake_matches_the_native_task():
    """gymnax's deterministic FrozenLake through the adapter gives the per-seed results of the native
    FrozenLake-4x4-v1 (same agent draws; r̃ = reward on both)."""
    import gymnax  # the dev extra installs it: this test runs wherever the tests do

    import jaxeac

    env, params = gymnax.make("FrozenLake-misc", is_slippery=False)
    adapted = GymnaxEnv(env, params)
    native = jaxeac.make("FrozenLake-4x4-v1", rtilde="reward")
    assert (adapted.n_states, adapted.n_actions, adapted.n_chances) == (16, 4, native.n_chances)
    for name in ("ac", "eac", "q_learning"):
        cfg = RunConfig(trials=40, agent=algorithm(name), epsilon=0.2)
        a = run_seeds(adapted, cfg, root_key=1, n_seeds=16)
        b = run_seeds(native, cfg, root_key=1, n_seeds=16)
        np.testing.assert_array_equal(a.success, b.success, err_msg=name)
        np.testing.assert_array_equal(a.steps, b.steps, err_msg=name)
        assert a.success.any(), name
