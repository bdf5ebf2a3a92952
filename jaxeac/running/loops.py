"""One seed's run as one compiled loop, in two structures with bit-identical results (tested).

* ``trials`` — `trace_run`: a `lax.scan` over trials, each a `lax.scan` over C
  chances, masked once the trial has ended. The literal shape of Algorithm 1;
  needed by the buffer memory layout, whose writes happen at trial ends.
* ``flat`` — the fast path: all lanes of a chunk advance one *chance* per
  iteration and a seed whose trial ends starts its next trial at the next
  iteration, so trials that end early (EAC's, mostly) leave no padded slots; with
  fewer lanes than seeds, lanes take waiting seeds from a queue. On GPUs the C
  chances of a block run as one fused kernel (`jaxeac.running.kernel`).

A chance is `choose` (E1 with the seed's uniform, R1), the environment's move, and
`learn_and_record` ((2)–(4), E5/E6 records); bowling calls the same two functions.
All take a resolved `RunConfig` (`RunConfig.resolve`).
SPEC ids (G1…, E1…, B1…, R1…) are defined in docs/SPEC.md.

(Over 400 lines on purpose: both loop structures side by side, so that their bit-identity can be
read line against line.)
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from jaxeac.algorithm.agent import (
    AgentState,
    end_trial,
    failure_slot,
    greedy_policy,
    init_agent,
    learn_step,
    record_step,
    select_action,
    tables_finite,
    value_learn_step,
)
from jaxeac.algorithm.config import Hyper, rate_at
from jaxeac.envs.protocol import LoopEnv as Env
from jaxeac.envs.protocol import chance_bound
from jaxeac.pytree import pytree_dataclass
from jaxeac.rng import action_uniform, as_key, bootstrap_uniform, seed_words
from jaxeac.running.carry import (  # noqa: F401  (flat_init, state_bytes_per_seed, program_key: re-exported)
    _FlatCarry,
    _Jumps,
    _shadowed,
    bind_inputs,
    flat_init,
    program_inputs,
    program_key,
    state_bytes_per_seed,
    visit_fields,
    visit_word,
)
from jaxeac.running.config import RunConfig
from jaxeac.running.kernel import LANES_PER_PROGRAM, advance_chances
from jaxeac.running.outputs import BatchOutput, SeedResult, pack_output


@pytree_dataclass
class TrialRecord:
    """What one trial leaves behind (per chance: state, action, r̃; and totals)."""

    states: jax.Array  # int32 [C]
    actions: jax.Array  # int32 [C]
    rtilde: jax.Array  # float [C]
    length: jax.Array  # int32 [], chances actually used
    success: jax.Array  # bool []


def choose(cfg: RunConfig, agent: AgentState, state, words, hyper: Hyper, n_chances: int, active,
           diagnose: bool = False):
    """E1 at `state` with the uniform of (trial, chance) of this seed (R1); (action, learns) (E2),
    and with `diagnose` (static) the step's `StepRoute` (E8) as a third value."""
    trial = jnp.minimum(agent.trial, cfg.trials - 1)
    u = action_uniform(words, trial, agent.chance, n_chances)
    return select_action(cfg.agent, agent, state, u, hyper, active, route=diagnose)


def learn_and_record(cfg: RunConfig, agent: AgentState, state, action, learns, reward, next_state,
                     terminated, rtilde, active, hyper: Hyper, before=None, next_uniform=None) -> AgentState:
    """After a chance: (2)–(4) on the transition where `learns` (E2) (X3's baselines:
    `value_learn_step`, SARSA's next action drawn with `next_uniform`), then r̃ and the memory
    records (E4–E6) where `active`, with the step sizes of the current trial (`before`:
    `record_step`)."""
    trial = jnp.minimum(agent.trial, cfg.trials - 1)
    alpha = rate_at(cfg.alpha, hyper.alpha, trial)
    if cfg.agent.learner == "actor_critic":
        agent = learn_step(agent, state, action, reward, next_state, terminated, learns, alpha,
                           rate_at(cfg.beta, hyper.beta, trial), hyper.gamma)
    else:
        agent = value_learn_step(cfg.agent, agent, state, action, reward, next_state, terminated, learns, alpha,
                                 hyper.gamma, hyper.epsilon, next_uniform)
    return record_step(cfg.agent, agent, state, action, rtilde, active, before)


def take_chance(env: Env, cfg: RunConfig, agent: AgentState, env_state, words, hyper: Hyper, active,
                before=None, diagnose: bool = False):
    """Alg. 1 lines 4–14 for one chance, if `active`: E1 choice, move, (2)–(4), r̃ (E5), records.

    Returns (agent, step, state, action, r̃), and with `diagnose` (static) the chance's
    `StepRoute` (E8) last. `before`: the r̃ E6 compares with, if not its slot's.
    """
    s = env.observation(env_state)
    action, learns, *route = choose(cfg, agent, s, words, hyper, env.n_chances, active, diagnose)
    step = env.move(env_state, action, words, jnp.minimum(agent.trial, cfg.trials - 1), agent.chance)
    s_next = env.observation(step.state)
    goal_known = agent.goal_known | (active & step.success)  # E5: this step included
    rtilde = env.rtilde(step, goal_known)
    next_uniform = None
    if cfg.agent.learner == "sarsa":  # X3: the next chance's action, drawn now for the target
        next_uniform = bootstrap_uniform(words, jnp.minimum(agent.trial, cfg.trials - 1), agent.chance + 1,
                                         env.n_chances)
    agent = learn_and_record(cfg, agent.replace(goal_known=goal_known), s, action, learns, step.reward,
                             s_next, step.terminated, rtilde, active, hyper, before, next_uniform)
    return agent, step, s, action, rtilde, *route


# --- the `trials` loop: literal Algorithm 1 structure -----------------------------------------


@pytree_dataclass
class _ChanceCarry:
    env_state: Any
    agent: AgentState
    done: jax.Array


def chance_of_trial(env: Env, cfg: RunConfig, hyper: Hyper, words, diagnose: bool = False):
    """One chance of the `trials` loop: ``take(carry) -> (carry, (state, action, r̃, live, success))``,
    masked once the trial has ended (``live`` False), with `diagnose` (static) the chance's
    `StepRoute` (E8) last. `run_trial` scans it; E8's count (`jaxeac.running.diagnostics`) loops it."""

    def take(carry: _ChanceCarry):
        live = ~carry.done
        agent, step, s, action, rtilde, *route = take_chance(env, cfg, carry.agent, carry.env_state, words,
                                                             hyper, live, diagnose=diagnose)
        env_state = jax.tree.map(lambda new, old: jnp.where(live, new, old), step.state, carry.env_state)
        done = carry.done | step.terminated | step.truncated
        return _ChanceCarry(env_state, agent, done), (s, action, rtilde, live, live & step.success, *route)

    return take


def first_chance(env: Env, agent: AgentState, words) -> _ChanceCarry:
    """The carry at the start of trial `agent.trial`."""
    return _ChanceCarry(env.start(words, agent.trial), agent, jnp.bool_(False))


def run_trial(env: Env, cfg: RunConfig, agent: AgentState, hyper: Hyper, words):
    """Algorithm 1 lines 3–29 for trial `agent.trial`: C chances (masked once done), then E4/E6.
    Where C is data (traced, `chance_bound`), the chances past it up to the bound are skipped,
    recorded as not taken (zeros), as masked chances are."""
    take = chance_of_trial(env, cfg, hyper, words)
    first = first_chance(env, agent, words)
    if not isinstance(env.n_chances, jax.Array):  # C static: every chance of the scan is one
        def chance(carry: _ChanceCarry, _):
            return take(carry)
    else:
        records = jax.eval_shape(take, first)[1]

        def chance(carry: _ChanceCarry, c):
            def skip(carry):
                return carry, jax.tree.map(lambda x: jnp.zeros(x.shape, x.dtype), records)

            return jax.lax.cond(c < env.n_chances, take, skip, carry)

    end, (states, actions, rtilde, live, reached) = jax.lax.scan(chance, first, jnp.arange(chance_bound(env)))
    record = TrialRecord(states, actions, rtilde, live.sum(dtype=jnp.int32), reached.any())
    agent = end_trial(cfg.agent, end.agent, record.success, jnp.bool_(True))
    return agent, record


def trace_run(env: Env, cfg: RunConfig, key: jax.Array, hyper: Hyper) -> tuple[AgentState, TrialRecord]:
    """One seed's run with the `trials` loop, keeping the final agent and every trial's record.
    A pure function of the seed's `key` (`jaxeac.rng.seed_key`; a JAX key, traced or not, or an
    integer k for ``jax.random.key(k)``, `jaxeac.rng.as_key`) and `hyper`; jit and vmap it freely."""
    check_run_args(env, cfg, hyper)
    cfg = cfg.resolve(env)
    agent = init_agent(cfg.agent, env.n_states, env.n_actions, chance_bound(env), cfg.trials)
    words = seed_words(as_key(key, "key"))
    return jax.lax.scan(lambda a, _: run_trial(env, cfg, a, hyper, words), agent, None, length=cfg.trials)


def jump_gate(env: Env):
    """bool [] (traced) where memory jumps are switched on per task by its tables, else None."""
    gate = getattr(env, "jump_gate", None)
    return gate() if gate is not None else None


def check_run_args(env: Env, cfg: RunConfig, hyper: Hyper | None = None) -> None:
    """The per-seed functions' arguments: TypeError naming the one that is not what they take
    (values are checked where they are made: `RunConfig`, `jaxeac.make`)."""
    missing = [a for a in ("n_states", "n_actions", "n_chances", "start", "move", "observation", "rtilde")
               if not hasattr(env, a)]
    if missing:
        raise TypeError(f"env must be a jaxeac environment (e.g. jaxeac.make('grid-paper-v0')); {env!r} "
                        f"lacks {', '.join(missing)}")
    if not isinstance(cfg, RunConfig):
        raise TypeError(f"cfg must be a RunConfig, e.g. RunConfig(trials=200, agent=algorithm('eac')) "
                        f"(got {cfg!r})")
    if hyper is not None and not isinstance(hyper, Hyper):
        raise TypeError(f"hyper must be a Hyper, e.g. cfg.hyper() (got {hyper!r})")


def make_run(env: Env, cfg: RunConfig) -> Callable[[jax.Array, Hyper], SeedResult]:
    """Build ``run(seed_key, hyper) -> SeedResult`` for one seed (the `trials` loop)."""
    check_run_args(env, cfg)
    cfg = cfg.resolve(env)

    def run(key: jax.Array, hyper: Hyper) -> SeedResult:
        agent, records = trace_run(env, cfg, key, hyper)
        return SeedResult(records.success, records.length, greedy_policy(cfg.agent, agent),
                          tables_finite(agent))

    return run


# --- the `flat` loop: one chance per iteration, trials back to back ----------------------------


def flat_slot(env: Env, cfg: RunConfig, carry: _FlatCarry, words, hyper: Hyper) -> _FlatCarry:
    """One chance of one seed; a trial that ends here is closed and the next one started.

    **Memory jumps** (``cfg.jump == "on"``; `jaxeac.running.config.resolved_jump`). In a
    deterministic world, a trial standing on a state with a success action follows the
    success memory to the goal (E1 a, E4 erases loops), without learning (E2). A state's
    success action never changes once set: E1(a) always takes it, so the only later writes
    (E4) write it again. So the path from it, and its length h, are fixed, and one step
    E1(a) took from it at chance c of trial t tells h = (chances trial t used) − c if
    trial t succeeded. Where h is known, the trial ends at once: a success with c + h
    chances if h ≤ C − c, else a failure after C. Nothing the skipped steps would have
    written is read again: their memory writes rewrite the same actions, failure flags
    on states with a success action are never consulted, and the r̃ that E6 compares the
    next trial with (paper's rule) is recomputed along the path (`shadow`). Per-seed
    results are those of taking every step (tested against the `trials` loop).
    """
    agent = carry.agent
    active = agent.trial < cfg.trials
    jumps = carry.jumps
    if jumps is None:
        agent, step, _, _, _ = take_chance(env, cfg, agent, carry.env_state, words, hyper, active)
        ends = active & (step.terminated | step.truncated)
        success = step.success
    else:
        n_chances, c = env.n_chances, agent.chance
        s = env.observation(carry.env_state)
        remembered = agent.memory.success_action(s, agent.trial, agent.outcomes)
        visit_trial, visit_chance = visit_fields(jumps.visits[s], chance_bound(env))
        walked = agent.log[jnp.maximum(visit_trial, 0)]  # > 0: that trial's chances, a success
        known = (remembered >= 0) & (visit_trial >= 0) & (walked > 0)
        to_goal = walked - visit_chance  # h: chances from s to the goal
        jump = active & known
        if (gate := jump_gate(env)) is not None:  # tables as inputs: exact on this task?
            jump = jump & gate
        takes = active & ~jump
        before = shadow = None
        if jumps.shadow is not None:  # E6 reads trial t−1's r̃ at c: on its path past its jump
            on_path = c >= jumps.anchor
            path_state = env.observation(jumps.shadow)
            # `path_action` reads no trial log: a read that the log's write does not depend on
            # would make XLA copy the whole log every chance to keep the old values.
            moved = env.move(jumps.shadow, jnp.maximum(agent.memory.path_action(path_state), 0), words,
                             agent.trial, c)  # deterministic (jumps need it): draws nothing
            path_rtilde = env.rtilde(moved, jnp.bool_(True))
            before = jnp.where(on_path, path_rtilde, agent.rtilde[failure_slot(cfg.agent.failure_rule, c, n_chances)])
            shadow = jax.tree.map(lambda here, nxt, old: jnp.where(jump, here, jnp.where(on_path, nxt, old)),
                                  carry.env_state, moved.state, jumps.shadow)
        agent, step, _, _, _ = take_chance(env, cfg, agent, carry.env_state, words, hyper, takes, before)
        remaining = n_chances - c
        agent = agent.replace(chance=jnp.where(jump, c + jnp.minimum(to_goal, remaining), agent.chance))
        ends = jump | (takes & (step.terminated | step.truncated))
        success = jnp.where(jump, to_goal <= remaining, step.success)
        row = jnp.where(takes & (remembered >= 0), s, env.n_states)  # a step E1(a) took: h known later
        jumps = _Jumps(
            visits=jumps.visits.at[row].set(visit_word(agent.trial, c, chance_bound(env)), mode="drop",
                                            unique_indices=True),
            anchor=jnp.where(ends, jnp.where(jump, c, n_chances), jumps.anchor),
            shadow=shadow,
        )
        active = takes
    agent = end_trial(cfg.agent, agent, success, ends)
    nxt = jnp.minimum(agent.trial, cfg.trials - 1)
    start = env.start(words, nxt)
    env_state = jax.tree.map(
        lambda fresh, moved, old: jnp.where(ends, fresh, jnp.where(active, moved, old)),
        start, step.state, carry.env_state,
    )
    return _FlatCarry(agent, env_state, jumps)


@pytree_dataclass
class _Lane:
    """One lane of the flat loop: the run of the seed it holds, and which entry that is."""

    run: _FlatCarry
    words: jax.Array  # uint32 [2]
    hyper: Hyper
    entry: jax.Array  # int32 [], index into the batch; ≥ M once the lane is idle


def flat_batch(env: Env, cfg: RunConfig, words, hyper: Hyper) -> BatchOutput:
    """All entries of a chunk (``words`` [M, 2], ``hyper`` leaves [M]) on min(M, lanes) lanes.

    Lanes advance one chance per iteration. With a lane per entry, blocks of C
    iterations run until every seed has run T trials and results are read out once.
    With fewer lanes, every C iterations lanes whose seed has run T trials (up to
    `harvest` of them) write its result and take the next waiting seed, so lanes stay
    busy until the queue is empty (a seed's result does not depend on its lane, R1).
    On wide lane counts (`tail_lanes`) the busy lanes then move to a narrower batch for
    the tail, where a few slow seeds would otherwise keep every lane iterating.
    """
    m = words.shape[0]
    cfg = cfg.resolve(env, m)  # a no-op for a config resolved before tracing
    n_lanes = min(m, cfg.lanes)
    slot = jax.vmap(lambda c, w, h: flat_slot(env, cfg, c, w, h))
    if cfg.kernel == "pallas":
        n_lanes = -(-n_lanes // LANES_PER_PROGRAM) * LANES_PER_PROGRAM  # whole programs; extra lanes idle
        interpret = jax.default_backend() != "gpu"

        def advance(run: _FlatCarry, w, h) -> _FlatCarry:  # C chances of every lane, one kernel
            return advance_chances(env, cfg, run, w, h, interpret=interpret)
    else:
        def advance(run: _FlatCarry, w, h) -> _FlatCarry:  # C chances of every lane, XLA ops
            return jax.lax.fori_loop(0, env.n_chances, lambda _, x: slot(x, w, h), run)
    policies = jax.vmap(lambda a: greedy_policy(cfg.agent, a))
    finite = jax.vmap(tables_finite)

    def start(entry) -> _Lane:  # a lane for `entry`; entries ≥ M give an idle lane
        i = jnp.minimum(entry, m - 1)
        w, h = words[i], jax.tree.map(lambda x: x[i], hyper)
        return _Lane(flat_init(env, cfg, w), w, h, entry)

    # Every entry has a lane from the start: no queue, results read out once. Seeds of an
    # algorithm with memories end far apart, so where a tail phase exists they go through the
    # queue path (with an empty queue) to reach it.
    if n_lanes >= m and not (cfg.agent.uses_memory and tail_lanes(n_lanes, cfg.kernel)):
        pad = jnp.minimum(jnp.arange(n_lanes), m - 1)  # lanes past M rerun the last entry, dropped
        lane_words, lane_hyper = words[pad], jax.tree.map(lambda x: x[pad], hyper)

        def unfinished(run: _FlatCarry):
            return (run.agent.trial < cfg.trials).any()

        def chances(run: _FlatCarry):
            return advance(run, lane_words, lane_hyper)

        first = jax.vmap(lambda w: flat_init(env, cfg, w))(lane_words)
        agent = jax.lax.while_loop(unfinished, chances, first).agent
        return pack_output(env, agent.log[:m], policies(agent)[:m], finite(agent)[:m])

    lanes = jax.vmap(start)(jnp.arange(n_lanes))
    out = pack_output(env, jnp.zeros((m, cfg.trials), jnp.int32), jnp.zeros((m, env.n_states), jnp.int32),
                      jnp.ones((m,), bool))

    def blocks(lanes, out, queued, width: int, until: int):
        """Blocks of C chances on `width` lanes while any lane is busy and either seeds wait in
        the queue or more than `until` lanes are busy."""
        # Lanes harvested per block: a bounded number, so per-block work (the finished lanes'
        # greedy policies, fresh lanes) stays small next to the block's C chances.
        harvest = max(1, width // 8)

        def block(carry):
            lanes, out, queued = carry
            run = advance(lanes.run, lanes.words, lanes.hyper)
            done = (run.agent.trial >= cfg.trials) & (lanes.entry < m)
            (idx,) = jnp.nonzero(done, size=harvest, fill_value=width)  # the first finished lanes
            got = idx < width
            lane = jnp.minimum(idx, width - 1)
            finished = jax.tree.map(lambda x: x[lane], run)
            row = jnp.where(got, lanes.entry[lane], m)  # rows ≥ M are dropped
            done_out = pack_output(env, finished.agent.log, policies(finished.agent),
                                   finite(finished.agent))
            out = jax.tree.map(lambda a, new: a.at[row].set(new, mode="drop"), out, done_out)
            nxt = queued + jnp.arange(harvest)  # the next waiting entries, in lane order
            take = got & (nxt < m)
            fresh = jax.vmap(start)(nxt)  # hand waiting entries to the harvested lanes
            # The writes go into `run`'s buffers, which the reads of the finished lanes above share:
            # indices that depend on what was read order every read first, so XLA writes in place
            # instead of copying every lane's tables, memory and log each block.
            target = jnp.where(take & _read(done_out), idx, width)
            lanes = jax.tree.map(lambda a, f: a.at[target].set(f, mode="drop"), lanes.replace(run=run), fresh)
            idle = jnp.where(got & ~take, idx, width)
            lanes = lanes.replace(entry=lanes.entry.at[idle].set(m, mode="drop"))
            return lanes, out, queued + take.sum(dtype=jnp.int32)

        def going(carry):
            busy = (carry[0].entry < m).sum()
            return (busy > 0) & ((carry[2] < m) | (busy > until))

        return jax.lax.while_loop(going, block, (lanes, out, queued))

    # The tail: once the queue is empty, the last seeds run on fewer lanes (`tail_lanes`), so
    # the slowest seeds' many chances are not paid for by every idle lane.
    width, queued = n_lanes, jnp.int32(n_lanes)
    for narrow in [*tail_lanes(n_lanes, cfg.kernel), 0]:
        lanes, out, queued = blocks(lanes, out, queued, width, narrow)
        if narrow:
            (busy,) = jnp.nonzero(lanes.entry < m, size=narrow, fill_value=width)
            pick = functools.partial(jnp.take, indices=jnp.minimum(busy, width - 1), axis=0)
            lanes = jax.tree.map(pick, lanes)
            lanes = lanes.replace(entry=jnp.where(busy < width, lanes.entry, m))  # fill: idle lanes
            width = narrow
    return out


#: The tail of a queue-fed chunk runs on 1/`TAIL_SHRINK` of the lanes, where that leaves at
#: least `TAIL_MIN_LANES` (accelerators' wide lane counts; BENCHMARKS.md, "Tabular tasks").
TAIL_SHRINK = 16
TAIL_MIN_LANES = 2048


def _read(values) -> jax.Array:
    """bool [], always True, computed from every leaf of `values` (narrow ints and bools): a value to
    make a later write depend on these reads, which XLA cannot see through."""
    low = sum(jnp.min(x).astype(jnp.int32) for x in jax.tree.leaves(values))
    return low > jnp.iinfo(jnp.int32).min


def tail_lanes(n_lanes: int, kernel: str) -> list[int]:
    """Lane counts of the flat loop's tail phases after the first (none for narrow lane counts)."""
    narrow = n_lanes // TAIL_SHRINK
    if kernel == "pallas":
        narrow -= narrow % LANES_PER_PROGRAM
    return [narrow] if narrow >= TAIL_MIN_LANES else []


def trials_batch(env: Env, cfg: RunConfig, keys, hyper: Hyper) -> BatchOutput:
    r = jax.vmap(make_run(env, cfg))(keys, hyper)
    return pack_output(env, jnp.where(r.success, r.steps, -r.steps), r.policy, r.finite)
