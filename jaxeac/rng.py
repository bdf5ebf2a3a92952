"""Random numbers of a run, in one place (SPEC R1, R2).

Seed i of a run has the key ``fold_in(root_key, i)`` (R1), so its results never
depend on the seeds beside it, the chunk size or the device count. Within a seed,
every draw of the agent comes from `step_uniform`: a counter-based hash of the
seed's key words and a counter naming the draw, (trial, chance) for the E1 choice
and (trial, C) for the start cell (G3). A stochastic environment's transitions draw from
a second stream of counters (`transition_uniform`, X1), SARSA's bootstrap action at a
trial's last chance from a third (`bootstrap_uniform`). No key is split per step, every
loop (the literal trials loop, the flat loop, the fused GPU kernel, bowling) draws the
same numbers, and the same root key gives bit-identical results (R2).
Bowling's execution noise (B3) comes from ``fold_in(fold_in(seed_key, trial), chance)``.
SPEC ids (G1…, E1…, B1…, R1…) are defined in docs/SPEC.md.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxeac.pytree import pytree_dataclass


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


def action_uniform(words, trial, chance, n_chances: int) -> jax.Array:
    """E1: the uniform that picks the action at (trial, chance) of the seed with key words `words`."""
    return step_uniform(words, action_counter(trial, chance, n_chances))


def start_uniform(words, trial, n_chances: int) -> jax.Array:
    """G3: the uniform that picks the start of trial `trial` (the counter after its C chances)."""
    return step_uniform(words, action_counter(trial, n_chances, n_chances))


def uniform_index(u, n: int) -> jax.Array:
    """The index ⌊u·n⌋ in 0…n−1 that a uniform u ∈ [0, 1) picks uniformly."""
    return jnp.minimum((u * n).astype(jnp.int32), n - 1)


def start_index(words, trial, n_chances: int, n_starts: int) -> jax.Array:
    """G3: the start cell (index into the free non-goal cells) of trial `trial`, uniform."""
    return uniform_index(start_uniform(words, trial, n_chances), n_starts)


#: Counter streams: the agent's counters stay far below 2^30; other streams set a top bit.
TRANSITION_STREAM = 1 << 31
BOOTSTRAP_STREAM = 1 << 30


def _stream_counter(trial, chance, n_chances: int, stream: int) -> jax.Array:
    """uint32: the counter of (trial, chance) in another stream (its top bit set)."""
    return jnp.asarray(action_counter(trial, chance, n_chances)).astype(jnp.uint32) | jnp.uint32(stream)


def transition_uniform(words, trial, chance, n_chances: int) -> jax.Array:
    """X1: the uniform a stochastic environment's move at (trial, chance) draws its outcome with."""
    return step_uniform(words, _stream_counter(trial, chance, n_chances, TRANSITION_STREAM))


def bootstrap_uniform(words, trial, chance, n_chances: int) -> jax.Array:
    """X3: SARSA's next action at (trial, chance): the E1 uniform of that chance while it exists
    (the agent takes that action next), else one of its own stream (the trial's last chance)."""
    own = step_uniform(words, _stream_counter(trial, chance, n_chances, BOOTSTRAP_STREAM))
    return jnp.where(chance < n_chances, action_uniform(words, trial, chance, n_chances), own)


def chance_key(words, trial, chance, n_chances: int) -> jax.Array:
    """X1: a JAX key for a keyed environment's draw at (trial, chance) (chance C: the reset),
    from the transition stream's counter: adapters of `reset(key)`/`step(key, ...)` APIs."""
    counter = _stream_counter(trial, chance, n_chances, TRANSITION_STREAM)
    return jax.random.fold_in(jax.random.wrap_key_data(words, impl="threefry2x32"), counter)


def throw_key(key: jax.Array, trial, chance) -> jax.Array:
    """B3: the key of the execution noise of throw (trial, chance) of the seed with key `key`."""
    return jax.random.fold_in(jax.random.fold_in(key, trial), chance)


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
        jax.vmap(lambda c: action_uniform(words, trial, c, n_chances))(chances),
    )
