"""A slow, literal, plain-Python reading of Algorithm 1 (Debnath & Nassour 2014).

Written line by line from the paper and SPEC G1–G5, E1–E7, with dicts and lists
instead of masked arrays, and driven by the same random numbers as the
vectorised runner (`jaxeac.running.batch.trial_randoms`). Used only by the tests.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from jaxeac.algorithm.config import AgentConfig
from jaxeac.envs.grid import ACTION_DELTAS, GridMap
from jaxeac.rng import trial_randoms


@dataclass
class ReferenceTrial:
    states: list[int] = field(default_factory=list)
    actions: list[int] = field(default_factory=list)
    rtilde: list[float] = field(default_factory=list)
    success: bool = False


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


def reference_run(grid: GridMap, cfg: AgentConfig, *, trials, chances, alpha, beta, gamma, tau, key):
    """Algorithm 1 for one seed with key `key` (a `fold_in(root, i)` key)."""
    n_states, n_actions = grid.n_cells, 4
    prefs = np.zeros((n_states, n_actions))  # line 1: initialise policy to random
    values = np.zeros(n_states)
    buffer = cfg.memory == "buffer"
    success_mem = FifoSuccess(cfg.capacity) if buffer else DictSuccess()
    failure_mem = FifoFailure(cfg.capacity) if buffer else SetFailure()
    gx, gy = grid.goal
    goal_known = False
    history: list[ReferenceTrial] = []
    starts = grid.start_cells
    for t in range(trials):
        randoms = trial_randoms(key, t, chances, starts.size)
        s = int(starts[int(randoms.start_index)])
        uniforms = np.asarray(randoms.action_uniforms)
        trial = ReferenceTrial()
        for c in range(chances):
            learn = True
            remembered = success_mem.get(s) if cfg.success_memory else None
            flagged = [a for a in range(n_actions) if cfg.failure_memory and (s, a) in failure_mem]
            if remembered is not None:  # lines 4-6
                a = remembered
                learn = False
            elif 0 < len(flagged) < n_actions:  # lines 7-9: avoid the failed actions
                allowed = [a for a in range(n_actions) if a not in flagged]
                a = softmax_choice(prefs[s], allowed, tau, uniforms[c])
                learn = False
            else:  # lines 11-14
                a = softmax_choice(prefs[s], list(range(n_actions)), tau, uniforms[c])
            if cfg.learn_on_memory_steps:
                learn = True
            s2, r, bumped = move(grid, s, a)
            terminal = s2 == grid.goal_index
            if learn:
                delta = r + gamma * (0.0 if terminal else values[s2]) - values[s]
                values[s] += alpha * delta
                prefs[s, a] += beta * delta
            if terminal:
                goal_known = True
            y2, x2 = divmod(s2, grid.width)
            if bumped:
                rt = -1.0
            elif goal_known:
                rt = 1.0 / (1.0 + math.hypot(x2 - gx, y2 - gy))
            else:
                rt = 0.0
            trial.states.append(s)
            trial.actions.append(a)
            trial.rtilde.append(rt)
            s = s2
            if terminal:  # lines 15-20
                trial.success = True
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
