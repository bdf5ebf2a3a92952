"""A slow, literal, plain-Python reading of Algorithm 1 (Debnath & Nassour 2014).

Written line by line from the paper and SPEC G1–G5, E1–E7, with dicts and lists
instead of masked arrays, and driven by the same random numbers as the
vectorised runner (`jaxeac.rng`). Worlds: the grid of G1–G4 (`GridReference`) or any
`TabularTask` read outcome by outcome (`TaskReference`, X1/X2). Also the value-based
baselines of X3 (Q-learning, SARSA) from Sutton & Barto's pseudo-code. Used only by the tests.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import jax
import numpy as np

from jaxeac.algorithm.config import AgentConfig
from jaxeac.envs.grid import ACTION_DELTAS, GridMap
from jaxeac.rng import action_uniform, bootstrap_uniform, seed_words, start_uniform, transition_uniform


@dataclass
class ReferenceTrial:
    states: list[int] = field(default_factory=list)
    actions: list[int] = field(default_factory=list)
    rtilde: list[float] = field(default_factory=list)
    success: bool = False
    branches: list[str] = field(default_factory=list)  # per step, E1's branch: "a", "b" or "c" (E8)
    learned: list[bool] = field(default_factory=list)  # per step, whether p and V were updated (E2, E8)


@dataclass
class ReferenceResult:
    trials: list[ReferenceTrial]
    preferences: np.ndarray
    values: np.ndarray
    success_memory: dict[int, int]
    failure_memory: set[tuple[int, int]]


class FifoSuccess:
    """E7 buffer policy for the success memory, literally: K slots, oldest insertion evicted."""

    def __init__(self, capacity: int):
        self.capacity, self.slots, self.count = capacity, [None] * capacity, 0

    def get(self, s):
        for slot in self.slots:
            if slot is not None and slot[0] == s:
                return slot[1]
        return None

    def put(self, s, a):
        for i, slot in enumerate(self.slots):
            if slot is not None and slot[0] == s:
                self.slots[i] = (s, a)
                return
        self.slots[self.count % self.capacity] = (s, a)
        self.count += 1

    def as_dict(self):
        return {slot[0]: slot[1] for slot in self.slots if slot is not None}


class FifoFailure:
    """E7 buffer policy for the failure memory: K (state, action) slots, oldest evicted."""

    def __init__(self, capacity: int):
        self.capacity, self.slots, self.count = capacity, [None] * capacity, 0

    def __contains__(self, pair):
        return pair in self.slots

    def add(self, pair):
        if pair not in self.slots:
            self.slots[self.count % self.capacity] = pair
            self.count += 1

    def as_set(self):
        return {slot for slot in self.slots if slot is not None}


class DictSuccess(dict):
    def put(self, s, a):
        self[s] = a

    def as_dict(self):
        return dict(self)


class SetFailure(set):
    def as_set(self):
        return set(self)


def move(grid: GridMap, s: int, a: int) -> tuple[int, float, bool]:
    """G4, literally: (next cell, reward, bumped)."""
    y, x = divmod(s, grid.width)
    dx, dy = ACTION_DELTAS[a]
    nx, ny = x + dx, y + dy
    if not (0 <= nx < grid.width and 0 <= ny < grid.height):
        return s, 0.0, False
    if grid.obstacles[ny, nx]:
        return s, -1.0, True
    s2 = ny * grid.width + nx
    return s2, (1.0 if s2 == grid.goal_index else 0.0), False


class GridReference:
    """The grid of G1–G4 with E5's r̃, literally."""

    def __init__(self, grid: GridMap):
        self.grid, self.n_states, self.n_actions = grid, grid.n_cells, 4

    def start(self, u: float) -> int:
        starts = self.grid.start_cells
        return int(starts[min(int(u * starts.size), starts.size - 1)])

    def move(self, s, a, u):
        """(s', r, bumped, terminal, success)."""
        s2, r, bumped = move(self.grid, s, a)
        return s2, r, bumped, s2 == self.grid.goal_index, s2 == self.grid.goal_index

    def rtilde(self, s2, r, bumped, goal_known) -> float:
        y2, x2 = divmod(s2, self.grid.width)
        gx, gy = self.grid.goal
        if bumped:
            return -1.0
        return 1.0 / (1.0 + math.hypot(x2 - gx, y2 - gy)) if goal_known else 0.0


class TaskReference:
    """A `TabularTask`, read outcome by outcome: the outcome of a draw u is the first k whose
    cumulative probability exceeds u (X1); r̃ by X2's rule."""

    def __init__(self, task, rtilde: str = "shaped"):
        self.task, self.n_states, self.n_actions = task, task.n_states, task.n_actions
        self.shaped = rtilde == "shaped" and task.goal is not None and task.shape is not None

    def start(self, u: float) -> int:
        starts = self.task.start_states
        return int(starts[min(int(u * starts.size), starts.size - 1)])

    def move(self, s, a, u):
        probs = self.task.probs[s, a]
        k = 0
        if not probs[0] == 1.0:
            total = 0.0
            for k in range(len(probs)):
                total += probs[k]
                if k == len(probs) - 1 or u < total:
                    break
        s2 = int(self.task.next_states[s, a, k])
        return (s2, float(self.task.rewards[s, a, k]), bool(self.task.bumped[s, a, k]),
                bool(self.task.terminal[s2]), bool(self.task.success[s2]))

    def rtilde(self, s2, r, bumped, goal_known) -> float:
        if not self.shaped:
            return r
        if bumped:
            return -1.0
        width = self.task.shape[1]
        (y2, x2), (gy, gx) = divmod(s2, width), divmod(self.task.goal, width)
        return 1.0 / (1.0 + math.hypot(x2 - gx, y2 - gy)) if goal_known else 0.0


def epsilon_greedy_choice(q_s, epsilon, u) -> int:
    """X3: u < ε explores (action ⌊(u/ε)·A⌋), else the ⌊((u−ε)/(1−ε))·m⌋-th of the m greedy actions."""
    n = len(q_s)
    if u < epsilon:
        return min(int(u / epsilon * n), n - 1)
    best = [a for a in range(n) if q_s[a] == max(q_s)]
    return best[min(int((u - epsilon) / (1 - epsilon) * len(best)), len(best) - 1)]


def softmax_choice(prefs_s, allowed, tau, u) -> int:
    """(1) restricted to `allowed`, sampled by inverse CDF with uniform u."""
    top = max(prefs_s[a] / tau for a in allowed)
    weights = [math.exp(prefs_s[a] / tau - top) if a in allowed else 0.0 for a in range(len(prefs_s))]
    total = sum(weights)
    cumulative = 0.0
    for a, w in enumerate(weights):
        cumulative += w
        if u * total < cumulative:
            return a
    return len(prefs_s) - 1


def reference_run(world, cfg: AgentConfig, *, trials, chances, alpha, beta, gamma, tau, key, epsilon=0.1):
    """Algorithm 1 (or an X3 baseline) for one seed with key `key` (a `fold_in(root, i)` key) in
    `world` (a `GridMap`, a `GridReference` or a `TaskReference`)."""
    if isinstance(world, GridMap):
        world = GridReference(world)
    words = seed_words(key)

    def uniform(fn, *args) -> float:
        return float(jax.device_get(fn(words, *args)))

    n_states, n_actions = world.n_states, world.n_actions
    prefs = np.zeros((n_states, n_actions))  # line 1: initialise policy to random (X3: Q = 0)
    values = np.zeros(n_states)
    buffer = cfg.memory == "buffer"
    success_mem = FifoSuccess(cfg.capacity) if buffer else DictSuccess()
    failure_mem = FifoFailure(cfg.capacity) if buffer else SetFailure()
    value_based = cfg.learner != "actor_critic"
    goal_known = False
    history: list[ReferenceTrial] = []
    for t in range(trials):
        s = world.start(uniform(start_uniform, t, chances))
        trial = ReferenceTrial()
        pending = None  # SARSA's next action
        for c in range(chances):
            u = uniform(action_uniform, t, c, chances)
            learn, branch = True, "c"
            remembered = success_mem.get(s) if cfg.success_memory else None
            flagged = [a for a in range(n_actions) if cfg.failure_memory and (s, a) in failure_mem]
            if value_based:  # X3
                a = pending if pending is not None else epsilon_greedy_choice(prefs[s], epsilon, u)
            elif remembered is not None:  # lines 4-6
                a = remembered
                learn, branch = False, "a"
            elif 0 < len(flagged) < n_actions:  # lines 7-9: avoid the failed actions
                allowed = [a for a in range(n_actions) if a not in flagged]
                a = softmax_choice(prefs[s], allowed, tau, u)
                learn, branch = False, "b"
            else:  # lines 11-14
                a = softmax_choice(prefs[s], list(range(n_actions)), tau, u)
            if cfg.learn_on_memory_steps:
                learn = True
            s2, r, bumped, terminal, success = world.move(s, a, uniform(transition_uniform, t, c, chances))
            if cfg.learner == "q_learning":  # Sutton & Barto (2018) §6.5
                target = r + (0.0 if terminal else gamma * max(prefs[s2]))
                prefs[s, a] += alpha * (target - prefs[s, a])
            elif cfg.learner == "sarsa":  # Sutton & Barto (2018) §6.4: choose a' from s', then update
                pending = epsilon_greedy_choice(prefs[s2], epsilon, uniform(bootstrap_uniform, t, c + 1, chances))
                target = r + (0.0 if terminal else gamma * prefs[s2, pending])
                prefs[s, a] += alpha * (target - prefs[s, a])
            elif learn:
                delta = r + gamma * (0.0 if terminal else values[s2]) - values[s]
                values[s] += alpha * delta
                prefs[s, a] += beta * delta
            if success:
                goal_known = True
            trial.states.append(s)
            trial.actions.append(a)
            trial.branches.append(branch)
            trial.learned.append(learn)
            trial.rtilde.append(world.rtilde(s2, r, bumped, goal_known))
            s = s2
            if terminal:  # lines 15-20
                trial.success = success
                break
        if trial.success and cfg.success_memory:
            for st, ac in zip(trial.states, trial.actions, strict=True):
                success_mem.put(st, ac)
        if not trial.success and cfg.failure_memory:  # lines 23-29
            if cfg.failure_rule == "previous_trial":
                if history:
                    prev = history[-1]
                    for c in range(min(len(trial.rtilde), len(prev.rtilde))):
                        if trial.rtilde[c] < prev.rtilde[c]:
                            failure_mem.add((trial.states[c], trial.actions[c]))
            else:
                for c in range(1, len(trial.rtilde)):
                    if trial.rtilde[c] < trial.rtilde[c - 1]:
                        failure_mem.add((trial.states[c], trial.actions[c]))
        history.append(trial)
    return ReferenceResult(history, prefs, values, success_mem.as_dict(), failure_mem.as_set())
