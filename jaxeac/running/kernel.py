"""The flat loop's C chances as one fused GPU kernel (Pallas, Triton backend).

The XLA loop (`jaxeac.running.batch`) runs each chance of every lane as a dozen GPU
kernels that pass [lanes] intermediates through memory. This kernel runs C chances
of a block of lanes in one program: each lane's scalars (cell, trial, chance, …)
stay in registers, and a chance touches memory only where the agent's state is
indexed by the seed's cell: its row of p and V (reads at s and s', writes at s), its
memory word, one entry of its trial log and of its r̃ slots.

It is the same algorithm, step for step, and calls the same definitions as the XLA
loop for every piece of Algorithm 1 (`jaxeac.algorithm`: E1's `restricts`,
`memory_choice` and `learns`, (3) `td_error`, (2)/(4) `learning_increments`, E6
`failure_slot`/`failure_met`, the packed memory's `settled`, `packed_in_effect` and
`packed_visit`, `log_entry`; the grid's `decode_move`, `move_reward` and
`shaped_reward`; R1's `action_uniform` and `start_index`). What it owns, because it
holds a block of lanes per action column in registers rather than [A]-vectors:
loading and storing the seed's row, memory word and log entry, the per-column
softmax draw (`_sample`) and the baselines' ε-greedy one (`_epsilon_greedy`), and the
flags as per-column bits. Tests check that it matches the XLA loop bit for bit on the
CPU (Pallas's interpreter runs the kernel body there); on GPUs both paths are compiled by different compilers, so
results are compared in BENCHMARKS.md rather than promised equal.

Supported: every environment that gives its `KernelTables` (`env.kernel_tables()`, the
protocol of `jaxeac.envs.protocol`): the grid world and every tabular task (the move, reward, end
flags and, in a stochastic task, the outcome's draw read from its tables), rows
tables, the packed dense memory or none (AC), both E6 rules, the E2 variant, the value-based
baselines (X3: Q-learning and SARSA, ε-greedy on Q in the same row), constant step sizes. Anything else runs the XLA loop (`jaxeac.running.config.kernel_unsupported` says why).
JAX deprecated the Triton backend in 0.11: where it cannot be imported or cannot lower this kernel
(`backend_problem`), `kernel='auto'` runs the XLA loop with one warning and `kernel='pallas'` is an
error (`jaxeac.running.config.resolved_kernel`). Pallas's Mosaic GPU backend cannot express the
kernel's per-lane gathers and scatters yet (BENCHMARKS.md, "What did not help").
SPEC ids (G1…, E1…, B1…, R1…) are defined in docs/SPEC.md.

(Over 400 lines: the kernel and what decides whether this JAX can build it, which lowers the
same program, kept together.)
"""

from __future__ import annotations

import functools
import sys
import threading

import jax
import jax.numpy as jnp

from jaxeac.algorithm import memory as mem
from jaxeac.algorithm.agent import (
    failure_met,
    failure_slot,
    learns,
    log_entry,
    memory_choice,
    restricts,
    td_error,
)
from jaxeac.algorithm.tables import RowTables, learning_increments
from jaxeac.envs.protocol import KernelTables
from jaxeac.rng import action_uniform, bootstrap_uniform
from jaxeac.running.carry import flat_init, program_cache_key, visit_fields, visit_word
from jaxeac.running.programs import remembered

LANES_PER_PROGRAM = 128  # one lane per thread: 4 warps (32, 64, 256 ran slower on an H100)


def _sample(logits: list, allowed: list, u):
    """`sample_softmax` on per-action columns: the same operations in the same order.

    A second copy on purpose: the kernel holds a block of lanes per action, while the
    XLA loop's [A]-vector form runs markedly faster on CPUs than this column form (tried:
    one shared column version slowed the CPU step). tests/test_kernel.py holds the two
    to identical actions for every algorithm.
    """
    if allowed is None:  # no restriction (constants stay out of the kernel: Triton lowers values)
        top = functools.reduce(jnp.maximum, logits)
        weights = [jnp.exp(x - top) for x in logits]
    else:
        masked = [jnp.where(ok, x, -jnp.inf) for x, ok in zip(logits, allowed, strict=True)]
        top = functools.reduce(jnp.maximum, masked)
        weights = [jnp.where(ok, jnp.exp(x - top), 0.0) for x, ok in zip(logits, allowed, strict=True)]
    cdf = [weights[0]]
    for w in weights[1:]:
        cdf.append(cdf[-1] + w)
    threshold = u * cdf[-1]
    action = functools.reduce(lambda n, c: n + (c <= threshold).astype(jnp.int32), cdf[1:],
                              (cdf[0] <= threshold).astype(jnp.int32))
    return jnp.minimum(action, len(logits) - 1)


def _epsilon_greedy(q: list, u, epsilon):
    """`epsilon_greedy` (X3) on per-action columns: the same operations in the same order (a
    second copy for the reason `_sample` gives; tests/test_kernel.py holds the two to identical
    actions)."""
    explore = u < epsilon
    v = jnp.where(explore, u / epsilon, (u - epsilon) / (1.0 - epsilon))
    top = functools.reduce(jnp.maximum, q)
    allowed = [(explore | (x == top)).astype(jnp.int32) for x in q]
    count = jnp.maximum(functools.reduce(jnp.add, allowed), 1)
    k = jnp.minimum((v * count).astype(jnp.int32), count - 1)  # the k-th allowed action, 0-based
    prefix, action = allowed[0], (allowed[0] <= k).astype(jnp.int32)
    for x in allowed[1:]:
        prefix = prefix + x
        action = action + (prefix <= k).astype(jnp.int32)
    return jnp.minimum(action, len(q) - 1)


def _column(values: list, index):
    """values[index] for a per-lane index into per-action columns."""
    return functools.reduce(lambda acc, a: jnp.where(index == a, values[a], acc), range(1, len(values)), values[0])


def _chance_kernel(env, cfg, tables: KernelTables, names: tuple[str, ...], *refs):
    """C chances of `LANES_PER_PROGRAM` lanes (see the module docstring)."""
    from jax.experimental import pallas as pl
    from jax.experimental.pallas import triton as plgpu

    agent = cfg.agent
    n_actions, n_trials = env.n_actions, cfg.trials
    value_based = agent.learner != "actor_critic"  # X3's baselines: ε-greedy on Q, with ε an input
    n_fixed = 7 if value_based else 6
    n_in = n_fixed + len(tables.arrays)
    (w0_ref, w1_ref, alpha_ref, beta_ref, gamma_ref, temp_ref) = refs[:6]
    env_refs = dict(zip(tables.arrays, refs[n_fixed:n_in], strict=True))  # the env's tables, by name
    state = dict(zip(names, refs[n_in + len(names):], strict=True))  # the outputs, aliased to the inputs
    lane = pl.program_id(0) * LANES_PER_PROGRAM + jnp.arange(LANES_PER_PROGRAM)
    n_chances = tables.chances(env_refs, jnp.int32(0))  # C: static, or a scalar read from the tables
    max_chances = tables.n_chances  # the static bound (`chance_bound`): the visit words' chance bits

    def put(ref, value, mask=None):
        plgpu.store(ref, value, mask=mask)

    words = (w0_ref[lane], w1_ref[lane])
    alpha, beta, gamma, temperature = alpha_ref[lane], beta_ref[lane], gamma_ref[lane], temp_ref[lane]
    epsilon = refs[6][lane] if value_based else None
    rows, log, rtilde = state["rows"], state["log"], state["rtilde"]
    packed = mem.PackedMemory(words=None, n_actions=n_actions) if agent.uses_memory else None

    jumps = "visits" in state  # memory jumps (`flat_slot`)

    def chance(_, carry):
        position, env_chance, trial_now, c, goal_known, prev_length, anchor, shadow, next_action = carry
        live = trial_now < n_trials
        trial = jnp.minimum(trial_now, n_trials - 1)
        u = action_uniform(words, trial, c, n_chances)
        s = position
        prefs = [rows[lane, s, a] for a in range(n_actions)]
        value = rows[lane, s, n_actions]
        if value_based:  # `select_action`: SARSA takes the action it bootstrapped on
            action = _epsilon_greedy(prefs, u, epsilon)
            if next_action is not None:
                action = jnp.where(next_action >= 0, next_action, action)
            active = learn = live
            jump = None
        else:
            logits = [p / temperature for p in prefs]
            allowed = restricted = remembered = None  # None: no restriction / no such memory
            if packed is not None:  # E1 (a), (b) from the seed's memory word at s
                f = packed.unpack(state["memory"][lane, s])
                succeeded, failed = mem.settled(f.stamp, trial_now, log[lane, jnp.maximum(f.stamp, 0)] > 0)
                remembered, failed_bits = mem.packed_in_effect(f, succeeded, failed)
            active, jump = live, None
            if jumps:  # a known path length from s: the trial ends here without a step
                # The log is read only where the visit word names a trial (a masked load: memory
                # traffic bounds this kernel); the visit word is read beside the memory word.
                visit = plgpu.load(state["visits"].at[lane, s], mask=live, other=0)
                visit_trial, visit_chance = visit_fields(visit, max_chances)
                known = (remembered >= 0) & (visit_trial >= 0)
                walked = plgpu.load(log.at[lane, jnp.maximum(visit_trial, 0)], mask=known, other=0)
                to_goal = walked - visit_chance
                jump = live & known & (walked > 0)
                gate = getattr(tables, "jump_gate", None)  # tables as inputs: exact on this task?
                if gate is not None and (exact := gate(env_refs, trial)) is not None:
                    jump = jump & exact
                active = live & ~jump
            if agent.failure_memory:
                flags = [(failed_bits >> a) & 1 == 1 for a in range(n_actions)]
                n_flagged = functools.reduce(lambda n, x: n + x.astype(jnp.int32), flags[1:],
                                             flags[0].astype(jnp.int32))
                restricted = restricts(n_flagged, n_actions)
                allowed = [restricted & ~x | ~restricted for x in flags]
            action, from_memory = memory_choice(agent, _sample(logits, allowed, u), remembered, restricted)
            learn = learns(agent, from_memory, active)

        # G4/G5, E3, X1
        s_next, reward, terminated, reached, bumped = tables.move(env_refs, s, action, words, trial, c)
        truncated = (~terminated) & (env_chance + 1 >= n_chances)

        taken = _column(prefs, action)
        if value_based:  # `value_learn_step`: Q(s', ·) read before the row is written
            q_next = [rows[lane, s_next, a] for a in range(n_actions)]
            if next_action is None:  # Q-learning: the greedy value
                bootstrap = functools.reduce(jnp.maximum, q_next)
            else:  # SARSA: the ε-greedy next action, kept for the next chance
                chosen = _epsilon_greedy(q_next, bootstrap_uniform(words, trial, c + 1, n_chances), epsilon)
                bootstrap = _column(q_next, chosen)
                next_action = jnp.where(learn, chosen, next_action)
            delta = td_error(reward, taken, bootstrap, gamma, terminated)
            actor, critic = learning_increments(delta, learn, 0.0, alpha)
        else:  # (2)-(4) (`learn_step`, `RowTables.learn`): read V(s') before the row is written
            delta = td_error(reward, value, rows[lane, s_next, n_actions], gamma, terminated)
            actor, critic = learning_increments(delta, learn, alpha, beta)
        put(rows.at[lane, s, action], taken + actor)
        put(rows.at[lane, s, n_actions], value + critic)

        # E5 and the records of `record_step`
        goal_known = goal_known | (active & reached).astype(jnp.int32)
        shaped = tables.rtilde(env_refs, s_next, bumped, goal_known == 1, reward)
        flag = None
        if agent.failure_memory:  # E6
            before = rtilde[lane, failure_slot(agent.failure_rule, c, n_chances)]
            if jumps and shadow is not None:  # trial t−1's r̃ past its jump, along its path
                on_path = c >= anchor
                path_word = plgpu.load(state["memory"].at[lane, shadow], mask=on_path, other=0)
                path_action = packed.unpack(path_word).pending  # `path_action`
                # deterministic (jumps need it): the move draws nothing
                path_next, path_reward, _, _, path_bumped = tables.move(
                    env_refs, shadow, jnp.maximum(path_action, 0), words, trial, c)
                path_rtilde = tables.rtilde(env_refs, path_next, path_bumped, True, path_reward)
                before = jnp.where(on_path, path_rtilde, before)
                shadow = jnp.where(jump, s, jnp.where(on_path, path_next, shadow))
            flag = active & failure_met(agent.failure_rule, c, prev_length, shaped, before)
            put(rtilde.at[lane, jnp.minimum(c, n_chances - 1)], shaped, active)
        if packed is not None:  # `PackedMemory.record`
            new = mem.packed_visit(
                f, trial_now, succeeded, failed,
                action if agent.success_memory else jnp.full_like(action, -1),
                0 if flag is None else jnp.where(flag, 1 << action, 0))
            put(state["memory"].at[lane, s], packed.pack(new), active)
        success = reached
        ends = active & (terminated | truncated)
        if jumps:
            put(state["visits"].at[lane, s], visit_word(trial_now, c, max_chances), active & (remembered >= 0))
            remaining = n_chances - c
            success = jnp.where(jump, to_goal <= remaining, reached)
            ends = ends | jump
            anchor = jnp.where(ends, jnp.where(jump, c, n_chances), anchor)
            c = jnp.where(jump, c + jnp.minimum(to_goal, remaining), c)
        c = c + active.astype(jnp.int32)

        # `end_trial` and the next trial's start (`flat_slot`)
        put(log.at[lane, jnp.minimum(trial_now, n_trials - 1)], log_entry(success, c), ends)
        if next_action is not None:  # SARSA: a new trial chooses afresh
            next_action = jnp.where(ends, -1, next_action)
        prev_length = jnp.where(ends, c, prev_length)
        trial_now = trial_now + ends.astype(jnp.int32)
        c = jnp.where(ends, 0, c)
        nxt = jnp.minimum(trial_now, n_trials - 1)
        start = tables.start(env_refs, words, nxt)
        position = jnp.where(ends, start, jnp.where(active, s_next, position))
        env_chance = jnp.where(ends, 0, jnp.where(active, env_chance + 1, env_chance))
        return position, env_chance, trial_now, c, goal_known, prev_length, anchor, shadow, next_action

    vectors = ("position", "env_chance", "trial", "chance", "goal_known", "prev_length", "anchor", "shadow",
               "next_action")
    carry = tuple(state[k][lane] if k in state else None for k in vectors)
    carry = jax.lax.fori_loop(0, n_chances, chance, carry)
    for k, v in zip(vectors, carry, strict=True):
        if k in state:
            put(state[k].at[lane], v)


@functools.cache
def _name_triton_dialect() -> None:
    """Make the Triton dialect's module findable where MLIR's Python bindings look for it.

    For each op they build, the bindings import "<prefix>.<namespace>" until one import succeeds,
    and remember only successes; JAX's Triton dialect ("tt") is `jaxlib.triton.dialect`, so the
    kernel's lowering made three failing imports per op (about 600 a program), each through the
    interpreter's import lock: the threads lowering a study's programs side by side waited on it
    7.5 thread-seconds (a profile of `jaxeac study --seeds 1000`, one H100). Naming the module under
    the first prefix makes the first lookup succeed; the lowered kernel is the same, byte for byte.
    """
    try:
        from jaxlib.mlir._mlir_libs import _mlir
        from jaxlib.triton import _triton_ops_gen, dialect
        prefix = list(_mlir.globals.dialect_search_modules)[0]
        namespace = _triton_ops_gen._Dialect.DIALECT_NAMESPACE
    except Exception:  # noqa: BLE001 - another layout of jaxlib: the bindings search as they did
        return
    sys.modules.setdefault(f"{prefix}.{namespace}", dialect)


def _build(env, cfg, tables: KernelTables, names: tuple[str, ...], out_shape: list, *, n_in: int,
           interpret: bool):
    """The kernel as a callable of (inputs, state): one program per `LANES_PER_PROGRAM` lanes, the
    state's outputs aliased to its inputs."""
    from jax.experimental import pallas as pl
    from jax.experimental.pallas import triton as plgpu

    _name_triton_dialect()  # before the kernel is lowered

    return pl.pallas_call(
        functools.partial(_chance_kernel, env, cfg, tables, names),
        out_shape=out_shape,
        grid=(out_shape[0].shape[0] // LANES_PER_PROGRAM,),
        input_output_aliases={n_in + i: i for i in range(len(names))},
        compiler_params=plgpu.CompilerParams(num_warps=LANES_PER_PROGRAM // 32, num_stages=1),
        interpret=interpret,
    )


def advance_chances(env, cfg, run, words: jax.Array, hyper, *, interpret: bool):
    """C chances of every lane of ``run`` (a `_FlatCarry` with leaves [L, ...]) in one kernel.

    Same result as C applications of the vmapped `flat_slot` (see the module docstring).
    """
    agent = run.agent
    assert isinstance(agent.tables, RowTables)
    n_lanes = words.shape[0]
    if n_lanes % LANES_PER_PROGRAM:
        raise ValueError(f"the fused kernel runs whole programs: lanes must be a multiple of "
                         f"{LANES_PER_PROGRAM} (got {n_lanes})")
    state = {
        "rows": agent.tables.rows, "log": agent.log, "rtilde": agent.rtilde,
        "position": run.env_state.position, "env_chance": run.env_state.chance,
        "trial": agent.trial, "chance": agent.chance,
        "goal_known": agent.goal_known.astype(jnp.int32), "prev_length": agent.prev_length,
    }
    if agent.memory is not None:
        state["memory"] = agent.memory.words
    if agent.next_action is not None:
        state["next_action"] = agent.next_action
    if run.jumps is not None:
        state["visits"], state["anchor"] = run.jumps.visits, run.jumps.anchor
        if run.jumps.shadow is not None:
            state["shadow"] = run.jumps.shadow.position
    names = tuple(state)
    f32 = agent.tables.rows.dtype
    tables = env.kernel_tables()
    if tables is None:
        raise ValueError(f"the fused kernel cannot run {env!r} (its kernel_tables() is None); "
                         "use kernel='xla'")
    consts = (
        words[:, 0], words[:, 1],
        *(jnp.broadcast_to(jnp.asarray(x, f32), (n_lanes,))
          for x in (hyper.alpha, hyper.beta, hyper.gamma, hyper.temperature,
                    *((hyper.epsilon,) if cfg.agent.learner != "actor_critic" else ()))),
        *(jnp.asarray(x) for x in tables.arrays.values()),
    )
    call = _build(env, cfg, tables, names, [jax.ShapeDtypeStruct(x.shape, x.dtype) for x in state.values()],
                  n_in=len(consts), interpret=interpret)
    out = call(*consts, *state.values())
    new = dict(zip(names, out, strict=True))
    memory = agent.memory if agent.memory is None else agent.memory.replace(words=new["memory"])
    agent = agent.replace(
        tables=agent.tables.replace(rows=new["rows"]), memory=memory, log=new["log"],
        rtilde=new["rtilde"], trial=new["trial"], chance=new["chance"],
        goal_known=new["goal_known"] == 1, prev_length=new["prev_length"],
        next_action=new.get("next_action"),
    )
    jumps = run.jumps
    if jumps is not None:
        shadow = jumps.shadow if jumps.shadow is None else jumps.shadow.replace(position=new["shadow"])
        jumps = jumps.replace(visits=new["visits"], anchor=new["anchor"], shadow=shadow)
    return run.replace(agent=agent, jumps=jumps, env_state=run.env_state.replace(
        position=new["position"], chance=new["env_chance"]))



_PROBED: dict = {}  # (program key, config, platform) -> `backend_problem`'s answer, once per process
_PROBING = threading.local()  # `.key`: this thread's probe under way (its tracing resolves the config again)


def backend_problem(env, cfg, *, lower: bool) -> str | None:
    """Why the fused kernel cannot be built in this JAX (None: it can), for an env the kernel
    supports and a config with the kernel and jump settings of its run.

    The kernel needs Pallas's Triton backend (`jax.experimental.pallas.triton`), which JAX
    deprecated in 0.11 and will remove. Checked: that the backend imports, and with `lower`
    that it lowers this kernel for a GPU (on `LANES_PER_PROGRAM` lanes, from shapes alone; on a
    CPU-only JAX too, for CUDA). Answers are kept per program key and config, for the process
    and, with the compilation cache on, for later ones (`jaxeac.running.programs.remembered`).
    """
    try:
        from jax.experimental.pallas import triton  # noqa: F401
    except ImportError as exc:
        return (f"Pallas's Triton backend cannot be imported in JAX {jax.__version__} "
                f"(jax.experimental.pallas.triton: {_first_line(exc)})")
    if not lower:
        return None
    platform = jax.default_backend() if jax.default_backend() == "gpu" else "cuda"
    key = program_cache_key(env, cfg, platform)  # one answer per layout
    if key in _PROBED:
        return _PROBED[key]
    if getattr(_PROBING, "key", None) is not None:  # the probe's own tracing resolves its config again
        return None
    _PROBING.key = (key,)  # per thread: another thread's probe is no answer for this one

    def probe() -> str | None:
        try:
            _lower(env, cfg, platform)
        except Exception as exc:  # noqa: BLE001 - whatever the backend raises is the reason
            return (f"Pallas's Triton backend could not lower the fused kernel in JAX {jax.__version__} "
                    f"({type(exc).__name__}: {_first_line(exc)})")
        return None

    try:  # a rerun reads the answer an earlier process found (`jaxeac.running.programs`)
        problem = probe() if key is None else remembered("kernel-probe", key, probe)
    finally:
        _PROBING.key = None
    if key is not None:
        _PROBED[key] = problem
    return problem


def _lower(env, cfg, platform: str):
    """Trace and lower `advance_chances` for `platform` on one program's lanes (nothing runs); the
    lowered program."""
    words = jax.ShapeDtypeStruct((LANES_PER_PROGRAM, 2), jnp.uint32)
    run = jax.eval_shape(lambda w: jax.vmap(lambda x: flat_init(env, cfg, x))(w), words)
    hyper = jax.tree.map(lambda x: jax.ShapeDtypeStruct((LANES_PER_PROGRAM,), x.dtype), cfg.hyper())
    advance = jax.jit(lambda r, w, h: advance_chances(env, cfg, r, w, h, interpret=False))
    return advance.trace(run, words, hyper).lower(lowering_platforms=(platform,))


def _first_line(exc: BaseException) -> str:
    return ((str(exc).strip().splitlines() or [type(exc).__name__])[0])[:200]
