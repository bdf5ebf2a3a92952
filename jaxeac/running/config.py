"""A run's configuration and the one place where every `auto` setting is decided.

`RunConfig` holds what defines one algorithm's run: static structure (trials, the
agent's `AgentConfig`, loop, kernel, lanes) and rates (constants, traced as `Hyper`,
or optax schedules). `RunConfig.resolve` fixes every `auto` choice — table layout,
loop, kernel, lanes per device — for a backend and a chunk size, once, before
tracing; the traced code only reads resolved values, and a run records them.
"""

from __future__ import annotations

import dataclasses
import warnings
from typing import Any, Literal

import jax
import jax.numpy as jnp

from jaxeac.algorithm import memory as mem
from jaxeac.algorithm.config import AgentConfig, Hyper, Rate
from jaxeac.envs.protocol import chance_bound
from jaxeac.errors import UsageError, check_int, check_number, is_plain_number
from jaxeac.running.carry import state_bytes_per_seed, visit_words_fit

Loop = Literal["auto", "flat", "trials"]
LOOPS = ("auto", "flat", "trials")
Kernel = Literal["auto", "xla", "pallas"]
KERNELS = ("auto", "xla", "pallas")
Jump = Literal["auto", "on", "off"]
JUMPS = ("auto", "on", "off")

CPU_CHUNK = 1 << 14  # seeds per chunk on CPUs: progress every few seconds, small outputs in flight
GPU_CHUNK_PER_DEVICE = 1 << 20  # seeds per chunk and GPU: saturates one H100 (BENCHMARKS.md)
CPU_LANES = 256  # per core: the lanes' tables stay in the core's cache (BENCHMARKS.md)
ACCELERATOR_MEMORY_LANES = 1 << 18  # EAC on GPUs, XLA ops: a queue beats a lane per seed (BENCHMARKS.md)
KERNEL_MEMORY_LANES = 1 << 15  # EAC on GPUs, fused kernel: few lanes keep hot rows in cache (BENCHMARKS.md)


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """One algorithm's run: trial count, step sizes (constant or optax schedule), agent, loop."""

    trials: int
    agent: AgentConfig
    alpha: Rate = 0.1
    beta: Rate = 0.3
    gamma: float = 0.9
    temperature: float = 1.0
    epsilon: float = 0.1  # X3: exploration rate of the value-based baselines (unused by AC/EAC)
    loop: Loop = "auto"
    lanes: int | None = None  # flat loop: seeds in flight per device; None: `default_lanes`
    kernel: Kernel = "auto"  # flat loop's chances: the fused kernel (GPUs) or XLA ops; `resolved_kernel`
    jump: Jump = "auto"  # flat loop: end a trial at once where it follows its success memory; `resolved_jump`

    def __post_init__(self):
        """Every field checked at construction: TypeError for a wrong type, ValueError (`UsageError`)
        for a bad value, naming the field, the value and the fix."""
        check_int("trials", self.trials, fix="pass the number of trials per seed, e.g. trials=200")
        if not isinstance(self.agent, AgentConfig):
            raise TypeError(f"agent must be an AgentConfig, e.g. algorithm('eac') (got {self.agent!r})")
        for name in ("alpha", "beta"):  # a constant or an optax schedule over the trial index
            _check_rate(name, getattr(self, name), schedule=True)
        _check_rate("gamma", self.gamma, high=1.0)
        _check_rate("temperature", self.temperature, positive=True)
        _check_rate("epsilon", self.epsilon, high=1.0)
        if self.lanes is not None:
            check_int("lanes", self.lanes, fix="pass seeds in flight per device, or None for the default")
        for name, choices in (("loop", LOOPS), ("kernel", KERNELS), ("jump", JUMPS)):
            if not isinstance(getattr(self, name), str):
                raise TypeError(f"{name} must be a string, one of {choices} (got {getattr(self, name)!r})")
        if self.jump not in JUMPS:
            raise UsageError(f"unknown jump setting {self.jump!r}; choose one of {JUMPS}")
        if self.kernel not in KERNELS:
            raise UsageError(f"unknown kernel {self.kernel!r}; choose one of {KERNELS}")
        if self.loop not in LOOPS:
            raise UsageError(f"unknown loop {self.loop!r}; choose one of {LOOPS}")

    def hyper(self) -> Hyper:
        """The traced constants (a scheduled rate's traced slot is unused)."""
        def const(x):
            return jnp.asarray(0.0 if callable(x) else x, dtype=float)

        return Hyper(const(self.alpha), const(self.beta), const(self.gamma), const(self.temperature),
                     const(self.epsilon))

    @property
    def resolved_loop(self) -> Literal["flat", "trials"]:
        """`auto`: flat unless the buffer layout needs trial-end writes."""
        if self.loop != "auto":
            return self.loop
        buffered = self.agent.uses_memory and self.agent.memory == "buffer"
        return "trials" if buffered else "flat"

    @property
    def is_resolved(self) -> bool:
        return (self.agent.tables != "auto" and self.loop != "auto" and self.kernel != "auto"
                and self.jump != "auto")

    def resolve(self, env: Any = None, n_entries: int | None = None, backend: str | None = None) -> RunConfig:
        """Every `auto` decided for `backend` (default: JAX's): tables, loop, kernel, and lanes for a
        chunk of `n_entries` seeds (lanes stay None without it). Idempotent."""
        backend = backend or jax.default_backend()
        cfg = dataclasses.replace(self, agent=self.agent.resolve(backend), loop=self.resolved_loop)
        cfg = dataclasses.replace(cfg, kernel=resolved_kernel(env, cfg, backend))
        cfg = dataclasses.replace(cfg, jump=resolved_jump(env, cfg))
        if cfg.lanes is None and n_entries is not None and cfg.loop == "flat":
            cfg = dataclasses.replace(cfg, lanes=default_lanes(cfg.agent, n_entries, backend, cfg.kernel))
        return cfg

    def describe(self) -> dict:
        """The settings as plain values (for summary.json): schedules by name."""
        def rate(x):
            return x if not callable(x) else getattr(x, "__name__", "schedule")

        out = {"trials": self.trials, "agent": dataclasses.asdict(self.agent), "alpha": rate(self.alpha),
               "beta": rate(self.beta), "gamma": self.gamma, "temperature": self.temperature,
               "loop": self.loop, "lanes": self.lanes, "kernel": self.kernel, "jump": self.jump}
        if self.agent.learner != "actor_critic":
            out["epsilon"] = self.epsilon
        return out


def _check_rate(name: str, value, *, schedule: bool = False, high: float | None = None,
                positive: bool = False) -> None:
    """A rate of `RunConfig`: a plain Python/NumPy number is checked (finite, in range, float32's
    normal range); a JAX value (traced under jit/vmap, as in a `Hyper` sweep) is left to the caller;
    for `schedule` rates (alpha, beta), any callable (an optax schedule over the trial index)."""
    if schedule and callable(value):
        return
    if isinstance(value, jax.Array):  # traced or on a device: not checked here
        return
    if not is_plain_number(value):
        kinds = "a number or an optax schedule (a callable of the trial index)" if schedule else "a number"
        raise TypeError(f"{name} must be {kinds} (got {value!r} of type {type(value).__name__})")
    fix = {"alpha": "the critic's step size, e.g. 0.1", "beta": "the actor's step size, e.g. 0.3",
           "gamma": "the discount, e.g. 0.9", "temperature": "the softmax temperature, e.g. 1.0",
           "epsilon": "the baselines' exploration rate, e.g. 0.1"}[name]
    check_number(name, value, high=high, positive=positive, fix=f"pass {fix}")


def kernel_unsupported(env: Any, cfg: RunConfig) -> str | None:
    """Why the fused kernel (`jaxeac.running.kernel`) cannot run this env and (table-resolved)
    config (None: it can). The env says whether it can (`kernel_tables()`, `jaxeac.envs.protocol`):
    the grid world and the tabular tasks can."""
    agent = cfg.agent
    kernel_tables = getattr(env, "kernel_tables", None)
    if kernel_tables is None or kernel_tables() is None:
        return ("the fused kernel runs the grid world and the tabular tasks only "
                "(environments whose kernel_tables() gives their tables)")
    if agent.tables != "rows":
        return "the fused kernel needs the rows table layout (tables='rows')"
    if agent.uses_memory and not (agent.memory == "dense"
                                   and mem.packed_fits(env.n_actions, cfg.trials)):
        return "the fused kernel needs the packed dense memory (A <= 5 actions and a bounded trial count)"
    if callable(cfg.alpha) or callable(cfg.beta):
        return "the fused kernel needs constant step sizes (not schedules)"
    return None


def resolved_kernel(env: Any, cfg: RunConfig, backend: str | None = None) -> Literal["xla", "pallas"]:
    """How the flat loop runs its chances: ``pallas`` (the fused kernel of `jaxeac.running.kernel`)
    or ``xla``. `auto`: the kernel on GPUs where it supports the env and config, XLA ops
    otherwise. ``pallas`` asks for the kernel anywhere; off GPUs it runs in Pallas's (slow)
    interpreter.

    The kernel is written for Pallas's Triton backend, which JAX deprecated in 0.11: where that
    backend cannot be imported, or (GPUs) cannot lower the kernel, `auto` runs XLA ops and warns
    once per process (a `RuntimeWarning` naming why), and ``pallas`` is a `UsageError` naming why
    and the fix, ``kernel='xla'``. Per-seed results are the same either way (XLA ops are the
    reference)."""
    if cfg.kernel == "xla":
        return "xla"
    backend = backend or jax.default_backend()
    why = kernel_unsupported(env, dataclasses.replace(cfg, agent=cfg.agent.resolve(backend)))
    if cfg.resolved_loop != "flat":
        why = "the fused kernel runs the flat loop (the buffer memory needs the trials loop)"
    if cfg.kernel == "pallas":
        if why is not None:
            raise UsageError(f"{why}; use kernel='xla' (or 'auto')")
        problem = _backend_problem(env, cfg, backend)
        if problem is not None:
            raise UsageError(f"kernel='pallas' cannot run: {problem}; use kernel='xla' (the same per-seed "
                             "results as XLA ops) or 'auto'")
        return "pallas"
    if why is not None or backend != "gpu":
        return "xla"
    problem = _backend_problem(env, cfg, backend)
    if problem is not None:
        global _fallback_warned
        if not _fallback_warned:  # once per process, whatever the number of chunks and configs
            _fallback_warned = True
            warnings.warn(f"kernel='auto' runs XLA ops instead of the fused GPU kernel (the same per-seed "
                          f"results, slower): {problem}. Pass kernel='xla' to choose XLA ops without this "
                          "warning.", RuntimeWarning, stacklevel=2)
        return "xla"
    return "pallas"


_fallback_warned = False  # `resolved_kernel` warned that `auto` fell back to XLA ops


def _backend_problem(env: Any, cfg: RunConfig, backend: str) -> str | None:
    """`jaxeac.running.kernel.backend_problem` for the run's config: the kernel with its jump setting,
    lowered where it would run on GPUs (in the interpreter off GPUs, it needs the backend's module only)."""
    from jaxeac.running.kernel import backend_problem

    return backend_problem(env, _kernel_config(env, cfg, backend), lower=backend == "gpu")


def _kernel_config(env: Any, cfg: RunConfig, backend: str) -> RunConfig:
    """The run's config as the fused kernel would run it on `backend`, with its jump setting."""
    run = dataclasses.replace(cfg, agent=cfg.agent.resolve(backend), loop="flat", kernel="pallas", lanes=None)
    return dataclasses.replace(run, jump=resolved_jump(env, run))


def jump_unsupported(env: Any, cfg: RunConfig) -> str | None:
    """Why a (loop- and kernel-resolved) config cannot end trials by memory jumps (None: it can).

    A jump needs what makes it exact: a deterministic environment, a success memory that
    chooses (E1 a) without learning (E2), and the flat loop (XLA ops or the fused kernel)."""
    gated = getattr(getattr(env, "layout", None), "gated_jumps", False)  # per task (`TableLayout`)
    if not (getattr(env, "deterministic", False) or gated):
        return "memory jumps need a deterministic environment"
    if not cfg.agent.success_memory:
        return "memory jumps follow the success memory, which this algorithm does not keep"
    if cfg.agent.learn_on_memory_steps:
        return "memory jumps skip steps that learn under learn_on_memory_steps"
    if cfg.loop != "flat":
        return "memory jumps run in the flat loop (the trials loop takes every step)"
    if not visit_words_fit(cfg.trials, chance_bound(env)):
        return "memory jumps store (trial, chance) in one int32, too small for this many trials and chances"
    return None


def resolved_jump(env: Any, cfg: RunConfig) -> Literal["on", "off"]:
    """``on``: a trial that stands on a state whose success-memory path to the goal has a
    known length ends at once (`jaxeac.running.loops`); same per-seed results as ``off``,
    which takes every step. `auto`: on wherever `jump_unsupported` allows."""
    if cfg.jump == "off":
        return "off"
    why = jump_unsupported(env, cfg)
    if cfg.jump == "on" and why is not None:
        raise UsageError(f"{why}; use jump='off' (or 'auto')")
    return "on" if why is None else "off"


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


def auto_chunk_size(env: Any, cfg: RunConfig, n_entries: int, devices) -> int:
    """Seeds per chunk when none is given: `CPU_CHUNK` on CPUs; on accelerators
    `GPU_CHUNK_PER_DEVICE` per device, fewer where the run's state would not fit in half the
    device's free memory. Results do not depend on it (R1)."""
    devices = list(devices)
    if devices[0].platform == "cpu":
        return max(1, min(n_entries, CPU_CHUNK))
    per_device = GPU_CHUNK_PER_DEVICE
    stats = devices[0].memory_stats() or {}
    free = stats.get("bytes_limit", 0) - stats.get("bytes_in_use", 0)
    if free > 0:
        resolved = cfg.resolve(env, per_device, devices[0].platform)
        lanes = resolved.lanes or per_device
        state = state_bytes_per_seed(env, resolved)
        out_bytes = cfg.trials + env.n_states * 4  # log and policy, at most 1 + 4 bytes each
        need = lambda m: min(m, lanes) * state + m * out_bytes  # noqa: E731
        while per_device > 1024 and need(per_device) > free // 2:
            per_device //= 2
    return max(1, min(n_entries, per_device * len(devices)))
