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


def program_key(env: Env):
    """What a compiled program of `env` depends on: its `program_key()` where its tables are the
    program's inputs (`jaxeac.envs.tabular.TabularEnv`: tasks of one layout share a program), else
    the environment itself."""
    key = getattr(env, "program_key", None)
    return key() if key is not None else env


def program_inputs(env: Env) -> dict:
    """The tables a compiled program of `env` takes as arguments (empty: they are part of it)."""
    inputs = getattr(env, "program_inputs", None)
    return inputs() if inputs is not None else {}


def program_cache_key(env: Env, *parts):
    """(`program_key`, *parts) as a dict key for answers shared by the tasks of one program, or None
    where it is unhashable (an env or rate that is not): then asked every time."""
    key = (program_key(env), *parts)
    try:
        hash(key)
    except TypeError:
        return None
    return key


def bind_inputs(env: Env, inputs: dict) -> Env:
    """`env` as its compiled program sees it: reading `inputs` (traced) as its tables."""
    return env.bind(inputs) if inputs else env


#: `state_bytes_per_seed`'s answers by (`program_key`, resolved config): a study's up-front checks
#: ask 8 algorithms x 11 tasks, 88 traces (0.97 s on a 2-core CPU) where its programs need 8.
_STATE_BYTES: dict = {}


def state_bytes_per_seed(env: Env, cfg) -> int:
    """Bytes of one lane's state in the flat loop (tables, memory, log, r̃, counters) as its compiled
    program holds it: traced on the environment the program binds (`bind_inputs`: a tabular
    layout's padded tables), so the tasks of one program share one answer, traced once."""
    cfg = cfg.resolve(env)
    key = program_cache_key(env, cfg)
    if key in _STATE_BYTES:
        return _STATE_BYTES[key]
    tables = {k: jax.ShapeDtypeStruct(np.shape(v), jax.dtypes.canonicalize_dtype(np.asarray(v).dtype))
              for k, v in program_inputs(env).items()}  # as the program takes them (float64 -> float32)
    shapes = jax.eval_shape(lambda w, t: flat_init(bind_inputs(env, t), cfg, w),
                            jax.ShapeDtypeStruct((2,), np.uint32), tables)
    size = int(sum(np.prod(x.shape) * x.dtype.itemsize for x in jax.tree.leaves(shapes)))
    if key is not None:
        _STATE_BYTES[key] = size
    return size
