"""One seed's whole run as a single `lax.scan` over trials; many seeds via vmap, in chunks.

`make_run(env, cfg)` returns ``run(seed_key, hyper) -> SeedResult`` (purejaxrl
style). Seed i of a run uses ``fold_in(root_key, i)`` (SPEC R1), so its result
never depends on the seeds beside it, the chunk size or the device count, and
the same root key and config give bit-identical results (R2).

Randomness per trial comes from one place, `trial_randoms`: a start-cell key
and the C action uniforms of the trial, drawn at once (no per-step key splits).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterator
from typing import Any, Protocol

import jax
import jax.numpy as jnp
import numpy as np

from jaxeac.agent import (
    AgentConfig,
    AgentState,
    Hyper,
    Rate,
    end_trial,
    greedy_policy,
    init_agent,
    learn_step,
    rate_at,
    select_action,
)
from jaxeac.errors import UsageError
from jaxeac.pytree import pytree_dataclass


class Env(Protocol):
    """What the runner needs from an environment (the grid world satisfies it)."""

    n_states: int
    n_actions: int
    n_chances: int

    def reset(self, key: jax.Array) -> Any: ...
    def observation(self, state: Any) -> jax.Array: ...
    def step(self, state: Any, action: jax.Array) -> Any: ...
    def shaped_reward(self, s_next, bumped, goal_known) -> jax.Array: ...


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """One algorithm's run: trial count, step sizes (constant or optax schedule), agent."""

    trials: int
    agent: AgentConfig
    alpha: Rate = 0.1
    beta: Rate = 0.3
    gamma: float = 0.9
    temperature: float = 1.0

    def hyper(self) -> Hyper:
        """The traced constants (a scheduled rate's traced slot is unused)."""
        def const(x):
            return jnp.asarray(0.0 if callable(x) else x, dtype=float)

        return Hyper(const(self.alpha), const(self.beta), const(self.gamma), const(self.temperature))


@pytree_dataclass
class TrialRandoms:
    """All random numbers one trial consumes."""

    reset_key: jax.Array  # key for the G3 start cell
    action_uniforms: jax.Array  # float32 [C], one per chance, for E1 sampling


@pytree_dataclass
class TrialRecord:
    """What one trial leaves behind (per chance: state, action, r̃; and totals)."""

    states: jax.Array  # int32 [C]
    actions: jax.Array  # int32 [C]
    rtilde: jax.Array  # float32 [C]
    length: jax.Array  # int32 [], chances actually used
    success: jax.Array  # bool []


@pytree_dataclass
class SeedResult:
    """G7 per-seed record: success and steps per trial, and the final greedy policy."""

    success: jax.Array  # bool [T]
    steps: jax.Array  # int32 [T]
    policy: jax.Array  # int32 [S]


def seed_key(root_key: jax.Array, seed: jax.Array) -> jax.Array:
    """R1: the key of seed i is ``fold_in(root_key, i)``."""
    return jax.random.fold_in(root_key, seed)


def trial_randoms(key: jax.Array, trial: jax.Array, n_chances: int) -> TrialRandoms:
    """The random numbers of trial `trial` (0-based) of the seed with key `key`."""
    reset_key, action_key = jax.random.split(jax.random.fold_in(key, trial))
    return TrialRandoms(reset_key, jax.random.uniform(action_key, (n_chances,)))


@pytree_dataclass
class _ChanceCarry:
    env_state: Any
    agent: AgentState
    done: jax.Array


def run_trial(env: Env, cfg: RunConfig, agent: AgentState, hyper: Hyper, randoms: TrialRandoms, trial):
    """Algorithm 1 lines 3–29 for one trial: C chances (masked once done), then memory writes."""
    alpha = rate_at(cfg.alpha, hyper.alpha, trial)
    beta = rate_at(cfg.beta, hyper.beta, trial)

    def chance(carry: _ChanceCarry, u):
        s = env.observation(carry.env_state)
        action, learns = select_action(cfg.agent, carry.agent, s, u, hyper)
        step = env.step(carry.env_state, action)
        live = ~carry.done
        s_next = env.observation(step.state)
        agent = learn_step(
            carry.agent, s, action, step.reward, s_next, step.terminated, learns & live,
            alpha, beta, hyper.gamma,
        )
        goal_known = agent.goal_known | (live & step.terminated)  # E5: this step included
        rtilde = env.shaped_reward(s_next, step.bumped, goal_known)
        env_state = jax.tree.map(lambda new, old: jnp.where(live, new, old), step.state, carry.env_state)
        done = carry.done | step.terminated | step.truncated
        out = (s, action, rtilde, live, live & step.terminated)
        return _ChanceCarry(env_state, agent.replace(goal_known=goal_known), done), out

    start = _ChanceCarry(env.reset(randoms.reset_key), agent, jnp.bool_(False))
    end, (states, actions, rtilde, live, reached) = jax.lax.scan(chance, start, randoms.action_uniforms)
    record = TrialRecord(states, actions, rtilde, live.sum(dtype=jnp.int32), reached.any())
    agent = end_trial(cfg.agent, end.agent, states, actions, rtilde, record.length, record.success)
    return agent, record


def trace_run(env: Env, cfg: RunConfig, key: jax.Array, hyper: Hyper) -> tuple[AgentState, TrialRecord]:
    """One seed's run, keeping everything: the final agent and every trial's record [T, ...]."""
    agent = init_agent(cfg.agent, env.n_states, env.n_actions, env.n_chances)

    def trial_step(agent: AgentState, trial):
        randoms = trial_randoms(key, trial, env.n_chances)
        return run_trial(env, cfg, agent, hyper, randoms, trial)

    return jax.lax.scan(trial_step, agent, jnp.arange(cfg.trials))


def make_run(env: Env, cfg: RunConfig) -> Callable[[jax.Array, Hyper], SeedResult]:
    """Build ``run(seed_key, hyper) -> SeedResult``: one `lax.scan` over T trials."""

    def run(key: jax.Array, hyper: Hyper) -> SeedResult:
        agent, records = trace_run(env, cfg, key, hyper)
        return SeedResult(records.success, records.length, greedy_policy(cfg.agent, agent))

    return run


def make_batch_run(env: Env, cfg: RunConfig) -> Callable:
    """jit(vmap(run)) over seed indices: ``(root_key, seeds [M], hyper) -> SeedResult [M, ...]``."""
    run = make_run(env, cfg)

    def batch(root_key: jax.Array, seeds: jax.Array, hyper: Hyper) -> SeedResult:
        keys = jax.vmap(seed_key, in_axes=(None, 0))(root_key, seeds)
        return jax.vmap(run, in_axes=(0, None))(keys, hyper)

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


def run_seeds(
    env: Env,
    cfg: RunConfig,
    *,
    root_key: int,
    n_seeds: int,
    chunk_size: int = 1024,
    hyper: Hyper | None = None,
    progress: Callable[[int], None] | None = None,
) -> SeedsResult:
    """Run seeds 0..N−1 of one algorithm in fixed-size chunks (one compile, bounded memory).

    The last chunk is padded with copies of its final seed so every chunk has the
    same shape; padded results are dropped. `progress(n)` is called after each
    chunk with the number of seeds it finished.
    """
    if n_seeds < 1:
        raise UsageError(f"seeds must be a positive integer (got {n_seeds})")
    if chunk_size < 1:
        raise UsageError(f"chunk size must be a positive integer (got {chunk_size})")
    chunk_size = min(chunk_size, n_seeds)
    hyper = cfg.hyper() if hyper is None else hyper
    batch = make_batch_run(env, cfg)
    root = jax.random.key(root_key)

    t0 = time.perf_counter()
    compiled = batch.lower(root, jnp.zeros((chunk_size,), jnp.int32), hyper).compile()
    compile_seconds = time.perf_counter() - t0

    parts: list[SeedResult] = []
    t0 = time.perf_counter()
    for seeds in chunks(n_seeds, chunk_size):
        padded = np.pad(seeds, (0, chunk_size - seeds.size), mode="edge")
        out = jax.device_get(compiled(root, padded, hyper))
        parts.append(jax.tree.map(lambda x, n=seeds.size: np.asarray(x)[:n], out))
        if progress is not None:
            progress(seeds.size)
    run_seconds = time.perf_counter() - t0
    cat = jax.tree.map(lambda *xs: np.concatenate(xs), *parts)
    return SeedsResult(
        seeds=np.arange(n_seeds, dtype=np.int64),
        success=cat.success.astype(bool),
        steps=cat.steps.astype(np.int32),
        policy=cat.policy.astype(np.int32),
        compile_seconds=compile_seconds,
        run_seconds=run_seconds,
    )
