"""The grid world of Debnath & Nassour (2014) §V-A, as a functional JAX environment.

SPEC G1–G5: an ASCII map (``.`` free, ``#`` obstacle, ``G`` goal; x = column,
y = row), four actions (G2: 0 right, 1 left, 2 up, 3 down), a uniformly drawn
free non-goal start cell (G3), moves that stay put off the grid (r = 0) or on
bumping an obstacle (r = −1), enter the goal with r = +1 and terminate (G4),
and at most C chances per trial (G5: truncation, kept apart from termination).

Static structure (the map, transition tables) lives on the `GridWorld` object;
`reset`/`step` are pure functions over the frozen `GridState`, gymnax-style, and the run
loops' `start`/`move` (`jaxeac.envs.protocol`, X1) are the same moves.
States are flat cell indices ``s = y * width + x``.
SPEC ids (G1…, E1…, B1…, R1…) are defined in docs/SPEC.md.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxeac.envs.protocol import KernelTables, Transition, UniformEnv
from jaxeac.errors import UsageError, check_int, check_number
from jaxeac.pytree import pytree_dataclass
from jaxeac.rng import uniform_index

#: G2 action order and the (dx, dy) each one applies.
ACTION_NAMES = ("right", "left", "up", "down")
ACTION_DELTAS = ((1, 0), (-1, 0), (0, -1), (0, 1))

#: G1: the `paper` preset map, 11×11, goal at the centre, two obstacles.
PAPER_MAP = """\
...........
...........
...........
...#.......
...#.......
...#.G.....
...#.......
...#.......
.....####..
...........
...........
"""



def paper_like_map(size: int) -> str:
    """The paper's layout scaled to a size × size grid (goal at the centre, the two walls at the
    same relative places); ``paper_like_map(11) == PAPER_MAP``. For calibration sweeps over size."""
    if size < 5:
        raise UsageError(f"map size must be at least 5 (got {size})")

    def at(frac):  # a fraction of the 11×11 layout's 0..10 span
        return round(frac * (size - 1) / 10)

    cells = [["."] * size for _ in range(size)]
    for y in range(at(3), at(7) + 1):
        cells[y][at(3)] = "#"
    for x in range(at(5), at(8) + 1):
        cells[at(8)][x] = "#"
    cells[size // 2][size // 2] = "G"
    return "\n".join("".join(row) for row in cells) + "\n"


MAPS = {"paper": PAPER_MAP, **{f"paper{n}": paper_like_map(n) for n in (7, 9, 13, 15, 21)}}


@dataclasses.dataclass(frozen=True)
class GridMap:
    """A validated map (G1): obstacle mask [H, W], goal cell, and start cells."""

    height: int
    width: int
    obstacles: np.ndarray  # bool [H, W]
    goal: tuple[int, int]  # (x, y)
    text: str

    @property
    def n_cells(self) -> int:
        return self.height * self.width

    @property
    def goal_index(self) -> int:
        return self.goal[1] * self.width + self.goal[0]

    @property
    def start_cells(self) -> np.ndarray:
        """G3: flat indices of free, non-goal cells, in row-major order."""
        free = ~self.obstacles.reshape(-1)
        free[self.goal_index] = False
        return np.flatnonzero(free).astype(np.int32)


#: Most cells a map may have: the transition table is a constant of the compiled run, and per-seed
#: tables are dense; a 3-million-cell map took ~30 s for a two-seed run, 10 million over 5 minutes.
MAX_CELLS = 1 << 22


def parse_map(text: str, *, source: str = "map") -> GridMap:
    """Parse and validate an ASCII map (G1); raise `UsageError` naming the problem.

    A leading UTF-8 byte-order mark (as some editors save) is ignored.
    """
    text = text.removeprefix("\ufeff")
    rows = [line.rstrip() for line in text.strip().splitlines()]
    if not rows or rows == [""]:
        raise UsageError(f"{source} is empty; give one row of '.', '#' and 'G' per line")
    widths = {len(r) for r in rows}
    if len(widths) != 1:
        shown = sorted(widths)
        shown = shown if len(shown) <= 8 else [*shown[:4], "...", *shown[-2:]]
        raise UsageError(
            f"{source} has ragged rows (lengths {', '.join(map(str, shown))}); make every row the same width"
        )
    bad = sorted({ch for r in rows for ch in r} - set(".#G"))
    if bad:
        shown = "".join(bad[:12]) + ("..." if len(bad) > 12 else "")
        raise UsageError(
            f"{source} has unknown characters {shown!r}; use only '.', '#' and 'G'"
        )
    if len(rows) * len(rows[0]) > MAX_CELLS:
        raise UsageError(f"{source} has {len(rows) * len(rows[0]):,} cells, more than the {MAX_CELLS:,} "
                         "a run can hold as per-seed tables (beyond, even two seeds take many minutes to "
                         "set up); use a smaller map")
    cells = np.frombuffer("".join(rows).encode("ascii"), np.uint8).reshape(len(rows), len(rows[0]))
    goal_ys, goal_xs = np.nonzero(cells == ord("G"))
    if goal_ys.size != 1:
        raise UsageError(f"{source} must have exactly one goal 'G' (found {goal_ys.size})")
    obstacles = cells == ord("#")
    goal = (int(goal_xs[0]), int(goal_ys[0]))
    grid = GridMap(len(rows), len(rows[0]), obstacles, goal, "\n".join(rows) + "\n")
    if grid.start_cells.size == 0:
        raise UsageError(f"{source} has no free start cell besides the goal; add a '.' cell")
    return grid


def load_map(path: str | Path) -> GridMap:
    """Read a map file (G1, UTF-8, a byte-order mark allowed); a missing, unreadable, non-text or
    oversized file (a device such as /dev/zero; over 64 MiB, about as many cells, far beyond any
    run's memory) is a `UsageError`."""
    import os
    import stat

    max_bytes = 64 << 20
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            mode = os.fstat(fh.fileno()).st_mode
            if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
                raise UsageError(f"map file {path} is a device, not a text file; pass a map file")
            data = fh.read(max_bytes + 1)
    except FileNotFoundError:
        raise UsageError(f"map file {path} does not exist; check the --map path") from None
    except IsADirectoryError:
        raise UsageError(f"map file {path} is a folder; pass the path of a map file") from None
    except OSError as exc:
        reason = exc.strerror or exc
        raise UsageError(f"cannot read map file {path}: {reason}; pass a readable text file") from None
    if len(data) > max_bytes:
        raise UsageError(f"map file {path} is larger than {max_bytes >> 20} MiB (about {max_bytes:,} cells, "
                         "beyond any run's memory); pass a smaller map")
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise UsageError(f"map file {path} is not UTF-8 text ({exc.reason} at byte {exc.start}); "
                         "save it as plain text") from None
    return parse_map(text, source=f"map file {path}")


def get_map(name: str) -> GridMap:
    """A named map preset (G1), e.g. ``paper``."""
    if name not in MAPS:
        raise UsageError(f"unknown map preset {name!r}; choose one of {sorted(MAPS)}")
    return parse_map(MAPS[name], source=f"map preset {name!r}")


def check_chances(chances) -> int:
    """G5's C: a positive integer (int32 on the device). 2.5 or 0 is a `UsageError` (a ValueError),
    a string a TypeError, each naming ``chances``."""
    return check_int("chances", chances, fix="pass the chances per trial (G5), e.g. chances=40")


def check_slip(slip) -> float:
    """X1's slip: a probability in [0, 1] (`UsageError`; a non-number: TypeError), naming ``slip``."""
    return check_number("slip", slip, high=1.0, fix="pass e.g. 0.1 for a random action one time in ten")


@pytree_dataclass
class GridState:
    """Agent position (flat cell index) and the chance counter within the trial."""

    position: jax.Array  # int32 []
    chance: jax.Array  # int32 [], steps taken so far in this trial


class GridWorld(UniformEnv):
    """Functional grid world with precomputed transition tables (G1–G5), in the API of
    `jaxeac.envs.protocol` (gymnax-style ``reset``/``step``, and the run loops' contract)."""

    n_actions = 4
    deterministic = True  # G4: a (cell, action) always leads to the same cell

    def __init__(self, grid_map: GridMap, n_chances: int):
        if not isinstance(grid_map, GridMap):
            raise TypeError(f"grid_map must be a GridMap, from get_map, parse_map or load_map "
                            f"(got {grid_map!r})")
        self.map = grid_map
        self.n_chances = check_chances(n_chances)
        self.n_states = grid_map.n_cells
        next_state, reward, bumped = transition_tables(grid_map)
        self._next_state = next_state
        self._reward = reward
        self._bumped = bumped
        # One gather per step: next cell and the bump flag packed as 2·s' + bumped (the reward
        # follows from them: −1 on a bump, +1 on entering the goal, else 0).
        self._moves = (2 * next_state + bumped).reshape(-1).astype(np.int32)
        self._start_cells = grid_map.start_cells
        gx, gy = grid_map.goal
        ys, xs = np.divmod(np.arange(self.n_states), grid_map.width)
        #: ‖s − g‖₂ for every cell, used by the shaped reward of E5.
        self.goal_distance = np.hypot(xs - gx, ys - gy)  # float64; jnp casts to the default float

    @property
    def n_starts(self) -> int:
        return int(self._start_cells.size)

    @property
    def tables(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(next_state [S, A] int32, reward [S, A] float, bumped [S, A] bool)."""
        return self._next_state, self._reward, self._bumped

    def reset_at(self, start_index: jax.Array) -> GridState:
        """Start in free non-goal cell number `start_index` (row-major order)."""
        cells = jnp.asarray(self._start_cells)
        return GridState(position=cells[start_index], chance=jnp.int32(0))

    def reset_from(self, u: jax.Array) -> GridState:
        """G3: start in a free, non-goal cell drawn uniformly with the uniform `u`."""
        return self.reset_at(uniform_index(u, self.n_starts))

    def observation(self, state: GridState) -> jax.Array:
        """The agent's state index: the flat cell index."""
        return state.position

    def transition(self, state: GridState, action: jax.Array, u=None) -> Transition:
        """G4/G5: apply `action` (deterministic: `u` unused); terminated (a success) on reaching
        the goal, truncated after C chances."""
        s = state.position
        s_next, bumped = decode_move(jnp.asarray(self._moves)[s * self.n_actions + action])
        chance = state.chance + 1
        terminated = s_next == self.map.goal_index
        truncated = (~terminated) & (chance >= self.n_chances)
        reward = move_reward(bumped, terminated)
        return Transition(GridState(s_next, chance), reward, terminated, truncated, terminated, bumped)

    def rtilde(self, transition: Transition, goal_known: jax.Array) -> jax.Array:
        """E5 at the cell reached (`shaped_reward`)."""
        distance = jnp.asarray(self.goal_distance)[transition.state.position]
        return shaped_reward(distance, transition.bumped, goal_known)

    def kernel_tables(self) -> GridKernelTables:
        """The fused kernel's tables (`GridKernelTables`), built once."""
        if getattr(self, "_kernel_tables", None) is None:
            self._kernel_tables = GridKernelTables(self)
        return self._kernel_tables


class GridKernelTables(KernelTables):
    """`GridWorld` in the fused kernel (`jaxeac.envs.protocol.KernelTables`): the packed ``moves``
    (2·s' + bumped), ‖s − g‖₂ (``distance``) and the start cells. Reward and end follow from s'
    (`move_reward`: the goal is the one terminal state, a success); r̃ is always E5's shaped form."""

    def __init__(self, env: GridWorld):
        super().__init__({"moves": np.asarray(env._moves, np.int32),
                          "distance": np.asarray(env.goal_distance, np.float32),
                          "starts": np.asarray(env._start_cells, np.int32)},
                         env.n_actions, env.n_chances, env.n_starts)
        self.goal = env.map.goal_index

    def move(self, ref, s, action, words, trial, chance):
        s_next, bumped = decode_move(ref["moves"][s * self.n_actions + action])
        terminated = s_next == self.goal
        return s_next, move_reward(bumped, terminated), terminated, terminated, bumped

    def rtilde(self, ref, s_next, bumped, goal_known, reward):
        return shaped_reward(ref["distance"][s_next], bumped, goal_known)


def decode_move(move) -> tuple[jax.Array, jax.Array]:
    """(s', bumped) from an entry ``2·s' + bumped`` of `GridWorld`'s packed move table (G4)."""
    return move >> 1, (move & 1) == 1


def move_reward(bumped, terminated) -> jax.Array:
    """G4: r = −1 on bumping into an obstacle, +1 on entering the goal, else 0 (also off the grid)."""
    return jnp.where(bumped, -1.0, jnp.where(terminated, 1.0, 0.0))


def shaped_reward(distance, bumped, goal_known) -> jax.Array:
    """E5: r̃ = −1 on a bump; else R_max / (1 + ‖s' − g‖₂) (R_max = 1, `distance` = ‖s' − g‖₂)
    once the goal is known; else 0."""
    return jnp.where(bumped, -1.0, jnp.where(goal_known, 1.0 / (1.0 + distance), 0.0))


def shortest_steps(grid_map: GridMap) -> np.ndarray:
    """int64 [S]: the fewest moves (G2, G4) from each cell to the goal, by breadth-first search
    backwards from the goal over `transition_tables`; 0 at the goal, −1 on obstacles and on cells
    from which the goal cannot be reached. Not E5's ‖s − g‖₂, which ignores obstacles."""
    nxt = transition_tables(grid_map)[0]
    free = ~grid_map.obstacles.reshape(-1)
    dist = np.full(grid_map.n_cells, -1, np.int64)
    dist[grid_map.goal_index] = 0
    level = np.zeros(grid_map.n_cells, bool)
    level[grid_map.goal_index] = True
    for d in range(1, grid_map.n_cells):
        level = free & (dist < 0) & level[nxt].any(axis=1)  # one move enters the previous level
        if not level.any():
            break
        dist[level] = d
    return dist


def shortest_actions(grid_map: GridMap) -> np.ndarray:
    """bool [S, A]: the actions (G2) that move a cell one step closer to the goal along a shortest
    path (`shortest_steps` one less at the cell reached): the best actions of E8. None at the goal,
    on obstacles and on cells that cannot reach the goal."""
    dist = shortest_steps(grid_map)
    nxt = transition_tables(grid_map)[0]
    return (dist[:, None] > 0) & (dist[nxt] == dist[:, None] - 1)


def transition_tables(grid_map: GridMap) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tabulate G4 for every (cell, action): next cell, reward, bumped."""
    h, w = grid_map.height, grid_map.width
    n = h * w
    next_state = np.zeros((n, 4), np.int32)
    reward = np.zeros((n, 4))
    bumped = np.zeros((n, 4), bool)
    goal = grid_map.goal_index
    for s in range(n):
        y, x = divmod(s, w)
        for a, (dx, dy) in enumerate(ACTION_DELTAS):
            nx, ny = x + dx, y + dy
            if not (0 <= nx < w and 0 <= ny < h):
                next_state[s, a] = s  # off the grid: stay, r = 0
            elif grid_map.obstacles[ny, nx]:
                next_state[s, a], reward[s, a], bumped[s, a] = s, -1.0, True
            else:
                t = ny * w + nx
                next_state[s, a] = t
                reward[s, a] = 1.0 if t == goal else 0.0
    return next_state, reward, bumped
