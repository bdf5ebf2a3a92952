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

import copy
import dataclasses
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
from jaxeac.rng import start_uniform, transition_uniform, uniform_index

RtildeRule = Literal["shaped", "reward"]
RTILDE_RULES = ("shaped", "reward")


@pytree_dataclass
class TabularState:
    """The current state and the chances taken so far in this episode."""

    position: jax.Array  # int32 []
    chance: jax.Array  # int32 []


@dataclasses.dataclass(frozen=True)
class TableLayout:
    """The static shape of a tabular task's compiled program (X1): the sizes its tables are padded
    to. Tasks with the same layout, actions and r̃ rule share one program; their tables are its
    inputs (`TabularEnv.program_inputs`). A padded state is never entered (no move leads to it,
    no trial starts there); a padded outcome has probability 0; a padded start is never drawn.

    `outcomes` 1: every task is deterministic (a move draws nothing). `gated_jumps`: some tasks
    are deterministic and some not; memory jumps (exact only on deterministic tasks) are then
    compiled in and switched on per task by a flag among the tables (`TabularEnv.jump_gate`).
    `chances`: the largest C. `mixed_chances`: the tasks' C differ; each task's own C is then data
    too (``info``), so they share the program, each cut after its own C chances and drawing its
    own counters (G5, R1); the per-chance arrays (r̃ slots, a trial's path) are `chances` long.
    Otherwise C is part of the program, as for one task."""

    states: int
    outcomes: int
    starts: int
    chances: int
    gated_jumps: bool = False
    mixed_chances: bool = False

    @classmethod
    def covering(cls, envs) -> TableLayout:
        """The smallest layout that holds every `TabularEnv` of `envs` (their own tables' sizes)."""
        own = [env.own_layout for env in envs]
        deterministic = [x.outcomes == 1 for x in own]
        return cls(max(x.states for x in own), max(x.outcomes for x in own), max(x.starts for x in own),
                   max(x.chances for x in own), any(deterministic) and not all(deterministic),
                   len({x.chances for x in own}) > 1)

    def holds(self, other: TableLayout) -> bool:
        return (self.states >= other.states and self.outcomes >= other.outcomes
                and self.starts >= other.starts and self.chances >= other.chances)


class TabularEnv(UniformEnv):
    """A `TabularTask` in the environment API of `jaxeac.envs.protocol` (X1).

    `n_chances`: chances per trial (default: the task's `max_steps`). `rtilde` (X2):
    ``shaped`` (E5's form; needs a grid task with a goal, else the reward is used) or
    ``reward`` (the task's reward). `layout`: the sizes its tables are padded to (default: its
    own), so that tasks of one layout share a compiled program (`TableLayout`, `padded`).

    The tables (`program_inputs`, flat NumPy arrays) are read by `transition`, `rtilde` and the
    fused kernel alike: per (s, a) and outcome the packed ``moves`` (2·s' + bumped) and
    ``reward``; per state the end flags ``ends`` (terminal | success << 1) and ``distance``
    (E5's ‖s − g‖₂; zeros where r̃ is the reward); the ``starts``; in a stochastic layout the
    ``cumulative`` probabilities (all but the last) of the K outcomes of (s, a): outcome k is
    their number at most the transition uniform (X1); ``info`` = [number of starts, 1 if the
    task is deterministic, C]. A compiled program gets them as arguments (`bind`).
    """

    def __init__(self, task: TabularTask, n_chances: int | None = None, rtilde: RtildeRule = "shaped",
                 layout: TableLayout | None = None):
        if not isinstance(task, TabularTask):
            raise TypeError(f"task must be a TabularTask of jaxeac.envs.tasks (got {task!r})")
        n_chances = check_chances(task.max_steps if n_chances is None else n_chances)
        if rtilde not in RTILDE_RULES:
            raise UsageError(f"unknown r̃ rule {rtilde!r}; choose one of {', '.join(RTILDE_RULES)}")
        self.task = task
        self.name = task.name
        self.n_states, self.n_actions = task.n_states, task.n_actions
        self.n_chances = int(n_chances)
        self.task_deterministic = task.deterministic
        self.goal_distance = task.goal_distance if rtilde == "shaped" else None
        self.rtilde_rule: RtildeRule = "shaped" if self.goal_distance is not None else "reward"
        k = 1 if task.deterministic else task.n_outcomes  # deterministic: outcome 0 has probability 1
        self.own_layout = TableLayout(task.n_states, k, int(np.size(task.start_states)), self.n_chances)
        layout = self.own_layout if layout is None else layout
        if not isinstance(layout, TableLayout) or not layout.holds(self.own_layout):
            raise UsageError(f"task {task.name}: layout {layout!r} does not hold its tables "
                             f"({self.own_layout})")
        self.layout = layout
        self.deterministic = layout.outcomes == 1  # the program's moves draw nothing
        self.arrays = _tables(task, self.n_actions, k, layout, self.goal_distance, self.n_chances)
        self._t = self.arrays  # what the moves read: these, or a program's inputs (`bind`)

    def __repr__(self) -> str:
        return f"TabularEnv({self.name!r}, chances={self.n_chances}, rtilde={self.rtilde_rule!r})"

    @property
    def n_starts(self) -> int:
        return self.own_layout.starts

    @property
    def max_chances(self) -> int:
        """The length of its per-chance arrays (`jaxeac.envs.protocol.chance_bound`): the layout's C."""
        return self.layout.chances

    def padded(self, layout: TableLayout) -> TabularEnv:
        """This task with its tables padded to `layout` (same per-seed results)."""
        return TabularEnv(self.task, self.n_chances, self.rtilde_rule, layout)

    # --- tables as program inputs (`jaxeac.running.loops.program_key`) ----------------------
    def program_key(self) -> tuple:
        """What its compiled program depends on: everything but the tables' values (C among them)."""
        return TabularEnv, self.n_actions, self.rtilde_rule, self.layout

    def program_inputs(self) -> dict[str, np.ndarray]:
        return self.arrays

    def bind(self, tables: dict) -> TabularEnv:
        """The environment as its compiled program sees it: `tables` (traced) in place of its own,
        the layout's padded state count, and, where the layout's tasks differ in C, C read from the
        tables (a traced int32)."""
        view = copy.copy(self)
        view._t, view.n_states, view._kernel_tables = dict(tables), self.layout.states, None
        if self.layout.mixed_chances:
            view.n_chances = jnp.asarray(tables["info"])[2]
        return view

    def jump_gate(self):
        """bool []: whether memory jumps are exact for this task (`TableLayout.gated_jumps`);
        None where the layout decides it statically."""
        return self._t["info"][1] == 1 if self.layout.gated_jumps else None

    # --- the moves -------------------------------------------------------------------------
    def reset_from(self, u: jax.Array) -> TabularState:
        """G3/X1: start in one of the task's start states, drawn uniformly with the uniform `u`."""
        start = jnp.asarray(self._t["starts"])[uniform_index(u, self._t["info"][0])]
        return TabularState(start, jnp.int32(0))

    def observation(self, state: TabularState) -> jax.Array:
        return state.position

    def transition(self, state: TabularState, action: jax.Array, u=None) -> Transition:
        """One move: outcome k of (s, a) picked with `u` (stochastic tasks), then E3 and G5."""
        row = state.position * self.n_actions + action
        at = row * self.layout.outcomes
        if self.layout.outcomes > 1:
            cumulative = jnp.asarray(self._t["cumulative"], float).reshape(-1, self.layout.outcomes - 1)
            at = at + jnp.sum(u >= cumulative[row], dtype=jnp.int32)
        s_next, bumped = decode_move(jnp.asarray(self._t["moves"])[at])
        chance = state.chance + 1
        ends = jnp.asarray(self._t["ends"])[s_next]
        terminated = (ends & 1) == 1
        truncated = ~terminated & (chance >= self.n_chances)
        return Transition(TabularState(s_next, chance), jnp.asarray(self._t["reward"], float)[at], terminated,
                          truncated, (ends & 2) == 2, bumped)

    def rtilde(self, transition: Transition, goal_known: jax.Array) -> jax.Array:
        """X2: E5's shaped r̃ at the state reached, or the task's reward (`rtilde="reward"`)."""
        if self.rtilde_rule == "reward":
            return transition.reward
        distance = jnp.asarray(self._t["distance"], float)[transition.state.position]
        return shaped_reward(distance, transition.bumped, goal_known)

    def kernel_tables(self) -> TabularKernelTables:
        """The fused kernel's tables (`TabularKernelTables`), built once."""
        if getattr(self, "_kernel_tables", None) is None:
            self._kernel_tables = TabularKernelTables(self)
        return self._kernel_tables


def _tables(task: TabularTask, n_actions: int, k: int, layout: TableLayout, goal_distance,
            n_chances: int) -> dict:
    """`TabularEnv`'s tables of `task` (its first `k` outcomes) padded to `layout`: a padded state
    stays put and is never entered, a padded outcome repeats outcome 0 behind a cumulative
    probability of 2 (never drawn), padded starts repeat the first. Floats stay float64 here: a
    program reads them in JAX's default float (float32 unless x64 is on), as it always did."""
    rows, big = task.n_states * n_actions, layout.outcomes
    moves = np.empty((layout.states * n_actions, big), np.int64)
    moves[:] = 2 * np.repeat(np.arange(layout.states), n_actions)[:, None]
    reward = np.zeros(moves.shape)
    real = 2 * np.asarray(task.next_states, np.int64).reshape(rows, -1)[:, :k] + \
        np.asarray(task.bumped, bool).reshape(rows, -1)[:, :k]
    moves[:rows, :k], moves[:rows, k:] = real, real[:, :1]
    reward[:rows, :k] = np.asarray(task.rewards).reshape(rows, -1)[:, :k]
    reward[:rows, k:] = reward[:rows, :1]
    ends = np.zeros(layout.states, np.int32)
    ends[:task.n_states] = np.asarray(task.terminal, np.int32) | (np.asarray(task.success, np.int32) << 1)
    distance = np.zeros(layout.states)
    if goal_distance is not None:
        distance[:task.n_states] = goal_distance
    starts = np.asarray(task.start_states, np.int32)
    arrays = {
        "moves": moves.reshape(-1).astype(np.int32), "reward": reward.reshape(-1), "ends": ends,
        "distance": distance, "starts": np.pad(starts, (0, layout.starts - starts.size), mode="edge"),
        "info": np.array([starts.size, task.deterministic, n_chances], np.int32),
    }
    if big > 1:  # [S·A, K − 1]: the outcome of a draw u is the number of these ≤ u
        cumulative = np.full((layout.states * n_actions, big - 1), 2.0)
        cumulative[:rows, :k - 1] = np.cumsum(np.asarray(task.probs).reshape(rows, -1), axis=1)[:, :k - 1]
        arrays["cumulative"] = cumulative.reshape(-1)
    return arrays


class TabularKernelTables(KernelTables):
    """`TabularEnv` in the fused kernel (`jaxeac.envs.protocol.KernelTables`): the env's own tables
    (see `TabularEnv`), read step for step as `TabularEnv.transition` reads them (X1)."""

    def __init__(self, env: TabularEnv):
        self.shaped = env.rtilde_rule == "shaped"
        self.outcomes = env.layout.outcomes  # K: 1 for a deterministic layout
        self.gated = env.layout.gated_jumps
        self.mixed = env.layout.mixed_chances
        super().__init__(dict(env._t), env.n_actions, env.max_chances, env.layout.starts)

    def chances(self, ref, like):
        """C: read from the tables (``info[2]``) as a vector like `like` where it is data, else static."""
        return ref["info"][jnp.full_like(like, 2)] if self.mixed else self.n_chances

    def move(self, ref, s, action, words, trial, chance):
        row = s * self.n_actions + action
        at = row * self.outcomes
        if self.outcomes > 1:  # X1: outcome k of the seed's transition uniform
            u = transition_uniform(words, trial, chance, self.chances(ref, trial))
            below = [(u >= ref["cumulative"][row * (self.outcomes - 1) + j]).astype(jnp.int32)
                     for j in range(self.outcomes - 1)]
            at = at + functools.reduce(lambda a, b: a + b, below)
        s_next, bumped = decode_move(ref["moves"][at])
        ends = ref["ends"][s_next]
        return s_next, ref["reward"][at], (ends & 1) == 1, (ends & 2) == 2, bumped

    def rtilde(self, ref, s_next, bumped, goal_known, reward):
        if not self.shaped:
            return reward
        return shaped_reward(ref["distance"][s_next], bumped, goal_known)

    def start(self, ref, words, trial):
        """G3: the start of trial `trial`, among the task's own starts (``info[0]`` of them)."""
        count = ref["info"][jnp.zeros_like(trial)]
        return ref["starts"][uniform_index(start_uniform(words, trial, self.chances(ref, trial)), count)]

    def jump_gate(self, ref, like):
        """`TabularEnv.jump_gate` per lane (`like`: a lane vector), or None."""
        return ref["info"][jnp.ones_like(like)] == 1 if self.gated else None


def grid_world(grid_map: GridMap, n_chances: int, slip: float = 0.0, name: str | None = None):
    """The paper's grid world on `grid_map` (G1–G5): the `GridWorld` itself, or, with `slip` > 0
    (X1), its table whose moves execute a uniformly random action with probability `slip`."""
    n_chances, slip = check_chances(n_chances), check_slip(slip)
    if not slip:
        return GridWorld(grid_map, n_chances)
    return TabularEnv(with_slip(grid_task(grid_map, n_chances, name=name), slip), n_chances)
