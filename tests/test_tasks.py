"""The classic tabular tasks (jaxeac.envs.tasks): Gymnasium's own tables, hand-computed paths and
transitions, the stochastic variants, slip, the paper's grid as a task, and check_task's messages."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from collections import Counter, deque

import numpy as np
import pytest

from jaxeac.envs import tasks
from jaxeac.envs.grid import get_map, transition_tables
from jaxeac.errors import UsageError


def cell(task, row, col):
    return row * task.shape[1] + col


def outcomes(task, s, a):
    """{(next, reward, bumped): probability} of (s, a), duplicates summed, zero-probability ones left out."""
    out = Counter()
    for k in range(task.n_outcomes):
        if task.probs[s, a, k] > 0:
            key = (int(task.next_states[s, a, k]), float(task.rewards[s, a, k]), bool(task.bumped[s, a, k]))
            out[key] += float(task.probs[s, a, k])
    return dict(out)


def shortest_path(task):
    """BFS over a deterministic task from its (first) start to its goal: the list of (state, action)."""
    assert task.deterministic
    start = int(task.start_states[0])
    came = {start: None}
    queue = deque([start])
    while queue:
        s = queue.popleft()
        if s == task.goal:
            break
        if task.terminal[s]:
            continue
        for a in range(task.n_actions):
            t = int(task.next_states[s, a, 0])
            if t not in came:
                came[t] = (s, a)
                queue.append(t)
    path, s = [], task.goal
    while came[s] is not None:
        path.append(came[s])
        s = came[s][0]
    return path[::-1]


def path_return(task, path):
    return sum(float(task.rewards[s, a, 0]) for s, a in path)


ALL = {
    "FrozenLake-4x4-v1": lambda: tasks.frozen_lake("4x4", slippery=False),
    "FrozenLake-4x4-slippery-v1": lambda: tasks.frozen_lake("4x4", slippery=True),
    "FrozenLake-8x8-v1": lambda: tasks.frozen_lake("8x8", slippery=False),
    "FrozenLake-8x8-slippery-v1": lambda: tasks.frozen_lake("8x8", slippery=True),
    "CliffWalking-v1": tasks.cliff_walking,
    "WindyGridworld-v0": lambda: tasks.windy_gridworld(stochastic=False),
    "WindyGridworld-stochastic-v0": lambda: tasks.windy_gridworld(stochastic=True),
    "FourRooms-v0": lambda: tasks.four_rooms(stochastic=False),
    "FourRooms-stochastic-v0": lambda: tasks.four_rooms(stochastic=True),
}


@pytest.mark.parametrize("name", sorted(ALL))
def test_names_shapes_and_goal(name):
    task = ALL[name]()
    assert task.name == name
    assert task.n_states == task.shape[0] * task.shape[1] and task.n_actions == 4
    assert task.success[task.goal] and task.success.sum() == 1 and task.terminal[task.goal]
    assert len(task.action_deltas) == 4 and task.next_states.dtype == np.int32
    assert task.deterministic == ("-slippery" not in name and "-stochastic" not in name)


# ---------------------------------------------------------------- against Gymnasium, transition by transition
@pytest.fixture
def gym():
    return pytest.importorskip("gymnasium")


def gym_outcomes(transitions):
    """{(next, reward, terminated): probability} of one Gymnasium P[s][a] list, duplicates summed."""
    out = Counter()
    for prob, nxt, reward, terminated in transitions:
        out[(int(nxt), float(reward), bool(terminated))] += prob
    return dict(out)


def assert_same_tables(task, env):
    P = env.unwrapped.P
    assert len(P) == task.n_states
    for s in range(task.n_states):
        assert len(P[s]) == task.n_actions
        for a in range(task.n_actions):
            ours = Counter()
            for (nxt, reward, _), prob in outcomes(task, s, a).items():
                ours[(nxt, reward, bool(task.terminal[nxt]))] += prob
            theirs = gym_outcomes(P[s][a])
            assert ours.keys() == theirs.keys(), (s, a)
            for key, prob in theirs.items():
                assert ours[key] == pytest.approx(prob, abs=1e-12), (s, a, key)
    starts = np.flatnonzero(env.unwrapped.initial_state_distrib)
    np.testing.assert_array_equal(task.start_states, starts)


@pytest.mark.parametrize("map_name", ["4x4", "8x8"])
@pytest.mark.parametrize("slippery", [False, True])
def test_frozen_lake_is_gymnasiums(gym, map_name, slippery):
    task = tasks.frozen_lake(map_name, slippery)
    env_id = "FrozenLake-v1" if map_name == "4x4" else "FrozenLake8x8-v1"
    env = gym.make(env_id, is_slippery=slippery)
    assert_same_tables(task, env)
    assert task.max_steps == env.spec.max_episode_steps
    desc = env.unwrapped.desc.ravel()
    np.testing.assert_array_equal(task.terminal, np.isin(desc, [b"G", b"H"]))
    assert desc[task.goal] == b"G"
    # gymnasium's outcome order when slippery: (a - 1) % 4, a, (a + 1) % 4
    for s in np.flatnonzero(~task.terminal):
        for a in range(4):
            assert [int(t[1]) for t in env.unwrapped.P[s][a]] == task.next_states[s, a].tolist()


def test_cliff_walking_is_gymnasiums(gym):
    task = tasks.cliff_walking()
    env = gym.make("CliffWalking-v1")
    assert_same_tables(task, env)
    assert env.unwrapped.P[35][2] == [(1.0, 47, -1, True)]  # entering the goal: -1 (v1), terminated


# ---------------------------------------------------------------- hand-computed golden values
def test_frozen_lake_4x4_by_hand():
    task = tasks.frozen_lake("4x4", slippery=False)
    path = shortest_path(task)
    assert len(path) == 6 and path_return(task, path) == 1.0
    # from (1, 0) moving right: the hole at (1, 1); bumped, terminal, not a success
    (((nxt, reward, bumped), prob),) = outcomes(task, cell(task, 1, 0), 2).items()
    assert (nxt, reward, bumped, prob) == (cell(task, 1, 1), 0.0, True, 1.0)
    assert task.terminal[nxt] and not task.success[nxt]
    assert outcomes(task, 0, 0) == {(0, 0.0, False): 1.0}  # off the grid: stay
    assert outcomes(task, task.goal, 3) == {(task.goal, 0.0, False): 1.0}  # absorbing


def test_frozen_lake_8x8_shortest_path():
    task = tasks.frozen_lake("8x8", slippery=False)
    assert len(shortest_path(task)) == 14  # 7 right + 7 down, round the holes


def test_cliff_walking_by_hand():
    task = tasks.cliff_walking()
    start = cell(task, 3, 0)
    assert task.start_states.tolist() == [start] and task.goal == cell(task, 3, 11)
    path = shortest_path(task)
    assert len(path) == 13 and path_return(task, path) == -13.0
    assert [a for _, a in path] == [0] + [1] * 11 + [2]  # up, 11 × right, down
    assert outcomes(task, start, 1) == {(start, -100.0, True): 1.0}  # into the cliff: back to the start
    assert outcomes(task, cell(task, 2, 5), 2) == {(start, -100.0, True): 1.0}
    cliff = np.array([c == "C" for c in tasks.CLIFF_MAP if c != "\n"])
    assert not task.terminal[start] and task.bumped[~cliff].sum() == 12  # 10 from above, 1 each from S, G


def test_windy_gridworld_by_hand():
    task = tasks.windy_gridworld()
    up, down, left, right = range(4)
    assert task.action_names == ("up", "down", "left", "right")
    assert task.start_states.tolist() == [cell(task, 3, 0)] and task.goal == cell(task, 3, 7)
    path = shortest_path(task)
    assert len(path) == 15 and path_return(task, path) == -15.0  # the book's Fig. for Example 6.5
    # (3, 6), wind 2, right: (1, 7); the book's example: one right of the goal, left: just above it
    assert outcomes(task, cell(task, 3, 6), right) == {(cell(task, 1, 7), -1.0, False): 1.0}
    assert outcomes(task, cell(task, 3, 8), left) == {(cell(task, 2, 7), -1.0, False): 1.0}
    # the wind of the column the move starts in: (3, 2) has none, moving right into column 3 stays in row 3
    assert outcomes(task, cell(task, 3, 2), right) == {(cell(task, 3, 3), -1.0, False): 1.0}
    # clipped at the top: (0, 6) up stays in row 0; (1, 7) right with wind 2 ends at (0, 8)
    assert outcomes(task, cell(task, 0, 6), up) == {(cell(task, 0, 6), -1.0, False): 1.0}
    assert outcomes(task, cell(task, 1, 7), right) == {(cell(task, 0, 8), -1.0, False): 1.0}
    assert outcomes(task, cell(task, 6, 5), down) == {(cell(task, 6, 5), -1.0, False): 1.0}  # wind 1 - 1 down
    assert not task.bumped.any() and (task.rewards == -1.0).all()


def test_windy_gridworld_stochastic_by_hand():
    task = tasks.windy_gridworld(stochastic=True)
    left, right = 2, 3
    third = pytest.approx(1 / 3, abs=1e-15)
    assert (task.probs == 1 / 3).all() and task.n_outcomes == 3
    # Exercise 6.10's example: one right of the goal, left: above it, two above, or the goal, 1/3 each
    s = cell(task, 3, 8)
    assert task.next_states[s, left].tolist() == [cell(task, 2, 7), cell(task, 1, 7), cell(task, 3, 7)]
    assert outcomes(task, s, left) == {(cell(task, r, 7), -1.0, False): third for r in (2, 1, 3)}
    s = cell(task, 3, 6)  # wind 2: pushed up 2, 3 or 1
    assert task.next_states[s, right].tolist() == [cell(task, 1, 7), cell(task, 0, 7), cell(task, 2, 7)]
    assert outcomes(task, cell(task, 3, 0), right) == {(cell(task, 3, 1), -1.0, False): 1.0}  # no wind
    assert outcomes(task, cell(task, 0, 4), left) == {  # wind 1 at the top: 1, 2 clip to row 0; 0 stays
        (cell(task, 0, 3), -1.0, False): pytest.approx(1.0, abs=1e-15)}


def test_four_rooms_by_hand():
    task = tasks.four_rooms()
    up, down, left, right = range(4)
    walls = np.array([c == "#" for c in tasks.FOUR_ROOMS_MAP if c != "\n"])
    assert task.shape == (13, 13) and walls.sum() == 169 - 104  # 104 free cells, as in the paper
    assert task.goal == cell(task, 7, 9)
    assert sorted(task.start_states.tolist()) == sorted(set(np.flatnonzero(~walls)) - {task.goal})
    hall = cell(task, 3, 6)  # the hallway between the two upper rooms
    assert outcomes(task, hall, right) == {(cell(task, 3, 7), 0.0, False): 1.0}
    assert outcomes(task, hall, up) == {(hall, 0.0, True): 1.0}  # a wall: stay, bumped
    assert outcomes(task, cell(task, 6, 9), down) == {(task.goal, 1.0, False): 1.0}
    assert outcomes(task, cell(task, 1, 1), left) == {(cell(task, 1, 1), 0.0, True): 1.0}
    assert len(shortest_path(task)) == 14  # from the first start, the upper-left corner (1, 1)


def test_four_rooms_stochastic_by_hand():
    task = tasks.four_rooms(stochastic=True)
    up = 0
    np.testing.assert_array_equal(task.probs[0, 0], [2 / 3, 1 / 9, 1 / 9, 1 / 9])
    assert (task.probs == task.probs[0, 0]).all()
    hall = cell(task, 3, 6)  # up (2/3) and down (1/9) hit walls; left, right 1/9 each
    assert task.next_states[hall, up].tolist() == [hall, hall, cell(task, 3, 5), cell(task, 3, 7)]
    assert outcomes(task, hall, up) == {
        (hall, 0.0, True): pytest.approx(7 / 9, abs=1e-15),
        (cell(task, 3, 5), 0.0, False): pytest.approx(1 / 9, abs=1e-15),
        (cell(task, 3, 7), 0.0, False): pytest.approx(1 / 9, abs=1e-15),
    }


@pytest.mark.parametrize("name", sorted(ALL))
def test_rows_sum_to_one(name):
    task = ALL[name]()
    np.testing.assert_allclose(task.probs.sum(-1), 1.0, rtol=0, atol=1e-15)
    assert (task.probs > 0).all()


def test_slippery_frozen_lake_thirds():
    task = tasks.frozen_lake("8x8", slippery=True)
    assert (task.probs == 1 / 3).all()
    s = cell(task, 1, 1)
    # down (1): (a - 1) % 4 = left, down, (a + 1) % 4 = right
    assert task.next_states[s, 1].tolist() == [cell(task, 1, 0), cell(task, 2, 1), cell(task, 1, 2)]


def test_unknown_frozen_lake_map():
    with pytest.raises(UsageError, match=r"unknown FrozenLake map '5x5'; choose one of \['4x4', '8x8'\]"):
        tasks.frozen_lake("5x5", slippery=False)


# ---------------------------------------------------------------- slip
def test_slip_zero_is_identity_and_name():
    task = tasks.cliff_walking()
    assert tasks.with_slip(task, 0) is task and tasks.with_slip(task, 0.0) is task
    slipped = tasks.with_slip(task, 0.25)
    assert slipped.name == "CliffWalking-v1-slip0.25" and slipped.n_outcomes == 4
    assert (slipped.goal, slipped.shape, slipped.max_steps) == (task.goal, task.shape, task.max_steps)
    np.testing.assert_array_equal(slipped.start_states, task.start_states)


@pytest.mark.parametrize("name", ["FrozenLake-4x4-slippery-v1", "FourRooms-v0",
                                  "WindyGridworld-stochastic-v0"])
def test_slip_one_makes_actions_alike(name):
    task = tasks.with_slip(ALL[name](), 1.0)
    assert task.n_outcomes == 4 * ALL[name]().n_outcomes
    for s in range(task.n_states):
        first = outcomes(task, s, 0)
        for a in range(1, 4):
            other = outcomes(task, s, a)
            assert other.keys() == first.keys()
            for key, prob in first.items():
                assert other[key] == pytest.approx(prob, abs=1e-12)


def test_slip_on_the_paper_grid_by_hand():
    task = tasks.with_slip(tasks.grid_task(get_map("paper"), 40), 0.2)
    right, left, up, down = range(4)  # G2
    s = 5 * 11 + 2  # (x 2, y 5): the obstacle column x = 3 is to its right
    assert task.next_states[s, up].tolist() == [4 * 11 + 2, s, 5 * 11 + 1, 6 * 11 + 2]  # up, then 0, 1, 3
    np.testing.assert_allclose(task.probs[s, up], [0.85, 0.05, 0.05, 0.05], rtol=0, atol=1e-15)
    assert task.rewards[s, up].tolist() == [0.0, -1.0, 0.0, 0.0]
    assert task.bumped[s, up].tolist() == [False, True, False, False]
    assert task.next_states[s, right].tolist() == [s, 5 * 11 + 1, 4 * 11 + 2, 6 * 11 + 2]  # right first
    np.testing.assert_allclose(task.probs[s, right], [0.85, 0.05, 0.05, 0.05], rtol=0, atol=1e-15)
    assert task.name == "grid-11x11-slip0.2"


@pytest.mark.parametrize("p", [-0.1, 1.5, float("nan"), "a lot", None, True])
def test_slip_bad_probability(p):
    message = r"^slip probability must be a number in \[0, 1\] \(got .*\); pass e\.g\. 0\.1 "
    with pytest.raises(UsageError, match=message):
        tasks.with_slip(tasks.cliff_walking(), p)


# ---------------------------------------------------------------- the paper's grid as a task
def test_grid_task_is_the_paper_grid():
    grid = get_map("paper")
    task = tasks.grid_task(grid, 40, name="grid-paper-v0")
    next_state, reward, bumped = transition_tables(grid)
    np.testing.assert_array_equal(task.next_states[..., 0], next_state)
    np.testing.assert_array_equal(task.rewards[..., 0], reward)
    np.testing.assert_array_equal(task.bumped[..., 0], bumped)
    assert task.n_outcomes == 1 and (task.probs == 1.0).all()
    np.testing.assert_array_equal(task.start_states, grid.start_cells)
    assert np.flatnonzero(task.terminal).tolist() == [grid.goal_index]
    np.testing.assert_array_equal(task.success, task.terminal)
    assert (task.name, task.goal, task.shape, task.max_steps) == ("grid-paper-v0", 60, (11, 11), 40)
    assert task.action_names == ("right", "left", "up", "down")
    assert task.goal_distance[grid.goal_index] == 0.0
    assert tasks.grid_task(grid, np.int64(25)).max_steps == 25


def test_grid_task_bad_chances():
    with pytest.raises(UsageError, match="max_steps must be a positive integer"):
        tasks.grid_task(get_map("paper"), 0)


# ---------------------------------------------------------------- check_task
def broken(task, **changes):
    return lambda: dataclasses.replace(task, **changes)


def test_check_task_rejects_inconsistent_tables():
    task = tasks.frozen_lake("4x4", slippery=True)
    probs = task.probs.copy()
    probs[3, 2, 0] = 0.5
    cases = [
        (broken(task, probs=probs), "probabilities must be ≥ 0 and sum to 1"),
        (broken(task, probs=task.probs * np.array([2.0, -1.0, 2.0])), "must be ≥ 0"),
        (broken(task, success=task.terminal.copy() | (np.arange(16) == 0), start_states=np.array([1])),
         "every success state must be terminal"),
        (broken(task, start_states=np.array([0, 5])), "no start state may be terminal"),
        (broken(task, goal=5), "goal 5 must be a success state"),
        (broken(task, next_states=task.next_states + 1), r"next_states must lie in 0…15"),
        (broken(task, rewards=task.rewards[..., :2]), "rewards must have the shape of next_states"),
        (broken(task, max_steps=0), "max_steps must be a positive integer"),
        (broken(task, action_names=("left", "down")), "2 action names for 4 actions"),
    ]
    for build, message in cases:
        with pytest.raises(UsageError, match=f"^task FrozenLake-4x4-slippery-v1: .*{message}"):
            build()
    dataclasses.replace(task)  # the unbroken task passes


def test_tasks_module_does_not_import_jax():
    code = ("import sys, jaxeac.envs.tasks as t; t.four_rooms(True); t.with_slip(t.cliff_walking(), 0.1); "
            "sys.exit('jax' in sys.modules)")
    assert subprocess.run([sys.executable, "-c", code], check=False).returncode == 0
