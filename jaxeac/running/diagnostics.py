"""Memory diagnostics (SPEC E8): which branch of E1 chose each step, how many steps learnt (E2),
and where the failure flags (E6) landed: the numbers that explain a result.

The run loops count nothing (their per-seed results and speed stay as they are). A grid run's
diagnostics re-run its first seeds (`diagnostic_seed_count`) through the `trials` loop's chances
(`count_runs`), adding each chance's `StepRoute` from the agent's own `select_action` to the counts
of its chance index. C may be data there (a mixed layout's), so a study's tasks share E8's programs.
Seed i uses ``fold_in(root, i)`` in every loop (R1) and the loops agree bit for bit (R2), so the
diagnosed seeds are the run's own; `diagnose_seeds` returns their successes to show it. Bowling
gathers the same `StepRoute` of every throw during its run (`jaxeac.experiments.bowling`).

Shares are pooled over the diagnosed seeds' steps (a ratio of sums, not a mean of per-seed
ratios); `diagnostics_block` writes them for summary.json.
SPEC ids (G1…, E1…, B1…, R1…) are defined in docs/SPEC.md.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxeac.algorithm.agent import AgentState, StepRoute, end_trial, init_agent
from jaxeac.algorithm.buffer import BufferMemory
from jaxeac.algorithm.config import AgentConfig, Hyper
from jaxeac.envs.protocol import chance_bound
from jaxeac.pytree import pytree_dataclass
from jaxeac.rng import KEY_LIMIT, as_key, root_key_int, seed_key, seed_words
from jaxeac.running.config import RunConfig
from jaxeac.running.loops import (
    Env,
    bind_inputs,
    chance_of_trial,
    check_run_args,
    first_chance,
    program_inputs,
    program_key,
    state_bytes_per_seed,
)
from jaxeac.running.outputs import KEEP_LOGS
from jaxeac.running.programs import load_or_build
from jaxeac.running.threads import OnceCache
from jaxeac.runtime import trim_host_memory

#: A grid run diagnoses its first `diagnostic_seed_count` seeds (summary.json: ``diagnostics_seeds``):
#: at most DIAGNOSTIC_SEEDS, and at most DIAGNOSTIC_STEPS chance evaluations (T × C a seed in the
#: trials loop, which takes every chance) but never fewer than MIN_DIAGNOSTIC_SEEDS.
DIAGNOSTIC_SEEDS = KEEP_LOGS  # as many as a compact run keeps the trial logs of (`diagnostics_from_logs`)
DIAGNOSTIC_STEPS = 10_000_000
MIN_DIAGNOSTIC_SEEDS = 100


def diagnostic_seed_count(n_seeds: int, trials: int, chances: int) -> int:
    """How many of a run's first seeds E8 re-runs: 1000 on the paper grid (T·C = 8000), 100 on Four
    Rooms (C = 500), where 1000 took a quarter of `jaxeac study`'s time on the 2-core CPU."""
    budget = max(MIN_DIAGNOSTIC_SEEDS, DIAGNOSTIC_STEPS // max(1, trials * chances))
    return int(min(n_seeds, DIAGNOSTIC_SEEDS, budget))

#: Device bytes one chunk of diagnosed seeds may hold (their agents and per-chance routes).
CHUNK_BYTES = 1 << 28


@pytree_dataclass
class SeedDiagnostics:
    """E8's counts for one seed (leaves get a leading seed axis over many)."""

    routes: StepRoute  # int32 [C] each: per chance index, steps taken, chosen by E1(a), restricted by E1(b), learnt
    flags: jax.Array  # int32 []: (state, action) pairs flagged failed when the run ends (E6)
    flags_on_best: jax.Array  # int32 []: of those, the pairs whose action is a best action at its state
    best_at_flags: jax.Array  # float []: Σ over flagged pairs of (best actions at the state) / A
    success: jax.Array  # bool [T]: the run's per-trial successes


def failure_pairs(cfg: AgentConfig, agent: AgentState, n_states: int, n_actions: int
                  ) -> tuple[jax.Array, jax.Array, jax.Array]:
    """(states, actions, held), int32/int32/bool [P]: the (state, action) pairs the failure memory
    holds after the agent's last trial (E6 only adds flags, so every pair flagged during the run;
    an E7 buffer that overflowed keeps its latest K). Dense layout: every pair of the table
    (P = S·A, held where flagged); buffer: its K slots (held where filled; no pair twice), read
    directly, so that no per-state search over the slots runs. Nothing held without a failure memory."""
    if not cfg.failure_memory:
        none = jnp.zeros((0,), jnp.int32)
        return none, none, jnp.zeros((0,), bool)
    memory = agent.memory
    if isinstance(memory, BufferMemory):  # slots below the insertion count are filled (FIFO)
        held = jnp.arange(memory.failure_states.shape[0]) < memory.failure_count
        return memory.failure_states, memory.failure_actions, held
    table = jax.vmap(lambda s: memory.failure_flags(s, agent.trial, agent.outcomes))(jnp.arange(n_states))
    states, actions = jnp.divmod(jnp.arange(n_states * n_actions, dtype=jnp.int32), n_actions)
    return states, actions, table.reshape(-1)


def flag_counts(pairs: tuple[jax.Array, jax.Array, jax.Array], best: jax.Array | None
                ) -> tuple[jax.Array, jax.Array, jax.Array]:
    """(flags, flags on a best action, Σ over flags of the share of best actions at their state)
    of one seed's `failure_pairs`, given the best actions `best` [S, A] (None: none known)."""
    states, actions, held = pairs
    n = held.sum(dtype=jnp.int32)
    if best is None:
        return n, jnp.int32(0), jnp.float32(0.0)
    best = jnp.asarray(best, bool)
    states = jnp.clip(states, 0, best.shape[0] - 1)  # an empty buffer slot holds −1 (not held)
    on_best = held & best[states, jnp.clip(actions, 0, best.shape[1] - 1)]
    share = best.sum(axis=1) / best.shape[1]
    return n, on_best.sum(dtype=jnp.int32), jnp.where(held, share[states], 0.0).sum(dtype=jnp.float32)


def trials_config(env: Env, cfg: RunConfig) -> RunConfig:
    """`cfg` in the literal `trials` loop (no memory jumps, XLA ops): the loop `diagnose` runs in."""
    return dataclasses.replace(cfg, loop="trials", kernel="auto", jump="auto", lanes=None).resolve(env)


def count_runs(env: Env, cfg: RunConfig, keys: jax.Array, hyper: Hyper
               ) -> tuple[AgentState, StepRoute, jax.Array]:
    """The seeds of `keys` [M] run side by side in the `trials` loop
    (`jaxeac.running.loops.chance_of_trial`: every chance up to C, masked once the trial has ended,
    then E4/E6), each chance's `StepRoute` added to the counts of its chance index instead of kept
    per trial: (final agents, int32 [M, bound] counts per field, successes bool [M, T]).

    A trial's chances stop once every seed's trial has ended (a masked chance changes nothing and
    counts nothing), and at C, which may be data (a mixed layout's), so tasks of every C share one
    program and pay for their own chances only. The seeds share the chance index, so each count is
    one slice's add (a per-seed index, as a vmapped loop has, is a scatter: 10x slower on a CPU)."""
    check_run_args(env, cfg, hyper)
    cfg = cfg.resolve(env)
    bound = chance_bound(env)
    words = jax.vmap(lambda k: seed_words(as_key(k, "key")))(keys)
    agents = jax.vmap(lambda _: init_agent(cfg.agent, env.n_states, env.n_actions, bound, cfg.trials))(words)
    zeros = jnp.zeros((words.shape[0], bound), jnp.int32)

    def take(at, w):
        return chance_of_trial(env, cfg, hyper, w, diagnose=True)(at)

    def trial(carry, _):
        agents, counts = carry

        def chance(inner):
            c, at, reached, counts = inner
            at, (*_, hit, route) = jax.vmap(take)(at, words)
            counts = jax.tree.map(lambda n, r: n.at[:, c].add(r.astype(jnp.int32)), counts, route)
            return c + 1, at, reached | hit, counts

        def going(inner):
            c, at, _, _ = inner
            return (c < env.n_chances) & ~at.done.all()

        first = jax.vmap(lambda a, w: first_chance(env, a, w))(agents, words)
        _, end, reached, counts = jax.lax.while_loop(
            going, chance, (jnp.int32(0), first, jnp.zeros(words.shape[0], bool), counts))
        agents = jax.vmap(lambda a, r: end_trial(cfg.agent, a, r, jnp.bool_(True)))(end.agent, reached)
        return (agents, counts), reached

    (agents, counts), success = jax.lax.scan(trial, (agents, StepRoute(zeros, zeros, zeros, zeros)), None,
                                             length=cfg.trials)
    return agents, counts, success.T


def seeds_diagnostics(env: Env, cfg: RunConfig, keys: jax.Array, hyper: Hyper,
                      best: jax.Array | None = None) -> SeedDiagnostics:
    """The seeds of `keys` [M] in the `trials` loop (`count_runs`), reduced to their E8 counts."""
    cfg = trials_config(env, cfg)
    agents, counts, success = count_runs(env, cfg, keys, hyper)
    flags = jax.vmap(lambda a: flag_counts(failure_pairs(cfg.agent, a, env.n_states, env.n_actions), best))(agents)
    return SeedDiagnostics(counts, *flags, success)


def _program(env: Env, cfg: RunConfig, has_best: bool, devices: tuple):
    """jit over a chunk of seeds: ``(root, seeds [M], hyper, best, tables) -> SeedDiagnostics [M]``,
    split over `devices` (seeds are independent, R1); one per `program_key` (a tabular task's
    tables are its inputs: tasks of one layout share it)."""
    return _keyed_program(program_key(env), env, cfg, has_best, devices)


_PROGRAMS: dict = {}


def _keyed_program(key, env: Env, cfg: RunConfig, has_best: bool, devices: tuple):
    whole = (key, cfg, has_best, devices)
    n_devices = len(devices)
    if whole in _PROGRAMS:
        return _PROGRAMS[whole]
    if len(_PROGRAMS) >= 16:
        _PROGRAMS.clear()

    def batch(root, seeds, hyper, best, tables):
        keys = jax.vmap(seed_key, in_axes=(None, 0))(root, seeds)
        bound = bind_inputs(env, tables)
        return seeds_diagnostics(bound, cfg, keys, hyper, best if has_best else None)

    if n_devices > 1:
        from jax.sharding import PartitionSpec

        from jaxeac.running.batch import SEEDS_AXIS, seed_mesh

        mesh = seed_mesh(devices)
        batch = jax.shard_map(batch, mesh=mesh, in_specs=(PartitionSpec(), PartitionSpec(SEEDS_AXIS),
                                                          PartitionSpec(), PartitionSpec(), PartitionSpec()),
                              out_specs=PartitionSpec(SEEDS_AXIS), check_vma=False)
    _PROGRAMS[whole] = program = jax.jit(batch)
    return program


def _devices(platform: str | None, n_seeds: int) -> tuple:
    """The local devices of `platform` (None: JAX's default backend) that `n_seeds` seeds split over:
    one device where `platform` is not the default backend (the host's CPU beside an accelerator's
    runs, where a study's many calls run side by side: split over the 16 host devices of one H100,
    the paper grid's E8 took 26.9 s in `jaxeac study --seeds 1000`, on one device 9.5 s)."""
    devices = tuple(jax.local_devices(backend=platform))
    if platform is not None and platform != jax.default_backend():
        return devices[:1]
    return devices[:min(len(devices), n_seeds)]


#: Seeds in one chunk of E8 where C is data (`jaxeac.envs.tabular.TableLayout.mixed_chances`): the
#: fewest any task diagnoses (`MIN_DIAGNOSTIC_SEEDS`), so that one program per algorithm serves the
#: layout's tasks whatever their C and seed counts (a study: 5 programs, not 20).
MIXED_CHUNK = MIN_DIAGNOSTIC_SEEDS


def _plan(env: Env, cfg: RunConfig, seeds: np.ndarray, best: np.ndarray | None, devices: tuple):
    """(config in the trials loop, chunk, best input, tables) of a `diagnose_seeds` call. Where the
    tables are inputs, a best-action input always goes in (none known: all False, its counts unread)."""
    cfg = trials_config(env, cfg)
    n_devices = len(devices)
    tables = program_inputs(env)
    per_seed = state_bytes_per_seed(env, cfg) + 16 * chance_bound(env) + cfg.trials + env.n_states * env.n_actions
    chunk = max(1, min(seeds.size, CHUNK_BYTES // per_seed))
    if isinstance(bind_inputs(env, tables).n_chances, jax.Array):
        chunk = min(chunk, MIXED_CHUNK)
    chunk = -(-chunk // n_devices) * n_devices
    best_arg = np.zeros((), bool)
    if best is None and tables:
        best = np.zeros((env.n_states, env.n_actions), bool)
    if best is not None:  # padded states (a tabular layout's, `bind_inputs`) have no best action
        n_padded = bind_inputs(env, tables).n_states
        best_arg = np.pad(np.asarray(best, bool), ((0, n_padded - np.shape(best)[0]), (0, 0)))
    return cfg, chunk, best_arg, tables


_EXECUTABLES = OnceCache()  # (program, chunk, best's shape) -> the compiled program


def _executable(env: Env, cfg: RunConfig, devices: tuple, has_best: bool, args: tuple):
    """The compiled program for these inputs' shapes, compiled once: a later caller, on any
    thread, waits for the first (`prepare_diagnostics` compiles ahead of the runs)."""
    shapes = tuple(str(jax.typeof(x)) for x in jax.tree.leaves(args[2:4]))  # the rates' and best's
    key = ((program_key(env), cfg, has_best, devices), args[1].shape, shapes)

    def build():
        program = _program(env, cfg, has_best, devices).lower(*args).compile()
        trim_host_memory()  # what XLA's compiler freed goes back (as after a run's compile: `batch`)
        return program

    identity = (program_key(env), cfg, has_best, [(d.platform, d.id) for d in devices])
    return _EXECUTABLES.get(key, lambda: load_or_build("diagnostics", identity, args, build,
                                                       platform=devices[0].platform)[0])[0]


def _checked_seeds(seeds) -> np.ndarray:
    seeds = np.asarray(seeds)
    if seeds.ndim != 1 or not (seeds.size == 0 or np.issubdtype(seeds.dtype, np.integer)):
        raise TypeError(f"seeds must be a 1-D sequence of integer seed indices (got {seeds!r})")
    seeds = seeds.astype(np.int64)
    if seeds.size == 0:
        raise ValueError("seeds is empty: no seeds to diagnose; pass at least one seed index")
    if seeds.min() < 0 or seeds.max() >= KEY_LIMIT:
        raise ValueError(f"seeds must lie in 0..{KEY_LIMIT - 1} (got {int(seeds.min())}..{int(seeds.max())})")
    return seeds


def prepare_diagnostics(env: Env, cfg: RunConfig, *, n_seeds: int, best: np.ndarray | None = None,
                        hyper: Hyper | None = None, platform: str | None = None) -> None:
    """Compile the program `diagnose_seeds` of `n_seeds` seeds will run (for these arguments),
    so that the call finds it compiled: compiles of many tasks' diagnostics can go at once,
    ahead of their runs."""
    seeds = _checked_seeds(np.arange(n_seeds))
    devices = _devices(platform, seeds.size)
    with jax.default_device(devices[0]):  # this thread's uncommitted inputs go to `devices`
        cfg, chunk, best_arg, tables = _plan(env, cfg, seeds, best, devices)
        hyper = cfg.hyper() if hyper is None else hyper
        args = (jax.random.key(0), np.zeros(chunk, np.int32), hyper, best_arg, tables)
        _executable(env, cfg, devices, best_arg.ndim > 0, args)


def diagnose_seeds(env: Env, cfg: RunConfig, *, root_key: int, seeds: Sequence[int] | np.ndarray,
                   best: np.ndarray | None = None, hyper: Hyper | None = None,
                   platform: str | None = None) -> SeedDiagnostics:
    """E8's counts of seeds `seeds` of a run with root key `root_key`: numpy arrays with a leading
    seed axis, from the `trials` loop counting each chance's route (`count_runs`; same keys, same
    runs: R1, R2).
    `best`: bool [S, A], the best actions of each state (None: none known). Chunks are sized to
    hold `CHUNK_BYTES` and split over the local devices of `platform` (default: JAX's default
    backend; ``"cpu"`` beside a GPU run: the same counts, R2)."""
    seeds = _checked_seeds(seeds)
    devices = _devices(platform, seeds.size)
    parts = []
    with jax.default_device(devices[0]):  # this thread's uncommitted inputs go to `devices`
        cfg, chunk, best_arg, tables = _plan(env, cfg, seeds, best, devices)
        root = jax.random.key(root_key_int(root_key))
        hyper = cfg.hyper() if hyper is None else hyper
        # One chunk in flight per call: a study's 20 calls side by side, each queueing all its chunks
        # on 16 CPU devices at once, stalled (no chunk done in 90 s); read one by one, they never did.
        for start in range(0, seeds.size, chunk):
            part = seeds[start:start + chunk]
            padded = np.pad(part, (0, chunk - part.size), mode="edge").astype(np.int32)
            args = (root, padded, hyper, best_arg, tables)
            out = jax.device_get(_executable(env, cfg, devices, best_arg.ndim > 0, args)(*args))
            parts.append(jax.tree.map(lambda x, n=part.size: np.asarray(x)[:n], out))
    whole = jax.tree.map(lambda *xs: np.concatenate(xs), *parts)
    # per chance index up to the task's own C (a mixed layout's counts run to the bound)
    return whole.replace(routes=jax.tree.map(lambda x: x[:, :env.n_chances], whole.routes))


def diagnostics_from_logs(logs: np.ndarray, n_chances: int) -> SeedDiagnostics:
    """E8's counts of seeds of an algorithm without memories (AC, the X3 baselines) from their trial
    logs (int [N, T]: chances used, negated if failed), as numpy arrays with a leading seed axis.

    Without memories every step is E1 (c) and learns (E2) and no flag is ever set, so the steps
    taken at chance index c are the trials that lasted more than c chances. Equal to
    `diagnose_seeds` of the same seeds (tested), without compiling and running the `trials` loop."""
    lengths = np.abs(np.asarray(logs)).astype(np.int64)
    n, trials = lengths.shape
    rows = np.arange(n)[:, None] * (n_chances + 1)  # per seed: trials of each length (1 … C)
    ended = np.bincount((rows + lengths).ravel(), minlength=n * (n_chances + 1)).reshape(n, n_chances + 1)
    taken = (trials - np.cumsum(ended, axis=1)[:, :n_chances]).astype(np.int32)  # trials longer than c
    none = np.zeros_like(taken)
    return SeedDiagnostics(routes=StepRoute(taken, none, none, taken), flags=np.zeros(n, np.int32),
                           flags_on_best=np.zeros(n, np.int32), best_at_flags=np.zeros(n, np.float32),
                           success=np.asarray(logs) > 0)


def _share(part, whole) -> float | None:
    return float(part) / float(whole) if whole else None


def diagnostics_block(routes: StepRoute, flags: int, *, flags_judged: int | None = None,
                      flags_on_best: int | None = None, best_at_flags: float | None = None) -> dict:
    """summary.json's ``memory_diagnostics`` entry of one algorithm (E8), from per-chance counts
    `routes` (int [C] or [N, C], summed over seeds) and the run's flag count `flags`. The best-action
    shares are over `flags_judged` flags (default: all of them); None where no best action is known.
    Shares are None where their denominator is 0."""
    taken, remembered, restricted, learns = (np.asarray(x).reshape(-1, np.shape(x)[-1]).sum(axis=0)
                                             for x in (routes.taken, routes.remembered, routes.restricted,
                                                       routes.learns))
    judged = flags if flags_judged is None else flags_judged
    known = flags_on_best is not None
    return {
        "steps": int(taken.sum()),
        "steps_per_chance": taken.astype(int).tolist(),
        "hit_rate_per_chance": [_share(h, n) for h, n in zip(remembered, taken, strict=True)],
        "hit_rate": _share(remembered.sum(), taken.sum()),
        "restricted_share": _share(restricted.sum(), taken.sum()),
        "learning_share": _share(learns.sum(), taken.sum()),
        "flags": int(flags),
        "flags_judged": int(judged) if known else 0,
        "flags_on_best_share": _share(flags_on_best, judged) if known else None,
        "flags_on_best_chance": _share(best_at_flags, judged) if known else None,
    }


def seeds_block(d: SeedDiagnostics, best_known: bool) -> dict:
    """`diagnostics_block` of `diagnose_seeds`'s counts."""
    flags = int(d.flags.sum())
    if not best_known:
        return diagnostics_block(d.routes, flags)
    return diagnostics_block(d.routes, flags, flags_on_best=int(d.flags_on_best.sum()),
                             best_at_flags=float(d.best_at_flags.sum(dtype=np.float64)))
