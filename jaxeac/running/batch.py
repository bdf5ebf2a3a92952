"""One seed's whole run as one compiled loop; many seeds via vmap, in chunks.

Seed i of a run uses ``fold_in(root_key, i)`` (SPEC R1), so its result never
depends on the seeds beside it, the chunk size or the device count, and the same
root key and config give bit-identical results (R2).

Two loop structures give bit-identical results (tested):

* ``trials`` — `trace_run`: a `lax.scan` over trials, each a `lax.scan` over C
  chances, masked once the trial has ended. The literal shape of Algorithm 1;
  needed by the buffer memory layout, whose writes happen at trial ends.
* ``flat`` — the fast path: all seeds of a chunk advance one *chance* per
  iteration and a seed whose trial ends starts its next trial at the next
  iteration, so trials that end early (EAC's, mostly) leave no padded slots.
  The loop stops when every seed of the chunk has run T trials.

On GPUs the flat loop's C chances per block run as one fused kernel
(`jaxeac.running.kernel`, chosen by `RunConfig.kernel`); it computes the same steps.

Random numbers come from one place: `step_uniform`, a counter-based hash of the
seed's key words and (trial, chance), so no per-step key splitting is needed and
both loops draw the same numbers.
"""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Literal, Protocol

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, PartitionSpec

from jaxeac.algorithm.agent import (
    AgentConfig,
    AgentState,
    Hyper,
    Rate,
    end_trial,
    greedy_policy,
    init_agent,
    learn_step,
    rate_at,
    record_step,
    select_action,
)
from jaxeac.errors import UsageError
from jaxeac.pytree import pytree_dataclass

Loop = Literal["auto", "flat", "trials"]
Kernel = Literal["auto", "xla", "pallas"]
KERNELS = ("auto", "xla", "pallas")


class Env(Protocol):
    """What the runner needs from an environment (the grid world satisfies it)."""

    n_states: int
    n_actions: int
    n_chances: int
    n_starts: int

    def reset_at(self, start_index: jax.Array) -> Any: ...
    def observation(self, state: Any) -> jax.Array: ...
    def step(self, state: Any, action: jax.Array) -> Any: ...
    def shaped_reward(self, s_next, bumped, goal_known) -> jax.Array: ...


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """One algorithm's run: trial count, step sizes (constant or optax schedule), agent, loop."""

    trials: int
    agent: AgentConfig
    alpha: Rate = 0.1
    beta: Rate = 0.3
    gamma: float = 0.9
    temperature: float = 1.0
    loop: Loop = "auto"
    lanes: int | None = None  # flat loop: seeds in flight per device; None: default_lanes
    kernel: Kernel = "auto"  # flat loop's chances: `jaxeac.running.kernel` (GPUs) or XLA ops; see resolved_kernel

    def __post_init__(self):
        if self.kernel not in KERNELS:
            raise UsageError(f"unknown kernel {self.kernel!r}; choose one of {KERNELS}")

    def hyper(self) -> Hyper:
        """The traced constants (a scheduled rate's traced slot is unused)."""
        def const(x):
            return jnp.asarray(0.0 if callable(x) else x, dtype=float)

        return Hyper(const(self.alpha), const(self.beta), const(self.gamma), const(self.temperature))

    @property
    def resolved_loop(self) -> Literal["flat", "trials"]:
        """`auto`: flat unless the buffer layout needs trial-end writes."""
        if self.loop != "auto":
            return self.loop
        buffered = self.agent.uses_memory and self.agent.memory == "buffer"
        return "trials" if buffered else "flat"


def resolved_kernel(env: Env, cfg: RunConfig, backend: str | None = None) -> Literal["xla", "pallas"]:
    """How the flat loop runs its chances: ``pallas`` (the fused kernel of `jaxeac.running.kernel`) or ``xla``.

    `auto`: the kernel on GPUs where it supports the env and config, XLA ops otherwise.
    ``pallas`` asks for the kernel anywhere; off GPUs it runs in Pallas's (slow) interpreter.
    """
    from jaxeac.running.kernel import kernel_unsupported

    if cfg.kernel == "xla":
        return "xla"
    why = kernel_unsupported(env, cfg)
    if cfg.resolved_loop != "flat":
        why = "the fused kernel runs the flat loop (the buffer memory needs the trials loop)"
    if cfg.kernel == "pallas":
        if why is not None:
            raise UsageError(f"{why}; use kernel='xla' (or 'auto')")
        return "pallas"
    return "pallas" if why is None and (backend or jax.default_backend()) == "gpu" else "xla"


@pytree_dataclass
class TrialRecord:
    """What one trial leaves behind (per chance: state, action, r̃; and totals)."""

    states: jax.Array  # int32 [C]
    actions: jax.Array  # int32 [C]
    rtilde: jax.Array  # float [C]
    length: jax.Array  # int32 [], chances actually used
    success: jax.Array  # bool []


@pytree_dataclass
class SeedResult:
    """G7 per-seed record: success and steps per trial, and the final greedy policy."""

    success: jax.Array  # bool [T]
    steps: jax.Array  # int32 [T]
    policy: jax.Array  # int32 [S]


@pytree_dataclass
class BatchOutput:
    """What a compiled chunk returns, in the narrowest integer types that hold it.

    ``log`` is `AgentState.log` per seed (chances used per trial, negated if it failed;
    every trial takes ≥ 1 chance, so the sign is the outcome), ``policy`` the G7 policy.
    Narrow types make the device-to-host transfer, the largest cost after the compute
    on GPUs, 4–5× smaller; `unpack_output` restores `SeedResult` on the host.
    """

    log: jax.Array  # int8/16/32 [M, T]
    policy: jax.Array  # int8/16/32 [M, S]


def narrow_int(largest: int) -> np.dtype:
    """The smallest signed integer type holding −largest … largest."""
    for dtype in (np.int8, np.int16):
        if largest <= np.iinfo(dtype).max:
            return np.dtype(dtype)
    return np.dtype(np.int32)


def pack_output(env: Env, log: jax.Array, policy: jax.Array) -> BatchOutput:
    """A chunk's logs and policies in `narrow_int` types (exact: |log| ≤ C, policy < A)."""
    return BatchOutput(log.astype(narrow_int(env.n_chances)), policy.astype(narrow_int(env.n_actions)))


def empty_results(n: int, n_trials: int, n_states: int) -> SeedResult:
    """Host arrays for `n` seeds' results, filled chunk by chunk by `unpack_output`."""
    return SeedResult(success=np.empty((n, n_trials), bool), steps=np.empty((n, n_trials), np.int32),
                      policy=np.empty((n, n_states), np.int32))


def unpack_output(out: BatchOutput, into: SeedResult | None = None, start: int = 0) -> SeedResult:
    """Host side of `pack_output`: success bool, steps and policy int32 (numpy arrays).

    With `into`, rows ``start …`` of its arrays are written in place (no temporaries, no
    concatenation of chunks: at 10^6 seeds per chunk that host work decides how fast
    several GPUs can go) and `into` is returned.
    """
    log, policy = np.asarray(out.log), np.asarray(out.policy)
    if into is None:
        into = empty_results(*log.shape, policy.shape[1])
        start = 0
    rows = slice(start, start + log.shape[0])
    np.greater(log, 0, out=into.success[rows])
    np.abs(log, out=into.steps[rows])
    into.policy[rows] = policy
    return into


def seed_key(root_key: jax.Array, seed: jax.Array) -> jax.Array:
    """R1: the key of seed i is ``fold_in(root_key, i)``."""
    return jax.random.fold_in(root_key, seed)


def seed_words(key: jax.Array) -> jax.Array:
    """uint32 [2]: the raw words of a (threefry) seed key, fed to `step_uniform`."""
    return jax.random.key_data(key).reshape(-1)[:2].astype(jnp.uint32)


def _mix32(h: jax.Array) -> jax.Array:
    """A 32-bit avalanche mixer (the "lowbias32" constants of C. Wellons' hash search)."""
    h = h ^ (h >> 16)
    h = h * jnp.uint32(0x7FEB352D)
    h = h ^ (h >> 15)
    h = h * jnp.uint32(0x846CA68B)
    return h ^ (h >> 16)


def step_uniform(words: jax.Array, counter: jax.Array) -> jax.Array:
    """A uniform in [0, 1) from the seed's key words and a 32-bit counter (counter-based RNG).

    Three mixing rounds keyed by both words; the top 24 bits give the float, which is
    exact in float32 and float64 alike.
    """
    h = _mix32(jnp.asarray(counter).astype(jnp.uint32) ^ words[0])
    h = _mix32(h ^ words[1])
    h = _mix32(h + jnp.uint32(0x9E3779B9))
    return (h >> 8).astype(float) * (1.0 / (1 << 24))


def action_counter(trial, chance, n_chances: int):
    """The counter of the E1 uniform at (trial, chance); chance C is the start-cell draw."""
    return trial * (n_chances + 1) + chance


def start_index(words, trial, n_chances: int, n_starts: int) -> jax.Array:
    """G3: the start cell (index into the free non-goal cells) of trial `trial`, uniform."""
    u = step_uniform(words, action_counter(trial, n_chances, n_chances))
    return jnp.minimum((u * n_starts).astype(jnp.int32), n_starts - 1)


@pytree_dataclass
class TrialRandoms:
    """All random numbers one trial consumes (for tests and the literal reference)."""

    start_index: jax.Array  # int32 []
    action_uniforms: jax.Array  # float [C]


def trial_randoms(key: jax.Array, trial, n_chances: int, n_starts: int) -> TrialRandoms:
    """The random numbers of trial `trial` (0-based) of the seed with key `key`."""
    words = seed_words(key)
    chances = jnp.arange(n_chances)
    return TrialRandoms(
        start_index(words, trial, n_chances, n_starts),
        jax.vmap(lambda c: step_uniform(words, action_counter(trial, c, n_chances)))(chances),
    )


def take_chance(env: Env, cfg: RunConfig, agent: AgentState, env_state, u, hyper: Hyper, active):
    """Alg. 1 lines 4–14 for one chance, if `active`: E1 choice, move, (2)–(4), r̃ (E5), records.

    Returns (agent, step, state, action, r̃).
    """
    trial = jnp.minimum(agent.trial, cfg.trials - 1)
    s = env.observation(env_state)
    action, learns = select_action(cfg.agent, agent, s, u, hyper)
    step = env.step(env_state, action)
    s_next = env.observation(step.state)
    agent = learn_step(
        agent, s, action, step.reward, s_next, step.terminated, learns & active,
        rate_at(cfg.alpha, hyper.alpha, trial), rate_at(cfg.beta, hyper.beta, trial), hyper.gamma,
    )
    goal_known = agent.goal_known | (active & step.terminated)  # E5: this step included
    rtilde = env.shaped_reward(s_next, step.bumped, goal_known)
    agent = record_step(cfg.agent, agent.replace(goal_known=goal_known), s, action, rtilde, active)
    return agent, step, s, action, rtilde


# --- the `trials` loop: literal Algorithm 1 structure -----------------------------------------


@pytree_dataclass
class _ChanceCarry:
    env_state: Any
    agent: AgentState
    done: jax.Array


def run_trial(env: Env, cfg: RunConfig, agent: AgentState, hyper: Hyper, words):
    """Algorithm 1 lines 3–29 for trial `agent.trial`: C chances (masked once done), then E4/E6."""
    trial = agent.trial
    n_chances = env.n_chances

    def chance(carry: _ChanceCarry, c):
        live = ~carry.done
        u = step_uniform(words, action_counter(trial, c, n_chances))
        agent, step, s, action, rtilde = take_chance(env, cfg, carry.agent, carry.env_state, u, hyper, live)
        env_state = jax.tree.map(lambda new, old: jnp.where(live, new, old), step.state, carry.env_state)
        done = carry.done | step.terminated | step.truncated
        return _ChanceCarry(env_state, agent, done), (s, action, rtilde, live, live & step.terminated)

    start = env.reset_at(start_index(words, trial, n_chances, env.n_starts))
    end, (states, actions, rtilde, live, reached) = jax.lax.scan(
        chance, _ChanceCarry(start, agent, jnp.bool_(False)), jnp.arange(n_chances)
    )
    record = TrialRecord(states, actions, rtilde, live.sum(dtype=jnp.int32), reached.any())
    agent = end_trial(cfg.agent, end.agent, record.success, jnp.bool_(True))
    return agent, record


def trace_run(env: Env, cfg: RunConfig, key: jax.Array, hyper: Hyper) -> tuple[AgentState, TrialRecord]:
    """One seed's run with the `trials` loop, keeping the final agent and every trial's record."""
    agent = init_agent(cfg.agent, env.n_states, env.n_actions, env.n_chances, cfg.trials)
    words = seed_words(key)
    return jax.lax.scan(lambda a, _: run_trial(env, cfg, a, hyper, words), agent, None, length=cfg.trials)


def make_run(env: Env, cfg: RunConfig) -> Callable[[jax.Array, Hyper], SeedResult]:
    """Build ``run(seed_key, hyper) -> SeedResult`` for one seed (the `trials` loop)."""

    def run(key: jax.Array, hyper: Hyper) -> SeedResult:
        agent, records = trace_run(env, cfg, key, hyper)
        return SeedResult(records.success, records.length, greedy_policy(cfg.agent, agent))

    return run


# --- the `flat` loop: one chance per iteration, trials back to back ----------------------------


@pytree_dataclass
class _FlatCarry:
    agent: AgentState
    env_state: Any


def _flat_init(env: Env, cfg: RunConfig, words) -> _FlatCarry:
    agent = init_agent(cfg.agent, env.n_states, env.n_actions, env.n_chances, cfg.trials)
    start = env.reset_at(start_index(words, 0, env.n_chances, env.n_starts))
    return _FlatCarry(agent, start)


def _flat_slot(env: Env, cfg: RunConfig, carry: _FlatCarry, words, hyper: Hyper) -> _FlatCarry:
    """One chance of one seed; a trial that ends here is closed and the next one started."""
    agent = carry.agent
    active = agent.trial < cfg.trials
    trial = jnp.minimum(agent.trial, cfg.trials - 1)
    u = step_uniform(words, action_counter(trial, agent.chance, env.n_chances))
    agent, step, _, _, _ = take_chance(env, cfg, agent, carry.env_state, u, hyper, active)
    ends = active & (step.terminated | step.truncated)
    agent = end_trial(cfg.agent, agent, step.terminated, ends)
    nxt = jnp.minimum(agent.trial, cfg.trials - 1)
    start = env.reset_at(start_index(words, nxt, env.n_chances, env.n_starts))
    env_state = jax.tree.map(
        lambda fresh, moved, old: jnp.where(ends, fresh, jnp.where(active, moved, old)),
        start, step.state, carry.env_state,
    )
    return _FlatCarry(agent, env_state)


@pytree_dataclass
class _Lane:
    """One lane of the flat loop: the run of the seed it holds, and which entry that is."""

    run: _FlatCarry
    words: jax.Array  # uint32 [2]
    hyper: Hyper
    entry: jax.Array  # int32 [], index into the batch; ≥ M once the lane is idle


CPU_LANES = 256  # per core: the lanes' tables stay in the core's cache (BENCHMARKS.md)
ACCELERATOR_MEMORY_LANES = 1 << 18  # EAC on GPUs, XLA ops: a queue beats a lane per seed (BENCHMARKS.md)
KERNEL_MEMORY_LANES = 1 << 15  # EAC on GPUs, fused kernel: few lanes keep hot rows in cache (BENCHMARKS.md)


def default_lanes(agent: AgentConfig, n_entries: int, backend: str | None = None,
                  kernel: Literal["xla", "pallas"] = "xla") -> int:
    """Seeds in flight per device when `RunConfig.lanes` is None (measured in BENCHMARKS.md).

    CPU: 256 lanes fed from a queue. Accelerators: a lane per seed for the classic
    AC. With memories (EAC), trials end early and unevenly and a learned seed keeps
    to a few cells, so fewer lanes fed from a queue run faster: 2^18 with XLA ops
    (1.31x a lane per seed at 4M seeds on one H100) and 2^15 with the fused kernel
    (1.9x its 2^18).
    """
    backend = backend or jax.default_backend()
    if backend == "cpu":
        return CPU_LANES
    if agent.uses_memory:
        return min(n_entries, KERNEL_MEMORY_LANES if kernel == "pallas" else ACCELERATOR_MEMORY_LANES)
    return n_entries


def _flat_batch(env: Env, cfg: RunConfig, words, hyper: Hyper) -> BatchOutput:
    """All entries of a chunk (``words`` [M, 2], ``hyper`` leaves [M]) on min(M, lanes) lanes.

    Lanes advance one chance per iteration. With a lane per entry, blocks of C
    iterations run until every seed has run T trials and results are read out once.
    With fewer lanes, every C iterations lanes whose seed has run T trials (up to
    `harvest` of them) write its result and take the next waiting seed, so lanes stay
    busy until the queue is empty (a seed's result does not depend on its lane, R1).
    """
    m = words.shape[0]
    kernel = resolved_kernel(env, cfg)
    lanes = cfg.lanes if cfg.lanes is not None else default_lanes(cfg.agent, m, kernel=kernel)
    n_lanes = min(m, lanes)
    slot = jax.vmap(lambda c, w, h: _flat_slot(env, cfg, c, w, h))
    if kernel == "pallas":
        from jaxeac.running.kernel import LANES_PER_PROGRAM, advance_chances

        n_lanes = -(-n_lanes // LANES_PER_PROGRAM) * LANES_PER_PROGRAM  # whole programs; extra lanes idle
        interpret = jax.default_backend() != "gpu"

        def advance(run: _FlatCarry, w, h) -> _FlatCarry:  # C chances of every lane, one kernel
            return advance_chances(env, cfg, run, w, h, interpret=interpret)
    else:
        def advance(run: _FlatCarry, w, h) -> _FlatCarry:  # C chances of every lane, XLA ops
            return jax.lax.fori_loop(0, env.n_chances, lambda _, x: slot(x, w, h), run)
    policies = jax.vmap(lambda a: greedy_policy(cfg.agent, a))

    def start(entry) -> _Lane:  # a lane for `entry`; entries ≥ M give an idle lane
        i = jnp.minimum(entry, m - 1)
        w, h = words[i], jax.tree.map(lambda x: x[i], hyper)
        return _Lane(_flat_init(env, cfg, w), w, h, entry)

    if n_lanes >= m:  # every entry has a lane from the start: no queue, read results out once
        pad = jnp.minimum(jnp.arange(n_lanes), m - 1)  # lanes past M rerun the last entry, dropped
        lane_words, lane_hyper = words[pad], jax.tree.map(lambda x: x[pad], hyper)

        def unfinished(run: _FlatCarry):
            return (run.agent.trial < cfg.trials).any()

        def chances(run: _FlatCarry):
            return advance(run, lane_words, lane_hyper)

        first = jax.vmap(lambda w: _flat_init(env, cfg, w))(lane_words)
        agent = jax.lax.while_loop(unfinished, chances, first).agent
        return pack_output(env, agent.log[:m], policies(agent)[:m])

    lanes = jax.vmap(start)(jnp.arange(n_lanes))
    out = pack_output(env, jnp.zeros((m, cfg.trials), jnp.int32), jnp.zeros((m, env.n_states), jnp.int32))

    # Lanes harvested per block: a bounded number, so per-block work (the finished lanes'
    # greedy policies, fresh lanes) stays small next to the block's C chances.
    harvest = max(1, n_lanes // 8)

    def block(carry):
        lanes, out, queued = carry
        run = advance(lanes.run, lanes.words, lanes.hyper)
        done = (run.agent.trial >= cfg.trials) & (lanes.entry < m)
        (idx,) = jnp.nonzero(done, size=harvest, fill_value=n_lanes)  # the first finished lanes
        got = idx < n_lanes
        lane = jnp.minimum(idx, n_lanes - 1)
        finished = jax.tree.map(lambda x: x[lane], run)
        row = jnp.where(got, lanes.entry[lane], m)  # rows ≥ M are dropped
        done_out = pack_output(env, finished.agent.log, policies(finished.agent))
        out = jax.tree.map(lambda a, new: a.at[row].set(new, mode="drop"), out, done_out)
        nxt = queued + jnp.arange(harvest)  # the next waiting entries, in lane order
        take = got & (nxt < m)
        fresh = jax.vmap(start)(nxt)  # hand waiting entries to the harvested lanes
        target = jnp.where(take, idx, n_lanes)
        lanes = jax.tree.map(lambda a, f: a.at[target].set(f, mode="drop"), lanes.replace(run=run), fresh)
        idle = jnp.where(got & ~take, idx, n_lanes)
        lanes = lanes.replace(entry=lanes.entry.at[idle].set(m, mode="drop"))
        return lanes, out, queued + take.sum(dtype=jnp.int32)

    _, out, _ = jax.lax.while_loop(lambda c: (c[0].entry < m).any(), block, (lanes, out, jnp.int32(n_lanes)))
    return out


def _trials_batch(env: Env, cfg: RunConfig, keys, hyper: Hyper) -> BatchOutput:
    r = jax.vmap(make_run(env, cfg))(keys, hyper)
    return pack_output(env, jnp.where(r.success, r.steps, -r.steps), r.policy)


SEEDS_AXIS = "seeds"


def seed_mesh(devices: Sequence[jax.Device] | None = None) -> Mesh:
    """A 1-D device mesh whose only axis, ``seeds``, the seed batch is split over."""
    return Mesh(np.array(list(devices) if devices is not None else jax.devices()), (SEEDS_AXIS,))


def make_batch_run(env: Env, cfg: RunConfig, mesh: Mesh | None = None) -> Callable:
    """jit over a chunk: ``(root_key, seeds [M], hyper with leaves [M]) -> BatchOutput [M, ...]``.

    With a `mesh`, the chunk is split over its ``seeds`` axis with `shard_map`: each
    device runs its own seeds with no communication (seeds are independent, R1).
    """
    loop = cfg.resolved_loop

    def batch(root_key: jax.Array, seeds: jax.Array, hyper: Hyper) -> BatchOutput:
        keys = jax.vmap(seed_key, in_axes=(None, 0))(root_key, seeds)
        if loop == "trials":
            return _trials_batch(env, cfg, keys, hyper)
        return _flat_batch(env, cfg, jax.vmap(seed_words)(keys), hyper)

    if mesh is not None:
        split = PartitionSpec(SEEDS_AXIS)
        batch = jax.shard_map(batch, mesh=mesh, in_specs=(PartitionSpec(), split, split), out_specs=split,
                              check_vma=False)  # per-seed loops: no collectives to check
    return jax.jit(batch)


@dataclasses.dataclass
class SeedsResult:
    """Results of all seeds of one algorithm, as numpy arrays on the host."""

    seeds: np.ndarray  # int64 [N]
    success: np.ndarray  # bool [N, T]
    steps: np.ndarray  # int32 [N, T]
    policy: np.ndarray  # int32 [N, S]
    compile_seconds: float
    run_seconds: float

    @property
    def successes(self) -> np.ndarray:
        return self.success.sum(axis=1)

    @property
    def first_success(self) -> np.ndarray:
        """1-based trial of the first success, −1 if none (G7)."""
        any_success = self.success.any(axis=1)
        return np.where(any_success, self.success.argmax(axis=1) + 1, -1)

    @property
    def agent_steps(self) -> int:
        return int(self.steps.sum())


def chunks(n_seeds: int, chunk_size: int) -> Iterator[np.ndarray]:
    """Seed indices 0..N−1 in chunks of `chunk_size` (the last one may be short)."""
    for start in range(0, n_seeds, chunk_size):
        yield np.arange(start, min(start + chunk_size, n_seeds), dtype=np.int32)


_COMPILED: dict = {}


def _compiled(env: Env, cfg: RunConfig, devices: tuple, root, seeds, hyper):
    """The compiled chunk program for this env object, config, devices and chunk shape (cached)."""
    key = (env, cfg, devices, seeds.shape, jax.tree.map(lambda x: x.dtype, hyper))
    if key not in _COMPILED:
        if len(_COMPILED) >= 64:
            _COMPILED.clear()
        mesh = seed_mesh(devices) if len(devices) > 1 else None
        _COMPILED[key] = make_batch_run(env, cfg, mesh).lower(root, seeds, hyper).compile()
    return _COMPILED[key]


UNPACK_ROWS = 1 << 15  # rows per host thread when unpacking a chunk's results


def run_entries(
    env: Env,
    cfg: RunConfig,
    *,
    root_key: int,
    seeds: np.ndarray,
    hyper: Hyper,
    chunk_size: int = 1024,
    devices: Sequence[jax.Device] | None = None,
    progress: Callable[[int], None] | None = None,
) -> tuple[SeedResult, float, float]:
    """Run entries (seed i, hyper i) in fixed-size chunks: one compile, bounded memory.

    `hyper` leaves have one value per entry, so a hyperparameter sweep shares one
    compiled program. Chunks are split over `devices` (all local devices by default);
    the chunk size is rounded up to a multiple of their number, and the last chunk is
    padded with copies of its final entry whose results are dropped. Returns
    (results as numpy, compile seconds, run seconds).
    """
    n = int(seeds.size)
    if n < 1:
        raise UsageError(f"seeds must be a positive integer (got {n})")
    if chunk_size < 1:
        raise UsageError(f"chunk size must be a positive integer (got {chunk_size})")
    devices = list(devices) if devices is not None else jax.local_devices()
    n_dev = len(devices)
    n_chunks = -(-n // chunk_size)
    chunk_size = -(-n // n_chunks)  # split evenly: no chunk is mostly padding
    chunk_size = -(-chunk_size // n_dev) * n_dev
    root = jax.random.key(root_key)
    hyper = jax.tree.map(lambda x: np.broadcast_to(np.asarray(x), (n,)), hyper)

    def chunk_inputs(start: int):
        stop = min(start + chunk_size, n)
        take = np.pad(np.arange(start, stop), (0, chunk_size - (stop - start)), mode="edge")
        return stop - start, seeds[take].astype(np.int32), jax.tree.map(lambda x: x[take], hyper)

    t0 = time.perf_counter()
    _, seeds0, hyper0 = chunk_inputs(0)
    compiled = _compiled(env, cfg, tuple(devices), root, seeds0, hyper0)
    compile_seconds = time.perf_counter() - t0

    whole = empty_results(n, cfg.trials, env.n_states)

    def dispatch(start: int) -> tuple[int, int, BatchOutput]:
        size, chunk_seeds, chunk_hyper = chunk_inputs(start)
        out = compiled(root, chunk_seeds, chunk_hyper)
        for leaf in jax.tree.leaves(out):
            leaf.copy_to_host_async()  # the copy back starts as soon as the chunk is done
        return start, size, out

    def collect(start: int, size: int, out: BatchOutput, pool: ThreadPoolExecutor) -> None:
        host = jax.device_get(out)

        def unpack_rows(r: int) -> None:  # on a host thread (numpy frees the GIL)
            stop = min(r + UNPACK_ROWS, size)  # padding rows past `size` are dropped
            unpack_output(jax.tree.map(lambda x: x[r:stop], host), whole, start + r)

        list(pool.map(unpack_rows, range(0, size, UNPACK_ROWS)))
        if progress is not None:
            progress(size)

    t0 = time.perf_counter()
    with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        pending = None  # the chunk in flight: dispatch is asynchronous, so the next chunk
        for start in range(0, n, chunk_size):  # computes while this one's results come back
            running = dispatch(start)
            if pending is not None:
                collect(*pending, pool)
            pending = running
        collect(*pending, pool)
    run_seconds = time.perf_counter() - t0
    return whole, compile_seconds, run_seconds


def run_seeds(
    env: Env,
    cfg: RunConfig,
    *,
    root_key: int,
    n_seeds: int,
    first_seed: int = 0,
    chunk_size: int = 1024,
    hyper: Hyper | None = None,
    devices: Sequence[jax.Device] | None = None,
    progress: Callable[[int], None] | None = None,
) -> SeedsResult:
    """Run seeds first_seed … first_seed+N−1 of one algorithm (see `run_entries`)."""
    if isinstance(n_seeds, bool) or not isinstance(n_seeds, int | np.integer) or n_seeds < 1:
        raise UsageError(f"seeds must be a positive integer (got {n_seeds})")
    seeds = np.arange(first_seed, first_seed + n_seeds, dtype=np.int64)
    out, compile_seconds, run_seconds = run_entries(
        env, cfg, root_key=root_key, seeds=seeds, hyper=cfg.hyper() if hyper is None else hyper,
        chunk_size=chunk_size, devices=devices, progress=progress,
    )
    return SeedsResult(
        seeds=seeds,
        success=out.success,
        steps=out.steps,
        policy=out.policy,
        compile_seconds=compile_seconds,
        run_seconds=run_seconds,
    )
