"""The grid world of SPEC G1-G5: map parsing, moves, rewards, termination vs truncation."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxeac.envs.grid import GridWorld, get_map, load_map, parse_map
from jaxeac.errors import UsageError


def xy(env, x, y):
    return y * env.map.width + x


def test_paper_map_g1():
    grid = get_map("paper")
    assert (grid.height, grid.width, grid.goal) == (11, 11, (5, 5))
    assert grid.obstacles.sum() == 9  # 5-cell wall in column 3 + 4-cell wall in row 8
    assert grid.obstacles[3:8, 3].all() and grid.obstacles[8, 5:9].all()
    assert grid.start_cells.size == 121 - 9 - 1  # G3: free, non-goal


@pytest.mark.parametrize(("text", "msg"), [
    ("...\n...\n", "exactly one goal"),
    ("G..\n..G\n", r"exactly one goal 'G' \(found 2\)"),
    ("G..\n..\n", "ragged rows"),
    ("G.x\n...\n", "unknown characters 'x'"),
    ("G#\n##\n", "no free start cell"),
    ("G\n", "no free start cell"),
    ("", "empty"),
])
def test_bad_maps_rejected_g1(text, msg):
    with pytest.raises(UsageError, match=msg):
        parse_map(text)


def test_map_file_errors(tmp_path):
    with pytest.raises(UsageError, match="does not exist"):
        load_map(tmp_path / "missing.txt")
    good = tmp_path / "m.txt"
    good.write_text("G.\n..\n")
    assert load_map(good).goal == (0, 0)


def test_moves_g2_g4():
    env = GridWorld(get_map("paper"), 40)
    state = env.reset_at(0)  # (0, 0), the first start cell
    assert int(state.position) == 0

    def move(x, y, a):
        s = env.reset_at(0).replace(position=jnp.int32(xy(env, x, y)))
        return env.transition(s, a)

    # G2: 0 right, 1 left, 2 up, 3 down
    assert int(move(1, 1, 0).state.position) == xy(env, 2, 1)
    assert int(move(1, 1, 1).state.position) == xy(env, 0, 1)
    assert int(move(1, 1, 2).state.position) == xy(env, 1, 0)
    assert int(move(1, 1, 3).state.position) == xy(env, 1, 2)
    # off the grid: stay, r = 0, not a bump
    st = move(0, 0, 1)
    assert (int(st.state.position), float(st.reward), bool(st.bumped)) == (0, 0.0, False)
    # into an obstacle: stay, r = −1, bumped
    st = move(2, 5, 0)
    assert (int(st.state.position), float(st.reward), bool(st.bumped)) == (xy(env, 2, 5), -1.0, True)
    # into the goal: move, r = +1, terminated (not truncated)
    st = move(4, 5, 0)
    assert int(st.state.position) == xy(env, 5, 5)
    assert (float(st.reward), bool(st.terminated), bool(st.truncated), bool(st.success)) == (1.0, True, False, True)


def test_gymnax_api_steps_like_the_loops_x1():
    env = GridWorld(get_map("paper"), 2)
    key = jax.random.key(0)
    obs, state = env.reset(key)
    assert int(obs) == int(state.position) and int(env.state_index(obs)) == int(obs)
    state = state.replace(position=jnp.int32(xy(env, 4, 5)))
    obs, state, reward, terminated, truncated, info = env.step(key, state, 0)  # into the goal
    assert (int(obs), float(reward), bool(terminated), bool(truncated)) == (xy(env, 5, 5), 1.0, True, False)
    assert bool(info["success"]) and not bool(info["bumped"])
    obs, state, *_ = env.step(key, state, 0)  # no automatic reset: the step is the table's
    assert int(obs) == xy(env, 6, 5)
    _, state, _, _, truncated, _ = env.step(key, env.reset_at(0), 1)  # chance 1 of C = 2
    assert not bool(truncated)
    *_, truncated, _ = env.step(key, state, 1)  # chance 2 of 2: truncated (G5)
    assert bool(truncated)


def test_truncation_after_c_chances_g5():
    env = GridWorld(get_map("paper"), 3)
    state = env.reset_at(0)
    flags = []
    for _ in range(3):
        step = env.transition(state, 1)  # bump the left edge forever
        state = step.state
        flags.append((bool(step.terminated), bool(step.truncated)))
    assert flags == [(False, False), (False, False), (False, True)]


def test_reset_uniform_over_start_cells_g3():
    env = GridWorld(parse_map("#.G\n.#.\n"), 5)
    keys = jax.random.split(jax.random.key(1), 6000)
    starts = np.asarray(jax.vmap(lambda k: env.reset(k)[1].position)(keys))
    assert set(starts.tolist()) == {1, 3, 5}  # never the goal or an obstacle
    np.testing.assert_allclose(np.bincount(starts, minlength=6)[[1, 3, 5]] / 6000, 1 / 3, atol=0.03)


def test_shaped_reward_e5():
    env = GridWorld(get_map("paper"), 40)

    def rtilde(cell, bumped, known):
        moved = env.transition(env.reset_at(0), 0).replace(state=env.reset_at(0).replace(
            position=jnp.int32(cell)), bumped=jnp.bool_(bumped))
        return float(env.rtilde(moved, jnp.bool_(known)))

    s = xy(env, 5, 6)  # one below the goal: ‖s' − g‖ = 1
    assert rtilde(s, False, True) == pytest.approx(0.5)
    assert rtilde(s, False, False) == 0.0  # goal not known yet
    assert rtilde(s, True, True) == -1.0  # bumped
    far = xy(env, 8, 9)  # distance 5
    assert rtilde(far, False, True) == pytest.approx(1 / 6)


def test_bad_chances():
    with pytest.raises(UsageError, match="chances must be a positive integer"):
        GridWorld(get_map("paper"), 0)


def test_paper_like_maps_scale_the_paper_layout():
    from jaxeac.envs.grid import PAPER_MAP, paper_like_map

    assert paper_like_map(11) == PAPER_MAP
    for n in (7, 15, 21):
        grid = parse_map(paper_like_map(n))
        assert (grid.height, grid.width, grid.goal) == (n, n, (n // 2, n // 2))
        assert grid.obstacles.any(axis=0).sum() >= 2  # both walls present
    with pytest.raises(UsageError, match="at least 5"):
        paper_like_map(3)
