"""A numba peer of the grid-world runner (``@njit(parallel=True)``, ``prange`` over seeds).

The same algorithm, arithmetic (float32) and random numbers as the C peer (`c_peer.c`):
SPEC G3–G5, (1)–(4), E1–E7 with dense tables; seed i of a run uses splitmix64 seeded
from (run seed, i), so its results depend neither on the number of seeds nor on the
threads. Agrees with jaxeac in distribution only (``tests/test_peers.py``).

numba is optional: ``pip install 'jaxeac[bench]'``. `available()` says whether it imports.
The first call compiles (seconds); `warm_up()` does that up front, e.g. before timing.
"""

from __future__ import annotations

import math
import time

import numpy as np

from jaxeac.envs.grid import GridMap, GridWorld
from peers.c_peer import (
    F_FAILURE,
    F_LEARN_MEMORY,
    F_SUCCESS,
    F_WITHIN_TRIAL,
    algo_flags,
    check_args,
    problem,
    root_seed,
)

try:
    import numba
    from numba import njit, prange
except ImportError:  # the optional `bench` extra is not installed
    numba = None

#: Seeds per parallel block (one workspace per block).
BLOCK = 32


def available() -> bool:
    """True when numba imports (the `bench` extra)."""
    return numba is not None


def version() -> str | None:
    return None if numba is None else numba.__version__


if numba is not None:
    U = np.uint64
    GOLDEN = U(0x9E3779B97F4A7C15)
    MIX1, MIX2 = U(0xBF58476D1CE4E5B9), U(0x94D049BB133111EB)
    SEED_SALT = U(0x6A09E667F3BCC909)
    LOW32 = U(0xFFFFFFFF)
    TWO32 = U(1 << 32)
    S30, S27, S31, S32, S40 = U(30), U(27), U(31), U(32), U(40)
    INV24 = np.float32(2.0**-24)
    F0, F1, FM1 = np.float32(0.0), np.float32(1.0), np.float32(-1.0)
    NEG_INF = np.float32(-np.inf)

    @njit(inline="always")
    def _mix64(z):
        z = (z ^ (z >> S30)) * MIX1
        z = (z ^ (z >> S27)) * MIX2
        return z ^ (z >> S31)

    @njit(inline="always")
    def _next64(state):
        """splitmix64 step on a one-element uint64 array; returns the output."""
        state[0] += GOLDEN
        return _mix64(state[0])

    @njit(inline="always")
    def _uniform01(state):
        return np.float32(_next64(state) >> S40) * INV24

    @njit(inline="always")
    def _bounded(state, n):
        """Uniform in [0, n), unbiased (Lemire), as c_peer.c."""
        m = (_next64(state) >> S32) * n
        low = m & LOW32
        if low < n:
            threshold = (TWO32 - n) % n
            while low < threshold:
                m = (_next64(state) >> S32) * n
                low = m & LOW32
        return m >> S32

    @njit(inline="always")
    def _sample_softmax(prefs, row, allowed, tau, unit_tau, u):
        """(1) by inverse CDF over the actions whose bit is set in `allowed`, as jaxeac's sample_softmax."""
        l0, l1, l2, l3 = prefs[row], prefs[row + 1], prefs[row + 2], prefs[row + 3]
        if not unit_tau:
            l0, l1, l2, l3 = l0 / tau, l1 / tau, l2 / tau, l3 / tau
        top = NEG_INF
        if allowed & 1 and l0 > top:
            top = l0
        if allowed & 2 and l1 > top:
            top = l1
        if allowed & 4 and l2 > top:
            top = l2
        if allowed & 8 and l3 > top:
            top = l3
        w0 = math.exp(l0 - top) if allowed & 1 else F0
        w1 = math.exp(l1 - top) if allowed & 2 else F0
        w2 = math.exp(l2 - top) if allowed & 4 else F0
        w3 = math.exp(l3 - top) if allowed & 8 else F0
        c1 = w0 + w1
        c2 = c1 + w2
        c3 = c2 + w3
        target = u * c3
        a = np.int64(w0 <= target) + np.int64(c1 <= target) + np.int64(c2 <= target) + np.int64(c3 <= target)
        return a if a < 3 else 3

    @njit(cache=True)
    def _run_one(next_state, bumped, reward, shaped, starts, goal, flags, trials, chances, alpha, beta,
                 gamma, tau, rng, prefs, values, succ, fail, states, actions, rt, prev_rt,
                 out_success, out_steps, i, per_trial):
        """One seed (see c_peer.c's run_one); returns (successes, agent steps, first success)."""
        use_success = (flags & F_SUCCESS) != 0
        use_failure = (flags & F_FAILURE) != 0
        learn_memory = (flags & F_LEARN_MEMORY) != 0
        within = (flags & F_WITHIN_TRIAL) != 0
        record = use_success or use_failure
        unit_tau = tau == F1
        prefs[:] = F0
        values[:] = F0
        succ[:] = -1
        fail[:] = 0
        n_starts = U(starts.size)
        prev_len, goal_known, total_success, first, total_steps = 0, False, 0, -1, 0
        for t in range(trials):
            s = np.int64(starts[np.int64(_bounded(rng, n_starts))])  # G3
            length, reached = 0, False
            for c in range(chances):
                learn = True
                remembered = np.int64(succ[s]) if use_success else np.int64(-1)
                if remembered >= 0:  # E1(a)
                    a = remembered
                    learn = False
                else:
                    allowed = np.int64(15)
                    if use_failure:
                        f = np.int64(fail[s])
                        if f != 0 and f != 15:  # E1(b)
                            allowed = ~f & 15
                            learn = False
                    a = _sample_softmax(prefs, 4 * s, allowed, tau, unit_tau, _uniform01(rng))
                if learn_memory:  # E2 variant
                    learn = True
                move = 4 * s + a
                s2 = np.int64(next_state[move])  # G4
                terminal = s2 == goal  # E3
                if learn:  # E2: (3), (2), (4)
                    v_next = F0 if terminal else values[s2]
                    delta = (reward[move] + gamma * v_next) - values[s]
                    values[s] += alpha * delta
                    prefs[move] += beta * delta
                if record:
                    if terminal:
                        goal_known = True  # E5: this step included
                    states[c] = s
                    actions[c] = a
                    if bumped[move]:
                        rt[c] = FM1
                    elif goal_known:
                        rt[c] = shaped[s2]
                    else:
                        rt[c] = F0
                length = c + 1
                s = s2
                if terminal:
                    reached = True
                    break
            if reached:
                total_success += 1
                if first < 0:
                    first = t
                if use_success:  # E4: chronological order, last write wins
                    for c in range(length):
                        succ[states[c]] = actions[c]
            elif use_failure:  # E6
                if within:
                    for c in range(1, length):
                        if rt[c] < rt[c - 1]:
                            fail[states[c]] |= np.uint8(1 << actions[c])
                else:
                    for c in range(min(length, prev_len)):
                        if rt[c] < prev_rt[c]:
                            fail[states[c]] |= np.uint8(1 << actions[c])
            if record:
                rt, prev_rt = prev_rt, rt
                prev_len = length
            total_steps += length
            if per_trial:
                out_success[i, t] = reached
                out_steps[i, t] = length
        return total_success, total_steps, first

    @njit(parallel=True, cache=True)
    def _run(next_state, bumped, reward, shaped, starts, goal, flags, trials, chances, alpha, beta, gamma,
             tau, n_seeds, root, per_trial, tables, out_success, out_steps, out_policy, out_prefs, out_values,
             out_total_success, out_total_steps, out_first):
        n_states = shaped.size
        use_success = (flags & F_SUCCESS) != 0
        n_blocks = (n_seeds + BLOCK - 1) // BLOCK
        base = _mix64(root ^ SEED_SALT)
        for b in prange(n_blocks):
            prefs = np.zeros(4 * n_states, np.float32)
            values = np.zeros(n_states, np.float32)
            succ = np.empty(n_states, np.int8)
            fail = np.zeros(n_states, np.uint8)
            states = np.zeros(chances, np.int32)
            actions = np.zeros(chances, np.int8)
            rt = np.zeros(chances, np.float32)
            prev_rt = np.zeros(chances, np.float32)
            rng = np.zeros(1, np.uint64)
            for i in range(b * BLOCK, min(n_seeds, (b + 1) * BLOCK)):
                rng[0] = _mix64(base + U(i) * GOLDEN)  # as c_peer.c's seed_state
                ts, st, fs = _run_one(
                    next_state, bumped, reward, shaped, starts, goal, flags, trials, chances, alpha, beta,
                    gamma, tau, rng, prefs, values, succ, fail, states, actions, rt, prev_rt, out_success,
                    out_steps, i, per_trial)
                out_total_success[i] = ts
                out_total_steps[i] = st
                out_first[i] = fs
                if per_trial:  # G7: memory action, else argmax of preferences
                    for s in range(n_states):
                        if use_success and succ[s] >= 0:
                            out_policy[i, s] = succ[s]
                        else:
                            best = 0
                            for a in range(1, 4):
                                if prefs[4 * s + a] > prefs[4 * s + best]:
                                    best = a
                            out_policy[i, s] = best
                if tables:
                    out_prefs[i, :] = prefs
                    out_values[i, :] = values


def _require():
    if numba is None:
        raise RuntimeError("numba is not installed: pip install 'jaxeac[bench]' (or numba)")


def run_numba(
    grid: GridWorld | GridMap | str,
    *,
    algo: str,
    trials: int,
    chances: int | None = None,
    alpha: float = 0.1,
    beta: float = 0.3,
    gamma: float = 0.9,
    temperature: float = 1.0,
    n_seeds: int,
    seed: int = 0,
    threads: int | None = None,
    per_trial: bool = True,
    tables: bool = False,
) -> dict[str, np.ndarray]:
    """Run `n_seeds` seeds of `algo` on `grid` with numba; same arguments and outputs as `c_peer.run_c`.

    `threads`: numba threads for this call (default: numba's, i.e. $NUMBA_NUM_THREADS or every core).
    """
    _require()
    flags = algo_flags(algo)
    check_args(trials, n_seeds, temperature, threads)
    p = problem(grid, chances)
    n, t, s = int(n_seeds), int(trials), p.n_states
    success = np.zeros((n, t) if per_trial else (1, 1), np.bool_)
    steps = np.zeros((n, t) if per_trial else (1, 1), np.int32)
    policy = np.zeros((n, s) if per_trial else (1, 1), np.int8)
    prefs = np.zeros((n, 4 * s) if tables else (1, 1), np.float32)
    values = np.zeros((n, s) if tables else (1, 1), np.float32)
    total_success = np.zeros(n, np.int32)
    total_steps = np.zeros(n, np.int64)
    first = np.zeros(n, np.int32)
    f32 = np.float32
    old_threads = numba.get_num_threads()
    old_chunk = numba.get_parallel_chunksize()
    try:
        if threads is not None:
            numba.set_num_threads(int(threads))
        numba.set_parallel_chunksize(1)  # blocks are handed out dynamically, like schedule(dynamic)
        _run(p.next_state, p.bumped, p.reward, p.shaped, p.starts, np.int64(p.goal), np.int64(flags),
             np.int64(t), np.int64(p.chances), f32(alpha), f32(beta), f32(gamma), f32(temperature),
             np.int64(n), np.uint64(root_seed(seed)), per_trial, tables, success, steps, policy, prefs,
             values, total_success, total_steps, first)
    finally:
        numba.set_parallel_chunksize(old_chunk)
        numba.set_num_threads(old_threads)
    out = {"successes": total_success, "agent_steps": total_steps, "first_success": first}
    if per_trial:
        out |= {"success": success, "steps": steps, "policy": policy}
    if tables:
        out |= {"preferences": prefs.reshape(n, s, 4), "values": values}
    return out


def warm_up() -> float:
    """Compile the numba functions (a tiny run); returns the seconds it took."""
    _require()
    t0 = time.perf_counter()
    run_numba("paper", algo="eac", trials=2, chances=3, n_seeds=2, seed=0, tables=True)
    return time.perf_counter() - t0
