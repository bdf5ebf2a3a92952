"""AC and EAC learning to bowl (paper §V-B, SPEC B1–B7) with the grid's agent code.

The agent is the same `jaxeac.algorithm.agent` code as on the grid (no copy): states are
the 1,024 masks of standing pins (B5; chance 1 always starts from all ten =
1023), actions the K shoulder angles (B2), the TD reward and the immediate
reward r̃ are the pins a throw knocks (E5), a trial is 2 chances, a strike ends
it early (E3) and it succeeds when all ten pins are down at its end (B5).
Pinned here: a trial's end is terminal for (3) (the frame is over, V(s') = 0).

Physics backends (B7):

* ``c`` — MuJoCo's C engine batched over threads: learning steps are jit-compiled
  and vmapped over seeds; the batched physics runs between them on the host.
* ``mjx`` and ``warp`` — the whole run (learning and physics) is one jit-compiled
  function; MJX steps the physics in JAX (``mjx``) or with its Warp implementation
  on NVIDIA GPUs (``warp``).

All consume the same random numbers: E1 uniforms from `step_uniform` and throw
noise from ``fold_in(fold_in(fold_in(root, seed), trial), chance)``.
SPEC ids (G1…, E1…, B1…, R1…) are defined in docs/SPEC.md.

(Over 400 lines: the bowling experiment end to end: settings, the compiled learning steps around
the physics, the trial rules and the outputs.)
"""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from jaxeac.algorithm.agent import AgentState, StepRoute, end_trial, init_agent
from jaxeac.algorithm.config import Hyper, algorithm
from jaxeac.envs.bowling import BowlingConfig, SolverSettings, initial_pins, throw, throw_noise
from jaxeac.envs.bowling import angles as angle_grid
from jaxeac.envs.bowling.scene import DEFAULT_SOLVER, MJX_IMPL, check_backend, check_scene
from jaxeac.errors import UsageError
from jaxeac.paper import BOWLING_PINS
from jaxeac.pytree import pytree_dataclass
from jaxeac.rng import seed_key, seed_words, throw_key
from jaxeac.running.batch import chunks
from jaxeac.running.config import RunConfig
from jaxeac.running.loops import choose as choose_action
from jaxeac.running.loops import learn_and_record

N_PINS = 10
N_MASKS = 1 << N_PINS  # B5: states are the sets of standing pins
FULL_RACK = N_MASKS - 1
CHANCES = 2  # B5


def mask_index(standing) -> jax.Array:
    """The state of a set of standing pins: bit i set ⇔ pin i+1 standing (B5)."""
    return (jnp.asarray(standing).astype(jnp.int32) << jnp.arange(N_PINS)).sum(-1)


STATES = ("mask", "tree")


@dataclasses.dataclass(frozen=True)
class TrialRules:
    """What a state is and when a trial succeeds (B5 and its named variants B5a, B5b).

    ``state="mask"`` (B5): the set of standing pins, 1,024 states. ``state="tree"`` (B5a, the
    paper's Fig. 5 tree): chance 1 is the root state 0, chance 2 is state 1 + k after angle k at
    chance 1, so chance-2 angles hang under the chance-1 angle, K + 1 states. ``success_pins``
    (B5b): a trial succeeds when it knocks at least this many pins (10, the default: all down).
    """

    state: str = "mask"
    success_pins: int = N_PINS

    def __post_init__(self) -> None:
        if self.state not in STATES:
            raise UsageError(f"unknown bowling state {self.state!r}: use one of {', '.join(STATES)}")
        if isinstance(self.success_pins, bool) or not isinstance(self.success_pins, int) \
                or not 1 <= self.success_pins <= N_PINS:
            raise UsageError(f"success pins {self.success_pins!r}: need an integer in [1, {N_PINS}] "
                             "(pins a trial must knock to succeed; 10 = all down)")

    def n_states(self, n_angles: int) -> int:
        return N_MASKS if self.state == "mask" else 1 + n_angles

    @property
    def first_state(self) -> int:
        """The state of chance 1: the full rack, or the tree's root."""
        return FULL_RACK if self.state == "mask" else 0

    def next_state(self, standing, action):
        """The state after a throw that left `standing` pins, having thrown angle `action`."""
        return mask_index(standing) if self.state == "mask" else 1 + jnp.asarray(action, jnp.int32)


PAPER_RULES = TrialRules()


@pytree_dataclass
class BowlingRecord:
    """Per seed: angle index [T, 2] (−1 = not thrown), pins per chance [T, 2], success [T], pins
    standing after each chance [T, 2] (10-bit masks as `mask_index`; −1 = not thrown)."""

    action: jax.Array
    knocked: jax.Array
    success: jax.Array
    standing: jax.Array
    diagnostics: BowlingDiagnostics | None = None  # E8, per seed


@pytree_dataclass
class BowlingDiagnostics:
    """E8 per seed: per chance, throws taken / chosen by E1(a) / restricted by E1(b) / learnt
    (int32 [2] each, summed over trials); E6 flags when the run ends, over every state and at
    the full rack (chance 1's state)."""

    routes: StepRoute
    flags: jax.Array  # int32 []
    rack_flags: jax.Array  # bool [K]


def choose(cfg: RunConfig, agent: AgentState, words, state, hyper: Hyper, active=True, diagnose: bool = False):
    """E1 at `state` with the uniform of (trial, chance) (`jaxeac.running.loops.choose`); with
    `diagnose`, the throw's `StepRoute` (E8) as a third value."""
    return choose_action(cfg, agent, state, words, hyper, CHANCES, jnp.asarray(active), diagnose)


def choose_throws(cfg: RunConfig, agents: AgentState, words, state, hyper: Hyper, active):
    """`choose` for every seed (agents, words, state, active [M]): (actions, learns, the throws'
    `StepRoute`s, E8), one computation for the throw and its count."""
    return jax.vmap(lambda a, w, s, act: choose(cfg, a, w, s, hyper, act, diagnose=True))(
        agents, words, state, active)


def throw_routes(cfg: RunConfig, agents: AgentState, words, state, hyper: Hyper, active) -> StepRoute:
    """E8: each seed's `StepRoute` of the throw `choose` picks (agents, words, state, active [M])."""
    return choose_throws(cfg, agents, words, state, hyper, active)[2]


def end_flags(cfg: RunConfig, agent: AgentState, n_angles: int,
              rules: TrialRules = PAPER_RULES) -> tuple[jax.Array, jax.Array]:
    """E8: (flags over every state, flags at chance 1's state — the full rack [K]) of one seed's
    failure memory."""
    from jaxeac.running.diagnostics import failure_pairs

    states, actions, held = failure_pairs(cfg.agent, agent, rules.n_states(n_angles), n_angles)
    rack = jnp.where(held & (states == rules.first_state), actions, n_angles)  # other pairs: dropped writes
    return held.sum(dtype=jnp.int32), jnp.zeros((n_angles,), bool).at[rack].set(True, mode="drop")


@functools.lru_cache(maxsize=8)
def _diagnostic_steps(cfg: RunConfig, n_angles: int, rules: TrialRules):
    """jit versions of `throw_routes` and `end_flags` (vmapped over seeds)."""
    return (jax.jit(functools.partial(throw_routes, cfg)),
            jax.jit(jax.vmap(functools.partial(end_flags, cfg, n_angles=n_angles, rules=rules))))


def learn_from_throw(cfg: RunConfig, agent: AgentState, state, action, learns, knocked, next_state,
                     cleared, success, last_chance, active, hyper: Hyper) -> AgentState:
    """(2)–(4) with r = pins knocked, E5 r̃ = pins knocked, and E4/E6 when the trial ends (all pins
    down or its last chance; a success by `TrialRules`) (`jaxeac.running.loops.learn_and_record`,
    then `end_trial`)."""
    reward = knocked.astype(agent.values.dtype)
    ends = active & (cleared | last_chance)
    agent = learn_and_record(cfg, agent, state, action, learns & active, reward, next_state, ends, reward,
                             active, hyper)
    return end_trial(cfg.agent, agent, success, ends)


def noise_normals(key: jax.Array, trial, chance) -> jax.Array:
    """B3: the standard-normal noise draws [angle, speed] of one throw."""
    return throw_noise(throw_key(key, trial, chance))


@functools.lru_cache(maxsize=8)
def _learning_steps(cfg: RunConfig):
    """jit(vmap) versions of `choose` (`choose_throws`), `learn_from_throw` and `noise_normals` over seeds."""
    pick = jax.jit(functools.partial(choose_throws, cfg))  # actions, learns and E8 routes
    learn = jax.jit(jax.vmap(functools.partial(learn_from_throw, cfg),
                             in_axes=(0, 0, 0, 0, 0, 0, 0, 0, None, 0, None)))
    noise = jax.jit(jax.vmap(noise_normals, in_axes=(0, None, None)))
    return pick, learn, noise


def run_chunk_c(cfg: RunConfig, phys: BowlingConfig, keys: jax.Array, hyper: Hyper,
                rules: TrialRules = PAPER_RULES) -> BowlingRecord:
    """One chunk of seeds with the C backend: compiled learning, batched C physics in between."""
    cfg = cfg.resolve(None)
    pick, learn, noise = _learning_steps(cfg)
    m = keys.shape[0]
    words = jax.vmap(seed_words)(keys)
    n_states = rules.n_states(phys.n_angles)
    agents = jax.vmap(lambda _: init_agent(cfg.agent, n_states, phys.n_angles, CHANCES, cfg.trials))(keys)
    grid = angle_grid(phys)
    action_rec = np.full((m, cfg.trials, CHANCES), -1, np.int8)
    knocked_rec = np.zeros((m, cfg.trials, CHANCES), np.int8)
    standing_rec = np.full((m, cfg.trials, CHANCES), -1, np.int16)
    _, flags_of = _diagnostic_steps(cfg, phys.n_angles, rules)
    counts = StepRoute(*(np.zeros((m, CHANCES), np.int32) for _ in range(4)))  # E8
    for t in range(cfg.trials):
        pins = initial_pins(m, phys.scene)
        state = np.full(m, rules.first_state, np.int32)
        standing = np.full(m, FULL_RACK, np.int32)
        pins_so_far = np.zeros(m, np.int32)
        active = np.ones(m, bool)
        for c in range(CHANCES):
            chosen = pick(agents, words, jnp.asarray(state), hyper, jnp.asarray(active))
            action, learns, route = jax.device_get(chosen)
            for total, x in zip(jax.tree.leaves(counts), jax.tree.leaves(route), strict=True):
                total[:, c] += x
            eps = np.asarray(noise(keys, t, c))
            knocked = np.zeros(m, np.int32)
            after = state.copy()
            idx = np.flatnonzero(active)
            if idx.size:
                sub = jax.tree.map(lambda x, i=idx: np.asarray(x)[i], pins)
                res = throw(sub, grid[action[idx]], eps[idx], backend="c", cfg=phys)
                knocked[idx] = res.knocked
                standing[idx] = np.asarray(mask_index(res.standing))
                after[idx] = np.asarray(rules.next_state(res.standing, action[idx]))
                pins = jax.tree.map(lambda full, part, i=idx: _set_rows(full, i, part), pins, res.pins_after)
                action_rec[idx, t, c] = action[idx]
                knocked_rec[idx, t, c] = res.knocked
                standing_rec[idx, t, c] = standing[idx]
            pins_so_far += knocked
            cleared = standing == 0
            agents = learn(agents, jnp.asarray(state), jnp.asarray(action), jnp.asarray(learns),
                           jnp.asarray(knocked), jnp.asarray(after), jnp.asarray(cleared),
                           jnp.asarray(pins_so_far >= rules.success_pins), c == CHANCES - 1,
                           jnp.asarray(active), hyper)
            active &= ~cleared
            state = after
    flags, rack_flags = jax.device_get(flags_of(agents))
    return BowlingRecord(action_rec, knocked_rec, np.asarray(agents.outcomes), standing_rec,
                         BowlingDiagnostics(counts, flags, rack_flags))


def _set_rows(full, rows, part):
    out = np.array(full, copy=True)
    out[rows] = np.asarray(part)
    return out


def make_run_mjx(cfg: RunConfig, phys: BowlingConfig, impl: str = "jax",
                 rules: TrialRules = PAPER_RULES) -> Callable:
    """The whole chunk with MJX (implementation impl) as one jit-compiled function:
    ``(keys [M], hyper) -> BowlingRecord``."""
    cfg = cfg.resolve(None)
    from jaxeac.envs.bowling.backend_mjx import make_batch_throw

    throw_all = make_batch_throw(phys, impl=impl)
    grid = jnp.asarray(angle_grid(phys), jnp.float32)

    def physics(pins, action, keys, trial, chance):
        eps_keys = jax.vmap(lambda k: throw_key(k, trial, chance))(keys)
        return throw_all(pins, grid[action], eps_keys)

    def batch(keys, hyper):
        m = keys.shape[0]
        words = jax.vmap(seed_words)(keys)
        n_states = rules.n_states(phys.n_angles)
        agents = jax.vmap(lambda _: init_agent(cfg.agent, n_states, phys.n_angles, CHANCES, cfg.trials))(keys)

        def trial_step(agents, t):
            pins = jax.tree.map(jnp.asarray, initial_pins(m, phys.scene))
            state = jnp.full((m,), rules.first_state, jnp.int32)
            pins_so_far = jnp.zeros((m,), jnp.int32)
            active = jnp.ones((m,), bool)
            actions, knocks, masks, routes = [], [], [], []
            for c in range(CHANCES):
                action, learns, route = choose_throws(cfg, agents, words, state, hyper, active)
                routes.append(route)  # E8
                res = physics(pins, action, keys, t, c)
                knocked = jnp.where(active, res.knocked, 0)
                after = jnp.where(active, rules.next_state(res.standing, action), state)
                cleared = active & (mask_index(res.standing) == 0)
                pins_so_far = pins_so_far + knocked
                agents = jax.vmap(learn_from_throw, in_axes=(None, 0, 0, 0, 0, 0, 0, 0, 0, None, 0, None))(
                    cfg, agents, state, action, learns, knocked, after, cleared,
                    pins_so_far >= rules.success_pins, c == CHANCES - 1, active, hyper)
                actions.append(jnp.where(active, action, -1))
                knocks.append(knocked)
                masks.append(jnp.where(active, mask_index(res.standing), -1))
                pins = res.pins_after
                active = active & ~cleared
                state = after
            routes = jax.tree.map(lambda *x: jnp.stack(x, -1).astype(jnp.int32), *routes)
            return agents, (jnp.stack(actions, -1), jnp.stack(knocks, -1), jnp.stack(masks, -1), routes)

        agents, (actions, knocks, masks, routes) = jax.lax.scan(trial_step, agents, jnp.arange(cfg.trials))
        flags, rack_flags = jax.vmap(lambda a: end_flags(cfg, a, phys.n_angles, rules))(agents)
        diagnostics = BowlingDiagnostics(jax.tree.map(lambda x: x.sum(axis=0), routes), flags, rack_flags)
        return BowlingRecord(jnp.swapaxes(actions, 0, 1).astype(jnp.int8),
                             jnp.swapaxes(knocks, 0, 1).astype(jnp.int8), agents.outcomes,
                             jnp.swapaxes(masks, 0, 1).astype(jnp.int16), diagnostics)

    return jax.jit(batch)


@dataclasses.dataclass(frozen=True)
class BowlingSettings:
    """Everything that defines a bowling run (defaults: paper's T = 10, K = 21, γ = 1; B2, B5)."""

    seeds: int = 1000
    trials: int = 10
    angles: int = 21
    theta_max: float = 0.1
    noise_angle: float = 0.003
    noise_speed: float = 0.1
    backend: str = "auto"  # B7: c on CPUs, warp (else mjx) on accelerators; `resolved`
    algos: tuple[str, ...] = ("ac", "eac")
    key: int = 0
    chunk_size: int = 1000
    alpha: float = 0.1
    beta: float = 0.3
    gamma: float = 1.0
    temperature: float = 1.0
    solver: SolverSettings = DEFAULT_SOLVER  # B7 constraint solver of both physics engines
    scene: str = "default"  # B1; "table1": B1a, a deck whose first throws are like Table I's
    state: str = "mask"  # B5 standing-pin mask; "tree": B5a, chance 2 keyed on the chance-1 angle
    success_pins: int = N_PINS  # B5b: pins a trial must knock to succeed (10: all down, B5)

    def validate(self) -> None:
        from jaxeac.experiments.common import check_algos, check_positive_int, check_rate

        for name in ("seeds", "trials", "chunk_size"):
            check_positive_int(name.replace("_", " "), getattr(self, name))
        if isinstance(self.angles, bool) or not isinstance(self.angles, int) or self.angles < 2:
            raise UsageError(f"angles must be an integer K >= 2 (got {self.angles!r})")
        check_backend(self.backend)
        check_rate("alpha", self.alpha)
        check_rate("beta", self.beta)
        check_rate("gamma", self.gamma, upper=1.0)
        check_rate("temperature", self.temperature, positive=True)
        check_algos(self.algos)
        self.check_memory_layout()
        self.physics()  # BowlingConfig validates θ_max and the noise levels
        self.rules()

    def check_memory_layout(self) -> None:
        """EAC's memories (dense layout: bowling has no other) hold at most 24 actions and, with K
        angles, fewer than min(2^(31-K), 32767) trials."""
        from jaxeac.algorithm.memory import MAX_DENSE_ACTIONS

        if not any(algorithm(a).uses_memory for a in self.algos):
            return
        if self.angles > MAX_DENSE_ACTIONS:
            raise UsageError(f"angles {self.angles}: EAC's memories hold at most {MAX_DENSE_ACTIONS} angles; "
                             f"use {MAX_DENSE_ACTIONS} angles or fewer (or AC alone)")
        most = min(1 << (31 - self.angles), 32_767) - 1
        if self.trials > most:
            raise UsageError(f"trials {self.trials}: with {self.angles} angles EAC's memories hold at most "
                             f"{most:,} trials; use {most:,} trials or fewer (or fewer angles)")

    def rules(self) -> TrialRules:
        return TrialRules(self.state, self.success_pins)

    def resolved(self) -> BowlingSettings:
        """These settings with the backend ``auto`` replaced by the one it picks here (B7)."""
        return dataclasses.replace(self, backend=check_backend(self.backend))

    def physics(self) -> BowlingConfig:
        return BowlingConfig(n_angles=self.angles, theta_max=self.theta_max,
                             noise_angle=self.noise_angle, noise_speed=self.noise_speed, solver=self.solver,
                             scene=check_scene(self.scene))

    def run_config(self, algo: str) -> RunConfig:
        """The resolved `RunConfig` of `algo` (bowling runs the XLA steps: no grid kernel)."""
        return RunConfig(trials=self.trials, agent=algorithm(algo), alpha=self.alpha, beta=self.beta,
                         gamma=self.gamma, temperature=self.temperature).resolve(None)


#: Seeds per chunk when none is given (`auto_chunk_size`): the size every backend has run at.
AUTO_CHUNK = 1000


def auto_chunk_size(settings: BowlingSettings, devices=None) -> int:
    """Seeds per chunk when none is given (`jaxeac bowling` without --chunk-size): `AUTO_CHUNK`, at
    most the seeds, and at most what fits in half the memory of a device (of the host on CPUs) at
    three copies of a seed's agent, as `check_bowling_resources` counts a chunk. Results do not
    depend on it (R1)."""
    from jaxeac.experiments.common import _device_memory, machine_memory

    devices = list(devices) if devices is not None else jax.local_devices()
    budget = _device_memory(devices[0]) or machine_memory()
    state = 1
    for algo in settings.algos:
        cfg = settings.run_config(algo)
        shapes = jax.eval_shape(
            lambda cfg=cfg: init_agent(cfg.agent, 1024, settings.angles, 2, settings.trials))
        state = max(state, sum(int(np.prod(x.shape, dtype=np.float64)) * x.dtype.itemsize
                               for x in jax.tree.leaves(shapes)))
    return max(1, min(settings.seeds, AUTO_CHUNK, budget // 2 // (3 * state)))


@dataclasses.dataclass
class BowlingResult:
    """All seeds of one algorithm: per-chance actions and pins, per-trial success; timings."""

    action: np.ndarray  # int8 [N, T, 2], −1 = not thrown (strike on chance 1)
    knocked: np.ndarray  # int8 [N, T, 2]
    success: np.ndarray  # bool [N, T]
    angles: np.ndarray  # float [K], the angle grid
    compile_seconds: float
    run_seconds: float
    standing: np.ndarray | None = None  # int16 [N, T, 2]: pins standing after each chance (mask), −1 not thrown
    diagnostics: BowlingDiagnostics | None = None  # E8, numpy leaves [N, ...]

    @property
    def returns(self) -> np.ndarray:
        """Pins per trial [N, T] (0–10)."""
        return self.knocked.sum(axis=2, dtype=np.int32)

    @property
    def total_return(self) -> np.ndarray:
        return self.returns.sum(axis=1)

    @property
    def throws(self) -> int:
        return int((self.action >= 0).sum())

    @property
    def angle_values(self) -> np.ndarray:
        """Angles in rad [N, T, 2], NaN where no throw was made."""
        return np.where(self.action >= 0, self.angles[np.maximum(self.action, 0)], np.nan)

    def best_path(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """B6: per seed, (θ₁, θ₂, return) of its highest-return trial (the first on ties)."""
        best = self.returns.argmax(axis=1)
        rows = np.arange(best.size)
        theta = self.angle_values[rows, best]
        return theta[:, 0], theta[:, 1], self.returns[rows, best]

    @property
    def first_success(self) -> np.ndarray:
        return np.where(self.success.any(axis=1), self.success.argmax(axis=1) + 1, -1)

    @classmethod
    def concatenate(cls, parts: list[BowlingResult]) -> BowlingResult:
        """Consecutive batches of one algorithm's seeds as one result (a sequential run)."""
        standing = None if parts[0].standing is None else np.concatenate([p.standing for p in parts])
        return cls(np.concatenate([p.action for p in parts]), np.concatenate([p.knocked for p in parts]),
                   np.concatenate([p.success for p in parts]), parts[0].angles,
                   parts[0].compile_seconds, sum(p.run_seconds for p in parts), standing,
                   _concatenate_diagnostics([p.diagnostics for p in parts]))


def _concatenate_diagnostics(parts: list[BowlingDiagnostics | None]) -> BowlingDiagnostics | None:
    """Consecutive batches' E8 counts as one (None if a batch has none)."""
    if any(p is None for p in parts):
        return None
    return jax.tree.map(lambda *xs: np.concatenate(xs), *parts)


_MJX_COMPILED: dict = {}  # (config, physics, backend, chunk) -> compiled run


def run_bowling_algo(settings: BowlingSettings, algo: str, *,
                     progress: Callable[[int], None] | None = None, first_seed: int = 0,
                     n_seeds: int | None = None) -> BowlingResult:
    """Seeds first_seed … first_seed+n−1 (default all N) of one algorithm (R1: seed i uses
    fold_in(root, i)), in chunks; an MJX program is compiled once per chunk shape."""
    settings = settings.resolved()
    cfg, phys = settings.run_config(algo), settings.physics()
    hyper = cfg.hyper()
    root = jax.random.key(settings.key)
    n = settings.seeds if n_seeds is None else n_seeds
    chunk = min(settings.chunk_size, n)
    parts: list[BowlingRecord] = []
    compile_seconds = compiled_now = 0.0
    t0 = time.perf_counter()
    for seeds in chunks(n, chunk):
        seeds = seeds + first_seed
        padded = np.pad(seeds, (0, chunk - seeds.size), mode="edge")
        keys = jax.vmap(seed_key, in_axes=(None, 0))(root, jnp.asarray(padded))
        if settings.backend in MJX_IMPL:
            cache = (cfg, phys, settings.backend, chunk, settings.rules())
            if cache not in _MJX_COMPILED:
                if len(_MJX_COMPILED) >= 16:
                    _MJX_COMPILED.clear()
                c0 = time.perf_counter()
                _MJX_COMPILED[cache] = make_run_mjx(cfg, phys, MJX_IMPL[settings.backend], settings.rules()).lower(
                    keys, hyper).compile()
                compiled_now = compile_seconds = time.perf_counter() - c0
            run_mjx = _MJX_COMPILED[cache]
            rec = jax.device_get(run_mjx(keys, hyper))
        else:
            rec = run_chunk_c(cfg, phys, keys, hyper, settings.rules())
        parts.append(jax.tree.map(lambda x, n=seeds.size: np.asarray(x)[:n], rec))
        if progress is not None:
            progress(seeds.size)
    elapsed = time.perf_counter() - t0
    cat = jax.tree.map(lambda *xs: np.concatenate(xs), *parts)
    return BowlingResult(cat.action, cat.knocked, cat.success.astype(bool), angle_grid(phys),
                         compile_seconds, elapsed - compiled_now, cat.standing.astype(np.int16), cat.diagnostics)


@dataclasses.dataclass
class BowlingRun:
    """A finished bowling experiment: settings and per-algorithm results."""

    settings: BowlingSettings
    results: dict[str, BowlingResult]


def run_bowling(settings: BowlingSettings, *, progress: Callable[[int], None] | None = None) -> BowlingRun:
    """Run every algorithm of (validated) `settings`; the run keeps them `resolved` (the backend `auto`
    picked)."""
    settings = settings.resolved()
    return BowlingRun(settings, {a: run_bowling_algo(settings, a, progress=progress) for a in settings.algos})


def summarize_bowling(run: BowlingRun) -> dict:
    """summary.json content, as the grid's, with `return` (pins over T trials) as the primary measure."""
    from jaxeac.experiments.common import summary_base

    out = summary_base("bowling", "return", run.settings, run.results,
                       {a: r.total_return for a, r in run.results.items()})
    for algo, r in run.results.items():
        out["per_algo"][algo] |= {
            "mean_successes": float(r.success.sum(axis=1).mean()), "throws": r.throws,
            "throws_per_second": r.throws / r.run_seconds if r.run_seconds > 0 else None,
        }
    out |= bowling_diagnostics(run)  # E8
    return out | {"physics": dataclasses.asdict(run.settings.physics()), "paper_totals": BOWLING_PINS}


def rack_means(results: dict[str, BowlingResult]) -> np.ndarray:
    """float [K]: mean pins of a chance-1 throw (from the full rack) per angle, over every seed and
    trial of every algorithm of the run; NaN for an angle never thrown from it (E8)."""
    k = next(iter(results.values())).angles.size
    pins, throws = np.zeros(k), np.zeros(k)
    for r in results.values():
        action, knocked = r.action[:, :, 0].ravel(), r.knocked[:, :, 0].ravel()
        thrown = action >= 0
        throws += np.bincount(action[thrown], minlength=k)
        pins += np.bincount(action[thrown], weights=knocked[thrown], minlength=k)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(throws > 0, pins / throws, np.nan)


def bowling_diagnostics(run: BowlingRun) -> dict:
    """summary.json's ``diagnostics_seeds``, ``rack_mean_pins``, ``best_rack_actions`` and
    ``memory_diagnostics`` (E8), over every seed: per chance, the share of throws E1(a) chose; the
    shares E1(b) restricted and that learnt (E2); the E6 flags, and of the flags at the full rack
    the share on a best angle (the highest `rack_means`)."""
    from jaxeac.running.diagnostics import diagnostics_block

    means = rack_means(run.results)
    best = means == np.nanmax(means) if np.isfinite(means).any() else np.zeros(means.size, bool)
    blocks = {}
    for algo, r in run.results.items():
        d = r.diagnostics
        if d is None:
            continue
        judged = int(d.rack_flags.sum())
        blocks[algo] = diagnostics_block(d.routes, int(d.flags.sum()), flags_judged=judged,
                                         flags_on_best=int(d.rack_flags[:, best].sum()),
                                         best_at_flags=judged * best.sum() / best.size)
    return {"diagnostics_seeds": run.settings.seeds,
            "rack_mean_pins": [None if np.isnan(x) else float(x) for x in means],
            "best_rack_actions": np.flatnonzero(best).tolist(), "memory_diagnostics": blocks}


def table_one(run: BowlingRun, seed: int = 0) -> str:
    """Table I: per-chance pins of one seed per algorithm, and means (95 % CI) over seeds."""
    from jaxeac.experiments.common import mean_ci95

    algos = list(run.results)
    lines = [f"### Table I — pins per chance, seed {seed}", "",
             "| trial | " + " | ".join(f"{a.upper()} chance 1 | {a.upper()} chance 2" for a in algos) + " |",
             "|---|" + "---|---|" * len(algos)]
    for t in range(run.settings.trials):
        cells = []
        for a in algos:
            k, act = run.results[a].knocked[seed, t], run.results[a].action[seed, t]
            cells += [str(k[0]), str(k[1]) if act[1] >= 0 else "–"]
        lines.append(f"| {t + 1} | " + " | ".join(cells) + " |")
    per_chance = [str(int(run.results[a].knocked[seed, :, c].clip(min=0).sum())) for a in algos
                  for c in range(CHANCES)]
    lines += ["| total per chance | " + " | ".join(per_chance) + " |", "",
              f"Seed {seed}'s totals (both chances, {run.settings.trials} trials): "
              + ", ".join(f"{a.upper()} **{int(run.results[a].total_return[seed])}**" for a in algos)
              + f" pins of {10 * run.settings.trials}.", ""]
    n = run.settings.seeds
    lines += [f"### Means over {n} seeds (95% CI)", "", "| trial | "
              + " | ".join(f"{a.upper()} chance 1 | {a.upper()} chance 2" for a in algos) + " |",
              "|---|" + "---|---|" * len(algos)]
    for t in range(run.settings.trials):
        cells = []
        for a in algos:
            for c in range(CHANCES):
                mean, _, lo, hi = mean_ci95(run.results[a].knocked[:, t, c])
                cells.append(f"{mean:.2f} [{lo:.2f}, {hi:.2f}]" if n > 1 else f"{mean:.2f}")
        lines.append(f"| {t + 1} | " + " | ".join(cells) + " |")
    lines.append("")
    for a in algos:
        mean, _, lo, hi = mean_ci95(run.results[a].total_return)
        paper = BOWLING_PINS.get(a) if run.settings.trials == 10 else None
        lines.append(f"- {a.upper()}: mean total {mean:.2f} of {10 * run.settings.trials} "
                     f"(95% CI [{lo:.2f}, {hi:.2f}])" + (f"; paper's single run: {paper}" if paper else ""))
    return "\n".join(lines) + "\n"


def per_seed_csv(run: BowlingRun) -> str:
    """per_seed.csv: algo, seed, return (pins over all T trials), successes, first success, B6 best path."""
    rows = ["algo,seed,return,successes,first_success,best_theta1,best_theta2,best_return"]
    for algo, r in run.results.items():
        th1, th2, best = r.best_path()
        for i in range(r.success.shape[0]):
            t2 = "" if np.isnan(th2[i]) else f"{th2[i]:.6g}"
            rows.append(f"{algo},{i},{r.total_return[i]},{int(r.success[i].sum())},{r.first_success[i]},"
                        f"{th1[i]:.6g},{t2},{best[i]}")
    return "\n".join(rows) + "\n"


def run_bowling_sequential(settings: BowlingSettings, design, *,
                           progress: Callable[[int], None] | None = None,
                           on_look: Callable[[dict], None] | None = None) -> tuple[BowlingRun, dict]:
    """A sequential comparison of EAC with AC on total pins (`jaxeac.stats.sequential`): seeds in
    batches of ⌊N / K⌋ per method, a paired look after each (seed i of both shares its key),
    stop at the first decision. Returns the run of the seeds used and the ``sequential`` record
    (design, looks, decision, decision rates simulated from the run's per-seed differences)."""
    from jaxeac.stats.sequential import calibration_record, run_sequential

    if not {"ac", "eac"} <= set(settings.algos):
        raise UsageError("--sequential compares eac with ac: --algos must include both")
    parts: dict[str, list[BowlingResult]] = {a: [] for a in settings.algos}
    t0 = time.perf_counter()

    def measure(first: int, n: int):
        for a in settings.algos:
            parts[a].append(run_bowling_algo(settings, a, progress=progress, first_seed=first, n_seeds=n))
        return parts["ac"][-1].total_return, parts["eac"][-1].total_return

    result = run_sequential(design, measure, on_look, paired=True)
    result["seconds_to_decision"] = time.perf_counter() - t0
    results = {a: BowlingResult.concatenate(p) for a, p in parts.items()}
    d = results["eac"].total_return.astype(np.float64) - results["ac"].total_return
    result["calibration"] = calibration_record(design, d, settings.key)
    return BowlingRun(dataclasses.replace(settings, seeds=result["seeds_used"]), results), result



def write_bowling_outputs(run: BowlingRun, out, *, figures: bool = True,
                          sequential: dict | None = None) -> dict:
    """per_seed.csv, curves.npz, bowling.npz, table1.md, summary.json and figures, all or nothing.
    `sequential`: a sequential run's record, kept in summary.json."""
    from jaxeac.io import RUN_FOLDER_FILES, atomic_write_json, staged_dir

    summary = summarize_bowling(run)
    if sequential is not None:
        summary["sequential"] = sequential
    with staged_dir(out, replaces=RUN_FOLDER_FILES) as stage:
        (stage / "per_seed.csv").write_text(per_seed_csv(run))
        np.savez_compressed(stage / "curves.npz",
                            **{a: r.success for a, r in run.results.items()},
                            **{f"{a}_return": r.returns.astype(np.int16) for a, r in run.results.items()})
        np.savez_compressed(stage / "bowling.npz",
                            **{f"{a}_knocked": r.knocked for a, r in run.results.items()},
                            **{f"{a}_action": r.action for a, r in run.results.items()},
                            **{f"{a}_angle": r.angle_values for a, r in run.results.items()},
                            **{f"{a}_standing": r.standing for a, r in run.results.items()
                               if r.standing is not None},
                            angles=angle_grid(run.settings.physics()),
                            pin_xy=run.settings.physics().scene.pin_xy())
        (stage / "table1.md").write_text(table_one(run))
        if figures:
            from jaxeac.plots import angle_figure

            angle_figure({a: r.angle_values for a, r in run.results.items()}, stage / "fig5_angles.png")
            summary["figures"] = ["fig5_angles.png"]
        atomic_write_json(stage / "summary.json", summary)
    return summary
