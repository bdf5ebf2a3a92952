"""A hand-vectorised NumPy peer of the JAX runner, for speed comparisons on the same SPEC.

Same model as `jaxeac.running.batch` with dense memories (SPEC E7): the grid world
G1–G5 (transition tables from `jaxeac.envs.grid.GridWorld`), AC eqs. (1)–(4), and EAC's
Algorithm 1 with E1 (success action, else softmax over unflagged actions, else
plain softmax), E2 (learn only on E1(c) steps), E3, E4 (last write wins), E5
(shaped r̃) and E6 (``failure_rule="previous_trial"``).

Seeds are vectorised: preferences ``[N, S, A]``, values ``[N, S]``, success
table ``int32 [N, S]`` (−1 = none), failure flags ``bool [N, S, A]``, all
addressed through flat row indices ``n·S + s``; a state's four failure flags are
read as one ``uint32`` word. Python loops run over trials and chances only (and
over chances of successful trials for E4's ordered write); seeds that reached
the goal drop out of the active set, so the work per chance shrinks as they
succeed. Actions come from inverse-CDF sampling with one uniform per seed and
chance, as in `jaxeac.algorithm.agent.sample_softmax`.

Randomness (R1/R2, peer reading): numbers are drawn per trial, in bulk for all
seeds, from one ``numpy.random.Generator`` (PCG64) seeded with `seed`. The same
`seed` and `n_seeds` give identical results (R2); unlike the JAX runner, a
seed's results depend on `n_seeds` (R1 is not kept), and they cannot equal
JAX's: the two agree in distribution only.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from jaxeac.algorithm.config import ALGORITHMS, AgentConfig
from jaxeac.envs.grid import GridMap, GridWorld, get_map
from jaxeac.errors import UsageError

#: ``draw(trial) -> (start_index int [N], uniforms float [N, C])``: one trial's random numbers.
Draw = Callable[[int], tuple[np.ndarray, np.ndarray]]


def _agent_config(algo: str) -> AgentConfig:
    if algo not in ALGORITHMS:
        raise UsageError(f"unknown algorithm {algo!r}; choose from {sorted(ALGORITHMS)}")
    cfg = ALGORITHMS[algo]
    if cfg.learn_on_memory_steps or cfg.failure_rule != "previous_trial":
        raise UsageError(f"algorithm {algo!r} uses an E2/E6 variant the NumPy peer does not implement")
    return cfg


def pcg64_draw(seed: int, n_seeds: int, n_starts: int, n_chances: int, dtype=np.float32) -> Draw:
    """Bulk per-trial draws from one PCG64 generator: start indices (G3) and action uniforms (E1)."""
    rng = np.random.Generator(np.random.PCG64(seed))

    def draw(trial: int) -> tuple[np.ndarray, np.ndarray]:
        starts = rng.integers(0, n_starts, size=n_seeds)
        return starts, rng.random((n_chances, n_seeds), dtype=dtype).T  # [N, C] view of a [C, N] draw

    return draw


def simulate(
    world: GridWorld,
    cfg: AgentConfig,
    draw: Draw,
    *,
    n_seeds: int,
    trials: int,
    alpha: float,
    beta: float,
    gamma: float,
    temperature: float,
    dtype=np.float32,
) -> dict[str, np.ndarray]:
    """Run `n_seeds` seeds of Algorithm 1 for `trials` trials, drawing random numbers with `draw`.

    Returns ``success bool [N, T]``, ``steps int32 [N, T]``, ``policy int32 [N, S]`` (G7),
    and the final ``preferences [N, S, A]`` and ``values [N, S]``.
    """
    n, c_max = int(n_seeds), world.n_chances
    n_states, n_actions = world.n_states, world.n_actions
    if n_actions != 4:
        raise ValueError("the NumPy peer packs the 4 failure flags of a state into one uint32 word")
    next_state, reward, bumped = (x.reshape(-1) for x in world.tables)  # flat index s·A + a
    reward = reward.astype(dtype)
    goal = world.map.goal_index
    start_cells = world.map.start_cells.astype(np.int64)
    # E5: R_max / (1 + ‖s' − g‖₂) per cell, computed in the working precision like the JAX code.
    shaped = (dtype(1.0) / (dtype(1.0) + world.goal_distance.astype(dtype))).astype(dtype)
    alpha, beta, gamma, tau = (dtype(x) for x in (alpha, beta, gamma, temperature))
    use_success, use_failure = cfg.success_memory, cfg.failure_memory
    zero, minus_one, minus_inf = dtype(0.0), dtype(-1.0), dtype(-np.inf)

    # [N, S, A] and [N, S] tables, addressed by flat rows n·S + s (and n·S·A + s·A + a).
    prefs = np.zeros((n * n_states, n_actions), dtype)
    prefs_flat = prefs.reshape(-1)
    values = np.zeros(n * n_states, dtype)
    success_mem = np.full(n * n_states, -1, np.int32) if use_success else None
    failure_mem = np.zeros((n * n_states, n_actions), bool) if use_failure else None
    # The 4 flags of a row read as one word: byte k is flag k (0 or 1) on any byte order.
    failure_words = failure_mem.view(np.uint32).reshape(-1) if use_failure else None
    all_flagged = np.uint32(0x01010101)
    goal_known = np.zeros(n, bool)
    prev_rtilde = np.zeros((c_max, n), dtype)
    prev_length = np.zeros(n, np.int32)

    out_success = np.zeros((trials, n), bool)
    out_steps = np.zeros((trials, n), np.int32)
    seed_rows = np.arange(n, dtype=np.int64) * n_states
    chance_index = np.arange(c_max)[:, None]

    for t in range(trials):
        start_index, uniforms = draw(t)
        uniforms = np.ascontiguousarray(np.asarray(uniforms, dtype).T)  # [C, N]
        states = np.zeros((c_max, n), np.int64)
        actions = np.zeros((c_max, n), np.int64)
        rtilde = np.zeros((c_max, n), dtype)
        length = np.zeros(n, np.int32)
        reached = np.zeros(n, bool)

        active = np.arange(n)  # seeds still in the trial
        base = seed_rows.copy()  # seed_rows[active]
        s = start_cells[start_index]  # G3
        for c in range(c_max):
            if active.size == 0:
                break
            row = base + s
            logits = np.take(prefs, row, axis=0).T.copy()  # [A, n], action-major
            if tau != 1:
                logits /= tau
            u = uniforms[c][active]
            learn = None
            if use_failure:  # E1(b): restrict to unflagged actions when some, not all, are flagged
                word = failure_words[row]
                restrict = (word != 0) & (word != all_flagged)
                if restrict.any():
                    for k in range(n_actions):
                        flagged = ((word >> np.uint32(8 * k)) & np.uint32(1)).astype(bool) & restrict
                        logits[k][flagged] = minus_inf
                learn = ~restrict
            # (1) by inverse CDF: the smallest a with u·Σw < cumsum(w)[a]
            weights = np.exp(logits - logits.max(axis=0))
            for k in range(1, n_actions):
                weights[k] += weights[k - 1]
            a = (weights <= u * weights[-1]).sum(axis=0)
            np.minimum(a, n_actions - 1, out=a)
            if use_success:  # E1(a): the remembered successful action wins
                remembered = success_mem[row]
                has = remembered >= 0
                a = np.where(has, remembered, a)
                learn = ~has if learn is None else learn & ~has

            move = s * n_actions + a
            s2 = next_state[move].astype(np.int64)  # G4
            terminal = s2 == goal  # E3
            # (3) δ = r + γ·V(s') − V(s), V(terminal) = 0; (2) critic, (4) actor, on E1(c) steps (E2)
            v_next = np.where(terminal, zero, values[base + s2])
            delta = reward[move] + gamma * v_next - values[row]
            if learn is not None:
                delta = np.where(learn, delta, zero)
            values[row] += alpha * delta
            prefs_flat[row * n_actions + a] += beta * delta

            if terminal.any():
                goal_known[active[terminal]] = True  # E5: this step included
            rt = np.where(goal_known[active], shaped[s2], zero)
            rt[bumped[move]] = minus_one
            states[c, active] = s
            actions[c, active] = a
            rtilde[c, active] = rt
            length[active] = c + 1
            if terminal.any():
                reached[active[terminal]] = True
                keep = ~terminal
                active, base, s = active[keep], base[keep], s2[keep]
            else:
                s = s2

        out_success[t] = reached
        out_steps[t] = length
        if use_success:  # E4: write each successful trial in chronological order (last write wins)
            won = np.flatnonzero(reached)
            for c in range(int(length[won].max()) if won.size else 0):
                won = won[length[won] > c]
                success_mem[seed_rows[won] + states[c, won]] = actions[c, won]
        if use_failure:  # E6: flag (s, a) of chance c where r̃(c|t) < r̃(c|t−1), failed trials only
            flag = (chance_index < np.minimum(length, prev_length)) & (rtilde < prev_rtilde) & ~reached
            fc, fn = np.nonzero(flag)
            failure_mem[seed_rows[fn] + states[fc, fn], actions[fc, fn]] = True
        prev_rtilde, prev_length = rtilde, length

    prefs = prefs.reshape(n, n_states, n_actions)
    policy = prefs.argmax(axis=2).astype(np.int32)  # G7
    if use_success:
        remembered = success_mem.reshape(n, n_states)
        policy = np.where(remembered >= 0, remembered, policy)
    return {
        "success": np.ascontiguousarray(out_success.T),
        "steps": np.ascontiguousarray(out_steps.T),
        "policy": policy,
        "preferences": prefs,
        "values": values.reshape(n, n_states),
    }


def run_numpy(
    grid_map: GridMap | str,
    *,
    algo: str,
    trials: int,
    chances: int,
    alpha: float = 0.1,
    beta: float = 0.3,
    gamma: float = 0.9,
    temperature: float = 1.0,
    n_seeds: int,
    seed: int = 0,
    dtype=np.float32,
) -> dict[str, np.ndarray]:
    """Run `n_seeds` seeds of `algo` (``"ac"``, ``"eac"``, …) on `grid_map` (a `GridMap` or preset name).

    Returns ``success bool [N, T]`` and ``steps int32 [N, T]`` (plus ``policy``,
    ``preferences``, ``values``). Same `seed` and `n_seeds` → identical output.
    """
    cfg = _agent_config(algo)
    if isinstance(grid_map, str):
        grid_map = get_map(grid_map)
    for name, value in (("trials", trials), ("seeds", n_seeds)):
        if isinstance(value, bool) or int(value) != value or value < 1:
            raise UsageError(f"{name} must be a positive integer (got {value!r})")
    if temperature <= 0:
        raise UsageError(f"temperature must be positive (got {temperature!r})")
    world = GridWorld(grid_map, chances)
    dtype = np.dtype(dtype).type
    draw = pcg64_draw(seed, int(n_seeds), world.n_starts, world.n_chances, dtype)
    return simulate(
        world, cfg, draw, n_seeds=int(n_seeds), trials=int(trials), alpha=alpha, beta=beta,
        gamma=gamma, temperature=temperature, dtype=dtype,
    )
