"""Any finite task of `jaxeac.envs.tasks` as a functional JAX environment (X1, X2).

`TabularEnv` runs a `TabularTask`'s tables: a move gathers the K outcomes of (s, a) and,
in a stochastic task, picks one with a single uniform (the transition stream of R1/X1);
entering a terminal state ends the episode, a success state as a success (E3), and C
chances truncate it (G5). The immediate reward r̃ that E6 compares (X2) is E5's form
on grid tasks with a goal — −1 for a bumped move, else R_max / (1 + ‖s' − g‖₂) once the
goal is known — and otherwise, or with ``rtilde="reward"``, the task's own reward (as
in bowling, where r̃ is the pins a throw knocked).
SPEC ids (G1…, E1…, B1…, R1…, X1…) are defined in docs/SPEC.md.
"""

from __future__ import annotations

import functools
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np

from jaxeac.envs.grid import GridMap, GridWorld, check_chances, check_slip, decode_move, shaped_reward
from jaxeac.envs.protocol import KernelTables, Transition, UniformEnv
from jaxeac.envs.tasks import TabularTask, grid_task, with_slip
from jaxeac.errors import UsageError
from jaxeac.pytree import pytree_dataclass
from jaxeac.rng import transition_uniform, uniform_index

RtildeRule = Literal["shaped", "reward"]
RTILDE_RULES = ("shaped", "reward")


@pytree_dataclass
class TabularState:
    """The current state and the chances taken so far in this episode."""

    position: jax.Array  # int32 []
    chance: jax.Array  # int32 []


class TabularEnv(UniformEnv):
    """A `TabularTask` in the environment API of `jaxeac.envs.protocol` (X1).

    `n_chances`: chances per trial (default: the task's `max_steps`). `rtilde` (X2):
    ``shaped`` (E5's form; needs a grid task with a goal, else the reward is used) or
    ``reward`` (the task's reward).
    """

    def __init__(self, task: TabularTask, n_chances: int | None = None, rtilde: RtildeRule = "shaped"):
        if not isinstance(task, TabularTask):
            raise TypeError(f"task must be a TabularTask of jaxeac.envs.tasks (got {task!r})")
        n_chances = check_chances(task.max_steps if n_chances is None else n_chances)
        if rtilde not in RTILDE_RULES:
            raise UsageError(f"unknown r̃ rule {rtilde!r}; choose one of {', '.join(RTILDE_RULES)}")
        self.task = task
        self.name = task.name
        self.n_states, self.n_actions = task.n_states, task.n_actions
        self.n_chances = int(n_chances)
        self.deterministic = task.deterministic
        self.goal_distance = task.goal_distance if rtilde == "shaped" else None
        self.rtilde_rule: RtildeRule = "shaped" if self.goal_distance is not None else "reward"
        rows = task.n_states * task.n_actions
        k = 1 if self.deterministic else task.n_outcomes  # deterministic: outcome 0 has probability 1

        def table(x):  # [S·A, k]
            return np.asarray(x).reshape(rows, -1)[:, :k]

        self._next = table(task.next_states).astype(np.int32)
        self._reward = table(task.rewards)
        self._bumped = table(task.bumped).astype(bool)
        # The outcome of a draw u: the number of cumulative probabilities (all but the last) ≤ u.
        self._cumulative = np.cumsum(np.asarray(task.probs).reshape(rows, -1), axis=1)[:, :k - 1]
        self._terminal = np.asarray(task.terminal, bool)
        self._success = np.asarray(task.success, bool)
        self._starts = np.asarray(task.start_states, np.int32)

    def __repr__(self) -> str:
        return f"TabularEnv({self.name!r}, chances={self.n_chances}, rtilde={self.rtilde_rule!r})"

    @property
    def n_starts(self) -> int:
        return int(self._starts.size)

    def reset_from(self, u: jax.Array) -> TabularState:
        """G3/X1: start in one of the task's start states, drawn uniformly with the uniform `u`."""
        return TabularState(jnp.asarray(self._starts)[uniform_index(u, self.n_starts)], jnp.int32(0))

    def observation(self, state: TabularState) -> jax.Array:
        return state.position

    def transition(self, state: TabularState, action: jax.Array, u=None) -> Transition:
        """One move: outcome k of (s, a) picked with `u` (stochastic tasks), then E3 and G5."""
        row = state.position * self.n_actions + action
        k = jnp.int32(0)
        if self._cumulative.shape[1]:
            k = jnp.sum(u >= jnp.asarray(self._cumulative, float)[row], dtype=jnp.int32)
        s_next = jnp.asarray(self._next)[row, k]
        chance = state.chance + 1
        terminated = jnp.asarray(self._terminal)[s_next]
        truncated = ~terminated & (chance >= self.n_chances)
        return Transition(TabularState(s_next, chance), jnp.asarray(self._reward, float)[row, k], terminated,
                          truncated, jnp.asarray(self._success)[s_next], jnp.asarray(self._bumped)[row, k])

    def rtilde(self, transition: Transition, goal_known: jax.Array) -> jax.Array:
        """X2: E5's shaped r̃ at the state reached, or the task's reward (`rtilde="reward"`)."""
        if self.goal_distance is None:
            return transition.reward
        distance = jnp.asarray(self.goal_distance)[transition.state.position]
        return shaped_reward(distance, transition.bumped, goal_known)

    def kernel_tables(self) -> TabularKernelTables:
        """The fused kernel's tables (`TabularKernelTables`), built once."""
        if getattr(self, "_kernel_tables", None) is None:
            self._kernel_tables = TabularKernelTables(self)
        return self._kernel_tables


class TabularKernelTables(KernelTables):
    """`TabularEnv` in the fused kernel (`jaxeac.envs.protocol.KernelTables`): per (s, a) and
    outcome the packed ``moves`` (2·s' + bumped) and ``reward``; per state the end flags ``ends``
    (terminal | success << 1) and ``distance`` (E5's ‖s − g‖₂; zeros where r̃ is the reward); the
    starts; and in a stochastic task the ``cumulative`` probabilities (all but the last) of the K
    outcomes of (s, a): outcome k is their number at most the transition uniform, as
    `TabularEnv.transition` draws it (X1)."""

    def __init__(self, env: TabularEnv):
        self.shaped = env.goal_distance is not None
        self.outcomes = env._next.shape[1]  # K: 1 for a deterministic task
        moves = 2 * env._next.astype(np.int64) + env._bumped  # [S·A, K]
        arrays = {
            "moves": moves.reshape(-1).astype(np.int32),
            "reward": np.asarray(env._reward, np.float32).reshape(-1),
            "ends": env._terminal.astype(np.int32) | (env._success.astype(np.int32) << 1),
            "distance": np.asarray(env.goal_distance if self.shaped else np.zeros(env.n_states), np.float32),
            "starts": np.asarray(env._starts, np.int32),
        }
        if self.outcomes > 1:  # [S·A, K − 1]
            arrays["cumulative"] = np.asarray(env._cumulative, np.float32).reshape(-1)
        super().__init__(arrays, env.n_actions, env.n_chances, env.n_starts)

    def move(self, ref, s, action, words, trial, chance):
        row = s * self.n_actions + action
        at = row
        if self.outcomes > 1:  # X1: outcome k of the seed's transition uniform
            u = transition_uniform(words, trial, chance, self.n_chances)
            below = [(u >= ref["cumulative"][row * (self.outcomes - 1) + j]).astype(jnp.int32)
                     for j in range(self.outcomes - 1)]
            at = row * self.outcomes + functools.reduce(lambda a, b: a + b, below)
        s_next, bumped = decode_move(ref["moves"][at])
        ends = ref["ends"][s_next]
        return s_next, ref["reward"][at], (ends & 1) == 1, (ends & 2) == 2, bumped

    def rtilde(self, ref, s_next, bumped, goal_known, reward):
        if not self.shaped:
            return reward
        return shaped_reward(ref["distance"][s_next], bumped, goal_known)


def grid_world(grid_map: GridMap, n_chances: int, slip: float = 0.0, name: str | None = None):
    """The paper's grid world on `grid_map` (G1–G5): the `GridWorld` itself, or, with `slip` > 0
    (X1), its table whose moves execute a uniformly random action with probability `slip`."""
    n_chances, slip = check_chances(n_chances), check_slip(slip)
    if not slip:
        return GridWorld(grid_map, n_chances)
    return TabularEnv(with_slip(grid_task(grid_map, n_chances, name=name), slip), n_chances)
