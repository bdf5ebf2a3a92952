"""The flat loop's C chances as one fused GPU kernel (Pallas, Triton backend).

The XLA loop (`jaxeac.running.batch`) runs each chance of every lane as a dozen GPU
kernels that pass [lanes] intermediates through memory. This kernel runs C chances
of a block of lanes in one program: each lane's scalars (cell, trial, chance, …)
stay in registers, and a chance touches memory only where the agent's state is
indexed by the seed's cell: its row of p and V (reads at s and s', writes at s), its
memory word, one entry of its trial log and of its r̃ slots.

It is the same algorithm, step for step: Algorithm 1 with E1–E7 for the grid world,
the same counter-based random numbers (`step_uniform`, R1) and the same order of
floating-point operations as `take_chance` / `end_trial` / `_flat_slot`. Tests check
that it matches the XLA loop bit for bit on the CPU (Pallas's interpreter runs the
kernel body there); on GPUs both paths are compiled by different compilers, so
results are compared in BENCHMARKS.md rather than promised equal.

Supported: the grid world, rows tables, the packed dense memory or none (AC), both
E6 rules, the E2 variant, constant step sizes. Anything else runs the XLA loop
(`kernel_unsupported` says why).
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp

from jaxeac.algorithm import memory as mem
from jaxeac.algorithm.agent import RowTables

LANES_PER_PROGRAM = 128  # one lane per thread: 4 warps (32, 64, 256 ran slower on an H100)


def kernel_unsupported(env: Any, cfg: Any) -> str | None:
    """Why the fused kernel cannot run this env and config (None: it can)."""
    from jaxeac.envs.grid import GridWorld
    from jaxeac.algorithm.agent import resolve_tables

    agent = cfg.agent
    if not isinstance(env, GridWorld):
        return "the fused kernel runs the grid world only"
    if resolve_tables(agent.tables) != "rows":
        return "the fused kernel needs the rows table layout (tables='rows')"
    if agent.uses_memory and not (agent.memory == "dense"
                                   and mem.packed_fits(env.n_actions, cfg.trials)):
        return "the fused kernel needs the packed dense memory (A <= 5 actions and a bounded trial count)"
    if callable(cfg.alpha) or callable(cfg.beta):
        return "the fused kernel needs constant step sizes (not schedules)"
    return None


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


def _chance_kernel(env, cfg, names: tuple[str, ...], *refs):
    """C chances of `LANES_PER_PROGRAM` lanes (see the module docstring)."""
    from jax.experimental import pallas as pl
    from jax.experimental.pallas import triton as plgpu

    from jaxeac.running.batch import action_counter, start_index, step_uniform

    agent = cfg.agent
    n_actions, n_chances, n_trials = env.n_actions, env.n_chances, cfg.trials
    n_in = 9
    (w0_ref, w1_ref, alpha_ref, beta_ref, gamma_ref, temp_ref, moves_ref, dist_ref, starts_ref) = refs[:n_in]
    state = dict(zip(names, refs[n_in + len(names):], strict=True))  # the outputs, aliased to the inputs
    lane = pl.program_id(0) * LANES_PER_PROGRAM + jnp.arange(LANES_PER_PROGRAM)

    def put(ref, value, mask=None):
        plgpu.store(ref, value, mask=mask)

    words = (w0_ref[lane], w1_ref[lane])
    alpha, beta, gamma, temperature = alpha_ref[lane], beta_ref[lane], gamma_ref[lane], temp_ref[lane]
    rows, log, rtilde = state["rows"], state["log"], state["rtilde"]
    packed = mem.PackedMemory(words=None, n_actions=n_actions) if agent.uses_memory else None

    def chance(_, carry):
        position, env_chance, trial_now, c, goal_known, prev_length = carry
        active = trial_now < n_trials
        trial = jnp.minimum(trial_now, n_trials - 1)
        u = step_uniform(words, action_counter(trial, c, n_chances))
        s = position
        prefs = [rows[lane, s, a] for a in range(n_actions)]
        value = rows[lane, s, n_actions]
        logits = [p / temperature for p in prefs]
        allowed = None  # all actions
        from_memory = None  # E2: whether a memory chose or restricted the action (None: never)
        if packed is not None:  # E1 (a), (b) from the seed's memory word at s
            f = mem._unpack_packed(packed, state["memory"][lane, s])
            outcome = log[lane, jnp.maximum(f.stamp, 0)] > 0
            settled = (f.stamp >= 0) & (f.stamp < trial_now)
            succeeded, failed_before = settled & outcome, settled & ~outcome
        if agent.failure_memory:
            bits = f.failed | jnp.where(failed_before, f.failed_pending, 0)
            flags = [(bits >> a) & 1 == 1 for a in range(n_actions)]
            n_flagged = functools.reduce(lambda n, x: n + x.astype(jnp.int32), flags[1:],
                                         flags[0].astype(jnp.int32))
            restrict = (n_flagged > 0) & (n_flagged < n_actions)
            allowed = [restrict & ~x | ~restrict for x in flags]
            from_memory = restrict
        action = _sample(logits, allowed, u)
        if agent.success_memory:
            remembered = jnp.where(succeeded, f.pending, f.committed)
            has_success = remembered >= 0
            action = jnp.where(has_success, remembered, action)
            from_memory = has_success if from_memory is None else from_memory | has_success
        learn = active if agent.learn_on_memory_steps or from_memory is None else active & ~from_memory

        # G4/G5: the move (`GridWorld.step`)
        move = moves_ref[s * n_actions + action]
        s_next, bumped = move >> 1, (move & 1) == 1
        terminated = s_next == env.map.goal_index
        reward = jnp.where(bumped, -1.0, jnp.where(terminated, 1.0, 0.0))
        truncated = (~terminated) & (env_chance + 1 >= n_chances)

        # (2)-(4) (`learn_step`, `RowTables.learn`): read V(s') before the row is written
        next_value = rows[lane, s_next, n_actions]
        delta = reward + gamma * jnp.where(terminated, 0.0, next_value) - value
        step = jnp.where(learn, delta, 0.0)
        taken = functools.reduce(lambda acc, a: jnp.where(action == a, prefs[a], acc),
                                 range(1, n_actions), prefs[0])
        put(rows.at[lane, s, action], taken + beta * step)
        put(rows.at[lane, s, n_actions], value + alpha * step)

        # E5 and the records of `record_step`
        goal_known = goal_known | (active & terminated).astype(jnp.int32)
        distance = dist_ref[s_next]
        shaped = jnp.where(bumped, -1.0, jnp.where(goal_known == 1, 1.0 / (1.0 + distance), 0.0))
        flag = None
        if agent.failure_memory:  # E6
            if agent.failure_rule == "previous_trial":
                before = rtilde[lane, jnp.minimum(c, n_chances - 1)]
                flag = active & (c < prev_length) & (shaped < before)
            else:
                before = rtilde[lane, jnp.maximum(c - 1, 0)]
                flag = active & (c >= 1) & (shaped < before)
            put(rtilde.at[lane, jnp.minimum(c, n_chances - 1)], shaped, active)
        if packed is not None:  # `record_packed`
            new = mem._Packed(
                stamp=trial_now,
                pending=action if agent.success_memory else jnp.full_like(action, -1),
                committed=jnp.where(succeeded, f.pending, f.committed),
                failed=f.failed | jnp.where(failed_before, f.failed_pending, 0),
                failed_pending=jnp.where(f.stamp == trial_now, f.failed_pending, 0)
                | (0 if flag is None else jnp.where(flag, 1 << action, 0)),
            )
            put(state["memory"].at[lane, s], mem._pack_packed(packed, new), active)
        c = c + active.astype(jnp.int32)

        # `end_trial` and the next trial's start (`_flat_slot`)
        ends = active & (terminated | truncated)
        put(log.at[lane, jnp.minimum(trial_now, n_trials - 1)], jnp.where(terminated, c, -c), ends)
        prev_length = jnp.where(ends, c, prev_length)
        trial_now = trial_now + ends.astype(jnp.int32)
        c = jnp.where(ends, 0, c)
        nxt = jnp.minimum(trial_now, n_trials - 1)
        start = starts_ref[start_index(words, nxt, n_chances, env.n_starts)]
        position = jnp.where(ends, start, jnp.where(active, s_next, position))
        env_chance = jnp.where(ends, 0, jnp.where(active, env_chance + 1, env_chance))
        return position, env_chance, trial_now, c, goal_known, prev_length

    vectors = ("position", "env_chance", "trial", "chance", "goal_known", "prev_length")
    carry = tuple(state[k][lane] for k in vectors)
    carry = jax.lax.fori_loop(0, n_chances, chance, carry)
    for k, v in zip(vectors, carry, strict=True):
        put(state[k].at[lane], v)


def advance_chances(env, cfg, run, words: jax.Array, hyper, *, interpret: bool):
    """C chances of every lane of ``run`` (a `_FlatCarry` with leaves [L, ...]) in one kernel.

    Same result as C applications of the vmapped `_flat_slot` (see the module docstring).
    """
    from jax.experimental import pallas as pl
    from jax.experimental.pallas import triton as plgpu

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
    names = tuple(state)
    f32 = agent.tables.rows.dtype
    consts = (
        words[:, 0], words[:, 1],
        *(jnp.broadcast_to(jnp.asarray(x, f32), (n_lanes,))
          for x in (hyper.alpha, hyper.beta, hyper.gamma, hyper.temperature)),
        jnp.asarray(env._moves), jnp.asarray(env.goal_distance, f32), jnp.asarray(env._start_cells),
    )
    n_in = len(consts)
    out = pl.pallas_call(
        functools.partial(_chance_kernel, env, cfg, names),
        out_shape=[jax.ShapeDtypeStruct(x.shape, x.dtype) for x in state.values()],
        grid=(n_lanes // LANES_PER_PROGRAM,),
        input_output_aliases={n_in + i: i for i in range(len(names))},
        compiler_params=plgpu.CompilerParams(num_warps=LANES_PER_PROGRAM // 32, num_stages=1),
        interpret=interpret,
    )(*consts, *state.values())
    new = dict(zip(names, out, strict=True))
    memory = agent.memory if agent.memory is None else agent.memory.replace(words=new["memory"])
    agent = agent.replace(
        tables=agent.tables.replace(rows=new["rows"]), memory=memory, log=new["log"],
        rtilde=new["rtilde"], trial=new["trial"], chance=new["chance"],
        goal_known=new["goal_known"] == 1, prev_length=new["prev_length"],
    )
    return run.replace(agent=agent, env_state=run.env_state.replace(
        position=new["position"], chance=new["env_chance"]))

