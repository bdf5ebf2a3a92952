"""What an environment offers: the gymnax 1.0 API outside, the run loops' contract inside (X1).

**Outside** every jaxeac environment has the functional API of gymnax 1.0 (and of navix,
xland-minigrid, jumanji …), so other libraries' agents run on it::

    obs, state = env.reset(key, params)
    obs, state, reward, terminated, truncated, info = env.step(key, state, action, params)

with termination (an absorbing state) kept apart from truncation (the chance limit C, G5),
``info["success"]`` (E3: the episode ended as a success on this step) and
``info["bumped"]`` (E5). A tabular agent also needs ``n_states``, ``n_actions`` and
``state_index(obs)``, the integer state of an observation. Unlike gymnax's ``step``,
jaxeac's does not reset by itself at the end of an episode.

**Inside** the run loops (`jaxeac.running.loops`) draw every random number from the
seed's counter-based stream (R1) rather than from keys, so that all loops and devices
draw the same numbers:

* ``start(words, trial)`` — the first state of trial `trial` (G3);
* ``move(state, action, words, trial, chance)`` — a `Transition` (G4, G5);
* ``observation(state)`` — the state index; ``rtilde(transition, goal_known)`` — E5's r̃;
* ``n_states``, ``n_actions``, ``n_chances``, ``deterministic``; inside a program whose inputs are
  the environment's tables, ``n_chances`` may be traced, and ``max_chances`` (optional, an int)
  bounds it: the length of the per-chance arrays (`chance_bound`);
* optionally ``kernel_tables()`` — the environment's `KernelTables` for the fused GPU kernel
  (`jaxeac.running.kernel`), or None where the kernel cannot run it (the default: an
  environment without the method runs as XLA ops).

`UniformEnv` derives both APIs from an environment whose every random choice is one
uniform in [0, 1) (the grid world and `jaxeac.envs.tabular.TabularEnv`);
`jaxeac.envs.adapters.GymnaxEnv` runs a gymnax environment under the loops.
SPEC ids (G1…, E1…, B1…, R1…, X1…) are defined in docs/SPEC.md.
"""

from __future__ import annotations

from typing import Any, Protocol

import jax
import jax.numpy as jnp

from jaxeac.pytree import pytree_dataclass
from jaxeac.rng import start_index, start_uniform, transition_uniform


@pytree_dataclass
class Transition:
    """What one move returns to the loops (G4, G5; X1)."""

    state: Any  # the environment's state after the move
    reward: jax.Array  # float []
    terminated: jax.Array  # bool []: entered an absorbing state (V(s') = 0 in (3))
    truncated: jax.Array  # bool []: used all C chances without terminating (G5)
    success: jax.Array  # bool []: terminated as a success (E3); ⊆ terminated
    bumped: jax.Array  # bool []: the move hit what the task penalises (E5: r̃ = −1)


class LoopEnv(Protocol):
    """What the run loops need from an environment (see the module docstring)."""

    n_states: int
    n_actions: int
    n_chances: int
    deterministic: bool

    def start(self, words: jax.Array, trial: jax.Array) -> Any: ...
    def move(self, state: Any, action: jax.Array, words: jax.Array, trial: jax.Array,
             chance: jax.Array) -> Transition: ...
    def observation(self, state: Any) -> jax.Array: ...
    def rtilde(self, transition: Transition, goal_known: jax.Array) -> jax.Array: ...


def chance_bound(env) -> int:
    """The static length of `env`'s per-chance arrays (r̃ slots, a trial's path): its
    ``max_chances`` where C is data of its program (`jaxeac.envs.tabular.TabularEnv`), else C."""
    return getattr(env, "max_chances", env.n_chances)


class KernelTables:
    """An environment's part of the fused kernel's chance (`jaxeac.running.kernel`): its tables and
    how a chance reads them, step for step as the environment's own `move`/`rtilde`/`start` compute
    (G3–G5, E3, E5, X1, X2), so the kernel never asks which environment it runs.

    `arrays` (name → NumPy table) are the kernel's inputs, in their order; a chance reads them
    through `ref` (name → the kernel's ref of that table). A move (s, a) is one word of the
    ``moves`` table, 2·s' + bumped (`jaxeac.envs.grid.decode_move`); the start of a trial is
    ``starts[start_index(...)]`` (G3, R1). Subclasses define `move` and `rtilde`.
    """

    def __init__(self, arrays: dict, n_actions: int, n_chances: int, n_starts: int):
        self.arrays = arrays
        self.n_actions, self.n_chances, self.n_starts = n_actions, n_chances, n_starts  # C: a bound if data

    def chances(self, ref, like):
        """C in the kernel (a vector like `like`, or an int): the environment's own where it is static;
        read from the tables where it is data (then `n_chances` is its bound, `chance_bound`)."""
        return self.n_chances

    def move(self, ref, s, action, words, trial, chance):
        """(s', reward, terminated, success, bumped) of action `action` at s in chance `chance` of
        trial `trial` (`env.move`; a stochastic environment's outcome from the seed's words, X1)."""
        raise NotImplementedError

    def rtilde(self, ref, s_next, bumped, goal_known, reward):
        """E5/X2's r̃ at s' (`env.rtilde`)."""
        raise NotImplementedError

    def start(self, ref, words, trial):
        """G3: the start state of trial `trial` (`env.start`)."""
        return ref["starts"][start_index(words, trial, self.chances(ref, trial), self.n_starts)]


class UniformEnv:
    """Base of environments whose every random choice is one uniform u ∈ [0, 1).

    A subclass defines ``reset_from(u)`` (the start state), ``transition(state, action, u)``
    (a `Transition`), ``observation(state)`` and ``rtilde``; this class gives the loops'
    ``start``/``move`` (uniforms of the seed's stream, R1/X1) and the gymnax-style
    ``reset``/``step`` (uniforms drawn from the key).
    """

    n_states: int
    n_actions: int
    n_chances: int
    deterministic: bool

    # --- the loops' contract -------------------------------------------------------------
    def start(self, words, trial):
        """G3: the first state of trial `trial`, from the seed's start uniform (R1)."""
        return self.reset_from(start_uniform(words, trial, self.n_chances))

    def move(self, state, action, words, trial, chance) -> Transition:
        """G4/G5 (X1): one move; a stochastic environment draws the outcome from the seed's
        transition stream, a deterministic one draws nothing."""
        u = None if self.deterministic else transition_uniform(words, trial, chance, self.n_chances)
        return self.transition(state, action, u)

    def kernel_tables(self) -> KernelTables | None:
        """The fused kernel's tables of this environment (`KernelTables`); None: it runs as XLA ops."""
        return None

    # --- the gymnax 1.0 API ----------------------------------------------------------------
    @property
    def num_actions(self) -> int:
        return self.n_actions

    @property
    def default_params(self) -> None:
        """No traced parameters: an environment's settings are fixed when it is built."""
        return None

    def state_index(self, obs) -> jax.Array:
        """The integer state of an observation (observations are the state indices)."""
        return jnp.asarray(obs, jnp.int32)

    def reset(self, key: jax.Array, params=None):
        """(obs, state): the start of an episode, drawn with `key`."""
        state = self.reset_from(jax.random.uniform(key))
        return self.observation(state), state

    def step(self, key: jax.Array, state, action, params=None):
        """(obs, state, reward, terminated, truncated, info), the outcome drawn with `key`;
        info holds ``success`` (E3) and ``bumped`` (E5). No automatic reset."""
        t = self.transition(state, jnp.asarray(action, jnp.int32),
                            None if self.deterministic else jax.random.uniform(key))
        info = {"success": t.success, "bumped": t.bumped}
        return self.observation(t.state), t.state, t.reward, t.terminated, t.truncated, info
