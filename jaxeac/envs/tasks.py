"""Finite tasks as tables: the classic tabular benchmarks and the paper's grid, in one format.

A `TabularTask` is a finite MDP written out as NumPy tables: for every (state, action) the
K possible next states with their probabilities, rewards and E5 "bump" flags, which states
end an episode and which of those count as a success (E3). `jaxeac.envs.tabular.TabularEnv`
runs any of them under AC, EAC, Q-learning and SARSA. Nothing here imports JAX.
SPEC ids (G1…, E1…, B1…, R1…, X1…) are defined in docs/SPEC.md.
"""

from __future__ import annotations

import dataclasses

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
        height, width = self.shape
        ys, xs = np.divmod(np.arange(self.n_states), width)
        gy, gx = divmod(self.goal, width)
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
