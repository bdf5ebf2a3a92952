"""Other libraries' environments under AC, EAC and the baselines (X1).

`GymnaxEnv` wraps any environment with gymnax's functional API (gymnax 1.0:
``reset_env(key, params) -> (obs, state)``, ``step_env(key, state, action, params) ->
(obs, state, reward, terminated, info)``) and a discrete observation, so the run loops
(`jaxeac.running.loops`) drive it like a jaxeac environment. gymnax itself is never
imported here: the adapter only calls those methods, so any library with the same shape
works, and gymnax stays an optional dependency.

Random numbers: the loops hand each reset and move a key made from the seed's
transition stream (`jaxeac.rng.chance_key`), so runs stay bit-identical across chunk
sizes and devices (R1, R2). The episode is cut after C chances by the loops (G5); the
wrapped environment's own time limit and automatic reset are not used. r̃ (E5/X2) is the
environment's reward; a success (E3) is a termination with positive reward unless
`success` says otherwise.
SPEC ids (G1…, E1…, B1…, R1…, X1…) are defined in docs/SPEC.md.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from jaxeac.envs.protocol import Transition
from jaxeac.errors import UsageError, check_int
from jaxeac.pytree import pytree_dataclass
from jaxeac.rng import chance_key


@pytree_dataclass
class WrappedState:
    """The wrapped environment's observation and state, and the chances taken this episode."""

    obs: Any
    inner: Any
    chance: jax.Array  # int32 []


def _discrete_size(env, params) -> int | None:
    """The number of observations of a discrete observation space (gymnax ``spaces.Discrete``)."""
    try:
        space = env.observation_space(params)
    except (AttributeError, NotImplementedError, TypeError):
        return None
    n = getattr(space, "n", None)
    shape = getattr(space, "shape", ())
    return int(n) if isinstance(n, int) and shape in ((), None) else None


class GymnaxEnv:
    """A gymnax-style environment with a discrete observation, as a jaxeac `LoopEnv`.

    `n_states` and `state_index` (observation → 0…S−1) default to a ``Discrete`` observation
    space's size and the observation itself; give both for any other finite observation
    (e.g. a position on a grid). `n_chances` defaults to ``params.max_steps_in_episode``.
    `success(obs, reward, terminated, info)` defaults to ``terminated & (reward > 0)``.
    """

    deterministic = False  # unknown: memory jumps stay off

    def __init__(self, env, params=None, *, n_states: int | None = None,
                 state_index: Callable[[Any], jax.Array] | None = None, n_chances: int | None = None,
                 success: Callable[..., jax.Array] | None = None):
        params = env.default_params if params is None else params
        discrete = _discrete_size(env, params)
        if n_states is None and discrete is None:
            raise UsageError(f"{getattr(env, 'name', type(env).__name__)} has no discrete observation space; "
                             "pass n_states and state_index (observation → 0…n_states−1) to run it under "
                             "tabular AC/EAC")
        if (n_states is None) != (state_index is None) and discrete is None:
            raise UsageError("give n_states and state_index together")
        self.env, self.params = env, params
        self.name = getattr(env, "name", type(env).__name__)
        self.n_states = int(n_states if n_states is not None else discrete)
        self.n_actions = int(env.num_actions)
        limit = getattr(params, "max_steps_in_episode", None)
        n_chances = limit if n_chances is None else n_chances
        self.n_chances = check_int("chances", n_chances, fix="pass n_chances, the chances per trial (G5)")
        self._index = state_index or (lambda obs: jnp.asarray(obs, jnp.int32).reshape(()))
        self._success = success or (lambda obs, reward, terminated, info: terminated & (reward > 0))

    def __repr__(self) -> str:
        return f"GymnaxEnv({self.name!r}, states={self.n_states}, chances={self.n_chances})"

    def start(self, words, trial) -> WrappedState:
        obs, inner = self.env.reset_env(chance_key(words, trial, self.n_chances, self.n_chances), self.params)
        return WrappedState(obs, inner, jnp.int32(0))

    def move(self, state: WrappedState, action, words, trial, chance) -> Transition:
        key = chance_key(words, trial, chance, self.n_chances)
        obs, inner, reward, terminated, info = self.env.step_env(key, state.inner, action, self.params)
        terminated = jnp.asarray(terminated, bool)
        reward = jnp.asarray(reward, float)
        steps = state.chance + 1
        return Transition(WrappedState(obs, inner, steps), reward, terminated,
                          ~terminated & (steps >= self.n_chances),
                          terminated & jnp.asarray(self._success(obs, reward, terminated, info), bool),
                          jnp.bool_(False))

    def observation(self, state: WrappedState) -> jax.Array:
        return jnp.asarray(self._index(state.obs), jnp.int32)

    def rtilde(self, transition: Transition, goal_known) -> jax.Array:
        """X2: the environment's reward."""
        return transition.reward

    def kernel_tables(self) -> None:
        """None: the fused kernel runs tabular tables only; a gymnax environment runs as XLA ops."""
        return None
