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

A user's key enters through `root_key_int` (a run's 32-bit root, as a run folder records it)
or `as_key` (any JAX key, traced or not): see `root_key_int` for how a JAX key maps.
SPEC ids (G1…, E1…, B1…, R1…) are defined in docs/SPEC.md.
"""

from __future__ import annotations

import numbers

import jax
import jax.numpy as jnp
import numpy as np

from jaxeac.errors import KEY_LIMIT
from jaxeac.pytree import pytree_dataclass

KEY_IMPL = "threefry2x32"  # the PRNG whose two key words `seed_words` feeds to `step_uniform`


def _is_traced(value) -> bool:
    return isinstance(value, jax.core.Tracer)


def _is_new_key(value) -> bool:
    """A new-style JAX key array (``jax.random.key``), traced or not."""
    return isinstance(value, jax.Array) and jax.dtypes.issubdtype(value.dtype, jax.dtypes.prng_key)


def _is_legacy_key(value) -> bool:
    """A legacy raw key (``jax.random.PRNGKey``): uint32 [2], a JAX or NumPy array, traced or not."""
    return (isinstance(value, jax.Array | np.ndarray) and value.dtype == np.uint32
            and tuple(value.shape) == (2,))


def _key_range(name: str) -> str:
    return (f"pass an integer in 0..{KEY_LIMIT - 1} (2^32 - 1), jax.random.key(k) or "
            f"jax.random.PRNGKey(k) with k in that range")


def _check_int_key(value, name: str) -> int:
    key = int(value)
    if not 0 <= key < KEY_LIMIT:
        alias = (f"; JAX keeps only k mod 2^32, so it would silently give key {key % KEY_LIMIT}'s run"
                 if key >= KEY_LIMIT or key < 0 else "")
        raise ValueError(f"{name} must lie in 0..{KEY_LIMIT - 1} (got {key}){alias}; {_key_range(name)}")
    return key


def root_key_int(key, name: str = "root_key") -> int:
    """The run's 32-bit root (R1) from a user's key; seed i's key is ``fold_in(jax.random.key(root), i)``.

    * An integer k in 0..2^32−1 (Python or NumPy, or a 0-d integer array; not a bool): k.
      Others are refused (ValueError): JAX keeps only k mod 2^32, so 2^40 would run key 0's
      seeds and −1 key 2^32−1's.
    * A JAX key of the default threefry2x32 PRNG, new-style (``jax.random.key(k)``, shape ())
      or legacy (``jax.random.PRNGKey(k)``, uint32 [2], a NumPy copy too): its two data words
      (`jax.random.key_data`) are [0, k] for every k in 0..2^32−1, and the root is k, so
      ``key(7)``, ``PRNGKey(7)`` and ``7`` give the same run. A key whose first word is not 0
      (from ``split`` or ``fold_in``) has no 32-bit root: ValueError (pass the integer it was
      made from). A key is data, not the int it came from: JAX has already folded an int
      outside 0..2^32−1 into 32 bits when it built the key (``key(-1)`` is ``key(2**32 - 1)``).

    A value traced under jit/vmap cannot be checked: TypeError (use `as_key` inside traced code).
    Anything else: TypeError naming `name`, the value and what to pass.
    """
    if _is_traced(key):
        raise TypeError(f"{name} must be a concrete value, not one traced under jit/vmap (got {key!r}); "
                        "pass it from outside the traced function")
    if _is_new_key(key) or _is_legacy_key(key):
        if _is_new_key(key):
            impl = str(jax.random.key_impl(key))
            if key.shape != () or impl != KEY_IMPL:
                raise TypeError(f"{name} must be one {KEY_IMPL} key (got a key array of shape {key.shape}, "
                                f"impl {impl}); {_key_range(name)}")
            words = np.asarray(jax.random.key_data(key)).reshape(-1)
        else:
            words = np.asarray(key).reshape(-1)
        if int(words[0]) != 0:
            raise ValueError(f"{name} is a JAX key with data words [{int(words[0])}, {int(words[1])}]: "
                             "a run's root is 32-bit, and only a key made from an integer k in "
                             f"0..{KEY_LIMIT - 1} (words [0, k]) has one; keys from split or fold_in "
                             f"do not; {_key_range(name)}")
        return int(words[1])
    if isinstance(key, bool | np.bool_):
        raise TypeError(f"{name} must be an integer key, not a bool (got {key!r}); {_key_range(name)}")
    if isinstance(key, numbers.Integral):
        return _check_int_key(key, name)
    if isinstance(key, numbers.Real):  # 1.5, 2.0, NaN: a number, but no integer key
        raise ValueError(f"{name} must be an integer (got {key!r}); {_key_range(name)}")
    if (isinstance(key, jax.Array | np.ndarray) and key.shape == ()
            and np.issubdtype(key.dtype, np.integer)):
        return _check_int_key(key, name)
    raise TypeError(f"{name} must be an integer or a JAX key (got {key!r} of type {type(key).__name__}); "
                    f"{_key_range(name)}")


def as_key(key, name: str = "key") -> jax.Array:
    """A new-style threefry2x32 key from a user's key, usable inside traced code: a JAX key
    (new-style, or legacy uint32 [2]: wrapped, the same words) is kept as it is, traced or not
    (any key, e.g. a seed's, from ``fold_in``); an integer becomes ``jax.random.key(root_key_int(k))``
    (refused outside 0..2^32−1). Anything else: TypeError naming `name`."""
    if _is_new_key(key):
        impl = str(jax.random.key_impl(key))
        if key.shape != () or impl != KEY_IMPL:
            raise TypeError(f"{name} must be one {KEY_IMPL} key (got a key array of shape {key.shape}, "
                            f"impl {impl}; vmap over a batch of keys)")
        return key
    if _is_legacy_key(key):
        return jax.random.wrap_key_data(jnp.asarray(key), impl=KEY_IMPL)
    if _is_traced(key):
        raise TypeError(f"{name} must be a JAX key when traced (got {key!r}); "
                        "pass jax.random.key(k), or the integer k from outside the traced function")
    return jax.random.key(root_key_int(key, name))


def check_seed_index(seed, name: str = "seed") -> None:
    """A concrete seed index must be an integer in 0..2^32−1 (`fold_in` keeps 32 bits; R1);
    traced ones are not checked."""
    if _is_traced(seed) or (isinstance(seed, jax.Array | np.ndarray) and seed.ndim > 0):
        return
    if isinstance(seed, bool | np.bool_) or not isinstance(seed, numbers.Integral | np.ndarray | jax.Array) \
            or not np.issubdtype(np.asarray(seed).dtype, np.integer):
        raise TypeError(f"{name} must be an integer seed index (got {seed!r}); pass e.g. 0")
    if not 0 <= int(seed) < KEY_LIMIT:
        raise ValueError(f"{name} must lie in 0..{KEY_LIMIT - 1} (got {int(seed)}); "
                         "pass a seed index in range")


def seed_key(root_key, seed) -> jax.Array:
    """R1: the key of seed i is ``fold_in(root_key, i)``. `root_key`: a JAX key (kept as it is,
    traced or not) or an integer k in 0..2^32−1 (``jax.random.key(k)``); see `as_key`."""
    check_seed_index(seed)
    return jax.random.fold_in(as_key(root_key, "root_key"), seed)


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
