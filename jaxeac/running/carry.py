"""What one lane of the flat loop carries, and its size: the agent, the environment's state and,
with memory jumps, `_Jumps` with its visit words (`jaxeac.running.loops.flat_slot`).

Below `jaxeac.running.config` and `jaxeac.running.loops` (both read it): the visit words' fit
decides `RunConfig.resolve`'s jumps, and a lane's bytes the automatic chunk size. A config here
is a `RunConfig` (its fields are read, the class is not imported, so nothing imports back).
SPEC ids (G1…, E1…, B1…, R1…) are defined in docs/SPEC.md.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxeac.algorithm.agent import AgentState, init_agent
from jaxeac.envs.protocol import LoopEnv as Env
from jaxeac.envs.protocol import chance_bound
from jaxeac.pytree import pytree_dataclass


@pytree_dataclass
class _Jumps:
    """What memory jumps carry per lane (`flat_slot`); absent where the run does not jump."""

    visits: jax.Array  # int32 [S]: (trial + 1, chance) of the last step E1(a) took from each state; 0: none
    anchor: jax.Array  # int32 []: chance at which the previous trial jumped (C: it took every step)
    shadow: Any  # env state on the previous trial's memory path at the current chance (E6); None without E6


@pytree_dataclass
class _FlatCarry:
    agent: AgentState
    env_state: Any
    jumps: _Jumps | None = None


def flat_init(env: Env, cfg, words) -> _FlatCarry:
    agent = init_agent(cfg.agent, env.n_states, env.n_actions, chance_bound(env), cfg.trials)
    start = env.start(words, 0)
    jumps = None
    if cfg.jump == "on":
        shadow = start if _shadowed(cfg) else None
        jumps = _Jumps(jnp.zeros((env.n_states,), jnp.int32), jnp.asarray(env.n_chances, jnp.int32), shadow)
    return _FlatCarry(agent, start, jumps)


def visit_word(trial, chance, max_chances: int):
    """A `_Jumps.visits` word: trial + 1 above the bits of the chance (0: no visit); `max_chances`:
    the static bound of C (`chance_bound`)."""
    return ((trial + 1) << _chance_bits(max_chances)) | chance


def visit_fields(word, max_chances: int):
    """(trial, chance) of a `visit_word`; trial −1: no visit."""
    bits = _chance_bits(max_chances)
    return (word >> bits) - 1, word & ((1 << bits) - 1)


def _chance_bits(n_chances: int) -> int:
    return max(1, (n_chances - 1).bit_length())


def visit_words_fit(n_trials: int, n_chances: int) -> bool:
    """Whether every `visit_word` of a run of this many trials and chances fits in an int32."""
    return (n_trials + 1) << _chance_bits(n_chances) < 1 << 31


def _shadowed(cfg) -> bool:
    """Whether E6 compares with trial t−1's r̃ (the paper's rule), which a jump leaves unwritten."""
    return cfg.agent.failure_memory and cfg.agent.failure_rule == "previous_trial"


def state_bytes_per_seed(env: Env, cfg) -> int:
    """Bytes of one lane's state in the flat loop (tables, memory, log, r̃, counters)."""
    cfg = cfg.resolve(env)
    shapes = jax.eval_shape(lambda w: flat_init(env, cfg, w), jax.ShapeDtypeStruct((2,), np.uint32))
    return int(sum(np.prod(x.shape) * x.dtype.itemsize for x in jax.tree.leaves(shapes)))
