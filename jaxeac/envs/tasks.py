"""Finite tasks as tables: the classic tabular benchmarks and the paper's grid, in one format.

A `TabularTask` is a finite MDP written out as NumPy tables: for every (state, action) the
K possible next states with their probabilities, rewards and E5 "bump" flags, which states
end an episode and which of those count as a success (E3). `jaxeac.envs.tabular.TabularEnv`
runs any of them under AC, EAC, Q-learning and SARSA. Nothing here imports JAX. Builders: `frozen_lake`,
`cliff_walking`, `windy_gridworld`, `four_rooms`, `grid_task`; `with_slip` adds random-action noise.
SPEC ids (G1…, E1…, B1…, R1…, X1…) are defined in docs/SPEC.md.
"""

from __future__ import annotations

import dataclasses
import math
import numbers

import numpy as np

from jaxeac.errors import UsageError


@dataclasses.dataclass(frozen=True, eq=False)
class TabularTask:
    """A finite MDP as tables (X1). States are ``0 … S−1``; on grid tasks ``s = y·width + x``.

    Entering a `terminal` state ends the episode; entering a `success` state (a subset of the
    terminal ones) ends it as a success (E3). Moves out of terminal states are never taken.
    The episode is also cut after `max_steps` chances (the default C, G5).
    """

    name: str  # e.g. "FrozenLake-4x4-v1"
    next_states: np.ndarray  # int32 [S, A, K]: the K possible next states of (s, a)
    probs: np.ndarray  # float64 [S, A, K]: their probabilities; each (s, a) sums to 1
    rewards: np.ndarray  # float64 [S, A, K]: the task's reward for each outcome
    bumped: np.ndarray  # bool [S, A, K]: the move hit what the task penalises (E5/X2: r̃ = −1)
    terminal: np.ndarray  # bool [S]
    success: np.ndarray  # bool [S], success ⊆ terminal
    start_states: np.ndarray  # int32 [n ≥ 1]: each episode starts in one drawn uniformly (G3)
    max_steps: int  # default chances per trial (C)
    source: str  # the published definition this follows
    action_names: tuple[str, ...]  # in the task's own action order
    shape: tuple[int, int] | None = None  # (height, width) of a grid task, for plots and E5 distances
    action_deltas: tuple[tuple[int, int], ...] | None = None  # (dx, dy) of each action on a grid
    goal: int | None = None  # the goal cell E5's distance term uses (None: r̃ is the task's reward)

    def __post_init__(self):
        check_task(self)

    @property
    def n_states(self) -> int:
        return int(self.next_states.shape[0])

    @property
    def n_actions(self) -> int:
        return int(self.next_states.shape[1])

    @property
    def n_outcomes(self) -> int:
        return int(self.next_states.shape[2])

    @property
    def deterministic(self) -> bool:
        """Every (s, a) has one possible next state (probability 1)."""
        return bool(np.all(self.probs[..., 0] == 1.0))

    @property
    def goal_distance(self) -> np.ndarray | None:
        """float64 [S]: ‖s − g‖₂ on the grid (E5's shaped r̃), or None without a grid goal."""
        if self.goal is None or self.shape is None:
            return None
        ys, xs = np.divmod(np.arange(self.n_states), self.shape[1])
        gy, gx = divmod(self.goal, self.shape[1])
        return np.hypot(xs - gx, ys - gy)


def check_task(task: TabularTask) -> None:
    """Raise `UsageError` naming what is inconsistent in a task's tables."""
    ns = np.asarray(task.next_states)
    if ns.ndim != 3 or min(ns.shape) < 1:
        raise UsageError(f"task {task.name}: next_states must be [S, A, K] with S, A, K ≥ 1 (got {ns.shape})")
    n_states, n_actions, _ = ns.shape
    for field in ("probs", "rewards", "bumped"):
        if np.shape(getattr(task, field)) != ns.shape:
            raise UsageError(f"task {task.name}: {field} must have the shape of next_states {ns.shape}")
    for field in ("terminal", "success"):
        if np.shape(getattr(task, field)) != (n_states,):
            raise UsageError(f"task {task.name}: {field} must have shape ({n_states},)")
    if ns.min() < 0 or ns.max() >= n_states:
        raise UsageError(f"task {task.name}: next_states must lie in 0…{n_states - 1}")
    probs = np.asarray(task.probs)
    if (probs < 0).any() or not np.allclose(probs.sum(-1), 1.0, atol=1e-12):
        raise UsageError(f"task {task.name}: each (state, action)'s probabilities must be ≥ 0 and sum to 1")
    if (np.asarray(task.success) & ~np.asarray(task.terminal)).any():
        raise UsageError(f"task {task.name}: every success state must be terminal")
    starts = np.asarray(task.start_states)
    if starts.ndim != 1 or starts.size < 1 or starts.min() < 0 or starts.max() >= n_states:
        raise UsageError(f"task {task.name}: start_states must be a non-empty list of states")
    if np.asarray(task.terminal)[starts].any():
        raise UsageError(f"task {task.name}: no start state may be terminal")
    if len(task.action_names) != n_actions:
        raise UsageError(f"task {task.name}: {len(task.action_names)} action names for {n_actions} actions")
    if task.shape is not None and task.shape[0] * task.shape[1] != n_states:
        raise UsageError(f"task {task.name}: shape {task.shape} does not hold {n_states} states")
    if task.goal is not None and not (0 <= task.goal < n_states and task.success[task.goal]):
        raise UsageError(f"task {task.name}: goal {task.goal} must be a success state")
    if isinstance(task.max_steps, bool) or not isinstance(task.max_steps, int) or task.max_steps < 1:
        raise UsageError(f"task {task.name}: max_steps must be a positive integer")


# ---------------------------------------------------------------- moves on an ASCII map (shared)

def _cells(text: str) -> np.ndarray:
    """An ASCII map as a [H, W] array of its characters; cell (y, x) is state y·W + x."""
    return np.array([list(row) for row in text.split()])


def _moves(cells: np.ndarray, deltas, *, lift=None, wall: str = "#") -> tuple[np.ndarray, np.ndarray]:
    """One step from every cell with every action: next cell (int32 [S, A]) and hit (bool [S, A]).

    Action a adds ``deltas[a] = (dx, dy)`` and, if given, the upward push ``lift[x]`` of the column x
    the move starts in; each coordinate is then clipped to the grid, so a step off the grid stays put.
    A step into a `wall` cell stays put with hit = True.
    """
    height, width = cells.shape
    states = np.arange(height * width)
    ys, xs = np.divmod(states, width)
    dx, dy = np.asarray(deltas).T
    up = np.zeros(width, int) if lift is None else np.asarray(lift)
    nx = np.clip(xs[:, None] + dx, 0, width - 1)
    ny = np.clip(ys[:, None] + dy - up[xs][:, None], 0, height - 1)
    target = ny * width + nx
    hit = cells.ravel()[target] == wall
    return np.where(hit, states[:, None], target).astype(np.int32), hit


def _map_task(name: str, cells: np.ndarray, next_states, probs, rewards, bumped, **fields) -> TabularTask:
    """A `TabularTask` on a map: the G cell is the goal (terminal, the only success), the shape is the
    map's, and `probs` broadcasts over next_states; `fields` give the rest (`terminal` defaults to G)."""
    flat = cells.ravel()
    goal = int(np.flatnonzero(flat == "G")[0])
    next_states = np.asarray(next_states, np.int32)
    return TabularTask(
        name=name,
        next_states=next_states,
        probs=np.broadcast_to(np.asarray(probs, np.float64), next_states.shape).copy(),
        rewards=np.asarray(rewards, np.float64),
        bumped=np.asarray(bumped, bool),
        terminal=fields.pop("terminal", flat == "G"),
        success=flat == "G",
        start_states=np.asarray(fields.pop("start_states", np.flatnonzero(flat == "S")), np.int32),
        shape=cells.shape,
        goal=goal,
        **fields,
    )


# ---------------------------------------------------------------- the classic tasks

#: Gymnasium's FrozenLake-v1 maps (S start, F frozen, H hole, G goal).
FROZEN_LAKE_MAPS = {
    "4x4": """\
SFFF
FHFH
FFFH
HFFG
""",
    "8x8": """\
SFFFFFFF
FFFFFFFF
FFFHFFFF
FFFFFHFF
FFFHFFFF
FHHFFFHF
FHFFHFHF
FFFHFFFG
""",
}

def frozen_lake(map_name: str, slippery: bool) -> TabularTask:
    """Gymnasium's FrozenLake-v1 (Towers et al., 2024, arXiv:2407.17032; toy_text/frozen_lake.py).

    Its maps, its actions (0 left, 1 down, 2 right, 3 up), and with `slippery` its three outcomes
    (a − 1) mod 4, a, (a + 1) mod 4 with 1/3 each. A step off the grid stays put. Entering the goal
    gives 1, anything else 0; holes and the goal end the episode, the goal as the only success; from
    either every action stays put with reward 0, as in Gymnasium. `bumped` marks falling into a hole.
    One start (S); max_steps 100 (4x4) or 200 (8x8), Gymnasium's registered time limits.
    """
    if map_name not in FROZEN_LAKE_MAPS:
        raise UsageError(f"unknown FrozenLake map {map_name!r}; choose one of {sorted(FROZEN_LAKE_MAPS)}")
    cells = _cells(FROZEN_LAKE_MAPS[map_name])
    flat = cells.ravel()
    deltas = ((-1, 0), (0, 1), (1, 0), (0, -1))
    moves, _ = _moves(cells, deltas)
    mix = [[(a - 1) % 4, a, (a + 1) % 4] if slippery else [a] for a in range(4)]
    next_states = moves[:, mix]
    ends = np.isin(flat, ["G", "H"])
    next_states[ends] = np.flatnonzero(ends)[:, None, None]  # absorbing, as Gymnasium writes them
    moving = ~ends[:, None, None]
    return _map_task(
        f"FrozenLake-{map_name}{'-slippery' if slippery else ''}-v1", cells, next_states,
        1.0 / len(mix[0]), (flat[next_states] == "G") & moving, (flat[next_states] == "H") & moving,
        terminal=ends, max_steps={"4x4": 100, "8x8": 200}[map_name],
        source="Gymnasium FrozenLake-v1 (gymnasium/envs/toy_text/frozen_lake.py); M. Towers et al., "
               "Gymnasium: A Standard Interface for Reinforcement Learning Environments, arXiv:2407.17032",
        action_names=("left", "down", "right", "up"), action_deltas=deltas,
    )


#: Sutton & Barto's cliff world (C: the cliff).
CLIFF_MAP = """\
............
............
............
SCCCCCCCCCCG
"""


def cliff_walking() -> TabularTask:
    """Cliff walking: Sutton & Barto, Reinforcement Learning: An Introduction, 2nd ed. (MIT Press, 2018),
    Example 6.6, as Gymnasium's CliffWalking-v1 (not slippery; toy_text/cliffwalking.py).

    4×12, start at (row 3, col 0), goal at (3, 11), the cliff between them; actions 0 up, 1 right,
    2 down, 3 left. Every step gives −1, entering the goal too (Gymnasium's v1); stepping into the
    cliff gives −100 and returns to the start without ending the episode (`bumped`). A step off the
    grid stays put. The goal ends the episode as a success. Gymnasium registers no time limit; we cut
    at max_steps = 100, the limit Gymnasium registers for the 4x4 FrozenLake-v1: ample for the 13-step
    shortest path and the 17-step safe one.
    """
    cells = _cells(CLIFF_MAP)
    flat = cells.ravel()
    deltas = ((0, -1), (1, 0), (0, 1), (-1, 0))
    moves, _ = _moves(cells, deltas)
    falls = flat[moves] == "C"
    start = int(np.flatnonzero(flat == "S")[0])
    return _map_task(
        "CliffWalking-v1", cells, np.where(falls, start, moves)[..., None], 1.0,
        np.where(falls, -100.0, -1.0)[..., None], falls[..., None], max_steps=100,
        source="Sutton & Barto, Reinforcement Learning: An Introduction, 2nd ed. (2018), Example 6.6; "
               "as Gymnasium CliffWalking-v1 (gymnasium/envs/toy_text/cliffwalking.py)",
        action_names=("up", "right", "down", "left"), action_deltas=deltas,
    )


#: The compass moves as (dx, dy), y growing downwards, in the order FourRooms and WindyGridworld use.
COMPASS_NAMES = ("up", "down", "left", "right")
COMPASS_DELTAS = ((0, -1), (0, 1), (-1, 0), (1, 0))


#: Sutton & Barto's windy gridworld and the upward wind of each column.
WINDY_MAP = """\
..........
..........
..........
S......G..
..........
..........
..........
"""
WIND = (0, 0, 0, 1, 1, 1, 2, 2, 1, 0)


def windy_gridworld(stochastic: bool = False) -> TabularTask:
    """The windy gridworld: Sutton & Barto, Reinforcement Learning: An Introduction, 2nd ed. (MIT
    Press, 2018), Example 6.5; `stochastic`: Exercise 6.10's stochastic wind.

    7×10, start at (row 3, col 0), goal at (3, 7); actions 0 up, 1 down, 2 left, 3 right. A move
    is shifted upwards by the wind 0 0 0 1 1 1 2 2 1 0 of the column it starts in (the book's
    example: one cell right of the goal, left leads to the cell just above it), then each coordinate
    is clipped to the grid. −1 per step, entering the goal too; the goal ends the episode. With
    `stochastic`, where a column has wind, the push is its value, one more, or one less, with 1/3 each
    (in that order; a windless column repeats its one outcome three times). Nothing is `bumped`. The
    book sets no time limit; max_steps = 200, about 13× the 15-step shortest episode.
    """
    cells = _cells(WINDY_MAP)
    wind = np.asarray(WIND)
    gusts = (0, 1, -1) if stochastic else (0,)
    next_states = np.stack([_moves(cells, COMPASS_DELTAS, lift=wind + g * (wind > 0))[0] for g in gusts], -1)
    return _map_task(
        f"WindyGridworld{'-stochastic' if stochastic else ''}-v0", cells, next_states,
        1.0 / len(gusts), np.full(next_states.shape, -1.0), np.zeros(next_states.shape, bool),
        max_steps=200,
        source="Sutton & Barto, Reinforcement Learning: An Introduction, 2nd ed. (2018), Example 6.5"
               + (" with the stochastic wind of Exercise 6.10" if stochastic else ""),
        action_names=COMPASS_NAMES, action_deltas=COMPASS_DELTAS,
    )


#: Sutton, Precup & Singh's rooms: 11×11 inside a border of walls, four hallways; G in the east one.
FOUR_ROOMS_MAP = """\
#############
#.....#.....#
#.....#.....#
#...........#
#.....#.....#
#.....#.....#
##.####.....#
#.....###G###
#.....#.....#
#.....#.....#
#...........#
#.....#.....#
#############
"""


def four_rooms(stochastic: bool = False) -> TabularTask:
    """The rooms example of Sutton, Precup & Singh, 'Between MDPs and semi-MDPs: A framework for
    temporal abstraction in reinforcement learning', Artificial Intelligence 112 (1999) 181–211, Fig. 2.

    The 11×11 rooms inside a border of walls (`FOUR_ROOMS_MAP`, 13×13 cells; walls are states never
    entered); actions 0 up, 1 down, 2 left, 3 right. With `stochastic`, as in the paper, the chosen
    direction with 2/3 and each other one with 1/9 (chosen first, then the others in action order).
    A move into a wall stays put and is `bumped`. The goal: the figure's hallway goal, which we read
    as the east hallway (row 7, col 9), between the two right-hand rooms; it is also the "east
    doorway" goal of the option-critic's four rooms (Bacon, Harb & Precup, AAAI 2017). Entering it
    gives +1 and ends the episode, anything else 0. Starts: uniform over the free non-goal cells.
    The paper sets no time limit; max_steps = 500, about the mean time a uniformly random policy
    takes to reach the goal (502 steps; it does within 500 in 64 % of episodes).
    """
    cells = _cells(FOUR_ROOMS_MAP)
    flat = cells.ravel()
    moves, hit = _moves(cells, COMPASS_DELTAS)
    if stochastic:
        mix, probs = [[a] + [b for b in range(4) if b != a] for a in range(4)], (2 / 3, 1 / 9, 1 / 9, 1 / 9)
    else:
        mix, probs = [[a] for a in range(4)], 1.0
    next_states = moves[:, mix]
    return _map_task(
        f"FourRooms{'-stochastic' if stochastic else ''}-v0", cells, next_states, probs,
        flat[next_states] == "G", hit[:, mix], start_states=np.flatnonzero(flat == "."), max_steps=500,
        source="Sutton, Precup & Singh, Between MDPs and semi-MDPs, Artificial Intelligence 112 (1999) "
               "181-211, Fig. 2 (the rooms example)",
        action_names=COMPASS_NAMES, action_deltas=COMPASS_DELTAS,
    )


def grid_task(grid_map, n_chances: int, name: str | None = None) -> TabularTask:
    """The paper's grid world (Debnath & Nassour, 'Extending Cortical-Basal Inspired Reinforcement
    Learning Model with Success-Failure Experience', ICDL-EpiRob 2014, §V-A; SPEC G1–G5) on
    `grid_map` (a `jaxeac.envs.grid.GridMap`) as a task with one outcome per move: its tables, its
    actions, the goal cell as the terminal success, the free non-goal cells as starts, `n_chances`
    (C) as max_steps. `name` defaults to ``grid-<height>x<width>``.
    """
    from jaxeac.envs.grid import ACTION_DELTAS, ACTION_NAMES, transition_tables  # grid.py imports JAX

    next_state, reward, bumped = transition_tables(grid_map)
    goal = grid_map.goal_index
    is_goal = np.arange(grid_map.n_cells) == goal
    return TabularTask(
        name=name or f"grid-{grid_map.height}x{grid_map.width}",
        next_states=next_state[..., None],
        probs=np.ones(next_state.shape + (1,)),
        rewards=reward[..., None],
        bumped=bumped[..., None],
        terminal=is_goal,
        success=is_goal.copy(),
        start_states=grid_map.start_cells,
        max_steps=int(n_chances) if isinstance(n_chances, numbers.Integral) else n_chances,
        source="Debnath & Nassour, Extending Cortical-Basal Inspired Reinforcement Learning Model with "
               "Success-Failure Experience, ICDL-EpiRob 2014, Sec. V-A (SPEC G1-G5)",
        action_names=ACTION_NAMES,
        shape=(grid_map.height, grid_map.width),
        action_deltas=ACTION_DELTAS,
        goal=goal,
    )


def with_slip(task: TabularTask, p: float) -> TabularTask:
    """`task` where, with probability `p`, the executed action is drawn uniformly from all A actions
    instead of the chosen one: the chosen action's outcomes get weight 1 − p + p/A, every other
    action's p/A. Outcome lists are concatenated, not merged (K' = A·K): the chosen action's first,
    then those of actions 0 … A−1 without it. ``p = 0`` returns `task` itself; the name gets ``-slip<p>``.
    A p outside [0, 1] is a `UsageError`.
    """
    try:
        value = float(p)
    except (TypeError, ValueError):
        value = math.nan
    if isinstance(p, bool) or not 0.0 <= value <= 1.0:  # NaN fails the comparison too
        raise UsageError(f"slip probability must be a number in [0, 1] (got {p!r}); "
                         "pass e.g. 0.1 for a random action one time in ten")
    if value == 0.0:
        return task
    n_states, n_actions, n_outcomes = task.next_states.shape
    order = np.array([[a] + [b for b in range(n_actions) if b != a] for a in range(n_actions)])  # [A, A]
    weight = np.full(order.shape, value / n_actions)
    weight[:, 0] += 1.0 - value

    def spread(table):  # [S, A, K] -> [S, A, A·K] in `order`
        return np.asarray(table)[:, order, :].reshape(n_states, n_actions, n_actions * n_outcomes)

    return dataclasses.replace(
        task,
        name=f"{task.name}-slip{value:g}",
        next_states=spread(task.next_states),
        probs=spread(task.probs) * np.repeat(weight, n_outcomes, axis=1),
        rewards=spread(task.rewards),
        bumped=spread(task.bumped),
        source=f"{task.source}; with a uniformly random action with probability {value:g}",
    )
