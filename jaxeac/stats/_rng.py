"""Fast counter-based random draws for resampling (SPEC §6).

`jax.random.bits` is slow on CPU for the ~10^8 draws a 10,000-resample
bootstrap over 10,000 seeds needs. Here the same Threefry-2x32 block cipher
(Salmon et al. 2011, "Parallel random numbers: as easy as 1, 2, 3"; 20 rounds,
the function behind `jax.random`) is written as plain `jnp` integer ops so XLA
fuses it into one loop; the key words come from an ordinary `jax.random` key,
so every draw is reproducible from the key recorded in the output.

Two samplers build on it:

* `uniform_index`: integers in [0, n) by Lemire's multiply-high
  (Lemire 2019, "Fast random integer generation in an interval"), bias < n/2^32.
* `random_subsets`: exactly-k-of-n subsets, uniform over all C(n, k), by
  selection sampling (Knuth, TAOCP Vol. 2, §3.4.2, Algorithm S; Fan, Muller &
  Rezucha 1962), one `lax.scan` over units, vectorised over resamples. This is
  the label draw of a permutation test, without sorting.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxeac.rng import as_key

_ROT = ((13, 15, 26, 6), (17, 29, 16, 24))
_PARITY = 0x1BD11BDA
_LO16 = 0xFFFF


def warm_key_programs() -> None:
    """Run once the eager key derivations a comparison makes (a key from an int, `fold_in`, a
    split in two and in three), so their small device programs exist before it needs them.
    On a GPU they took about 1.4 s to compile on a first run (up to ~0.5 s apiece), and a comparison
    waited on all of them after the run; `jaxeac grid` calls this on its compile-ahead thread
    while the run computes.
    The derived keys are thrown away: later calls only find the programs compiled."""
    key = as_key(0)
    jax.random.fold_in(key, 1)
    _ = tuple(jax.random.split(key))
    _ = tuple(jax.random.split(key, 3))


def key_words(key: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The two uint32 words of a threefry key."""
    data = jax.random.key_data(key).reshape(-1)
    return data[0], data[1]


def _rotl(x: jax.Array, d: int) -> jax.Array:
    return (x << jnp.uint32(d)) | (x >> jnp.uint32(32 - d))


def threefry2x32(k0: jax.Array, k1: jax.Array, x0: jax.Array, x1: jax.Array):
    """Threefry-2x32 with 20 rounds (Salmon et al. 2011), as in `jax.random`."""
    k2 = k0 ^ k1 ^ jnp.uint32(_PARITY)
    ks = (k0, k1, k2)
    x0 = x0 + k0
    x1 = x1 + k1
    for i in range(5):
        for r in _ROT[i % 2]:
            x0 = x0 + x1
            x1 = _rotl(x1, r)
            x1 = x0 ^ x1
        x0 = x0 + ks[(i + 1) % 3]
        x1 = x1 + ks[(i + 2) % 3] + jnp.uint32(i + 1)
    return x0, x1


def random_words(key: jax.Array, shape: tuple[int, ...]) -> jax.Array:
    """uint32 words of `shape`: threefry of the counters 0..size-1 under `key`."""
    size = 1
    for s in shape:
        size *= s
    half = (size + 1) // 2
    k0, k1 = key_words(key)
    c = lax.iota(jnp.uint32, half)
    a, b = threefry2x32(k0, k1, c, jnp.zeros_like(c))
    return jnp.concatenate([a, b])[:size].reshape(shape)


def mulhi32(b: jax.Array, n: jax.Array) -> jax.Array:
    """floor(b * n / 2^32) for uint32 b, n, exact, using 16-bit limbs (no uint64)."""
    n = jnp.asarray(n, jnp.uint32)
    bh, bl = b >> 16, b & jnp.uint32(_LO16)
    nh, nl = n >> 16, n & jnp.uint32(_LO16)
    mid1 = bh * nl + ((bl * nl) >> 16)
    mid2 = bl * nh + (mid1 & jnp.uint32(_LO16))
    return bh * nh + (mid1 >> 16) + (mid2 >> 16)


def uniform_index(key: jax.Array, shape: tuple[int, ...], n: int) -> jax.Array:
    """int32 indices uniform on [0, n) (multiply-high; Lemire 2019); n is static."""
    b = random_words(key, shape)
    if n <= _LO16:  # n < 2^16: hi16*n + (lo16*n >> 16) < 2^32, one limb product fewer
        nn = jnp.uint32(n)
        return ((((b >> 16) * nn) + (((b & jnp.uint32(_LO16)) * nn) >> 16)) >> 16).astype(jnp.int32)
    return mulhi32(b, jnp.uint32(n)).astype(jnp.int32)


def random_subsets(key: jax.Array, n: int, k: int, reps: int, dtype=jnp.bool_) -> jax.Array:
    """[n, reps] of `dtype` (bool, or 0/1 floats for a matmul): column r marks a
    uniform random k-subset of n units.

    Selection sampling (Knuth Algorithm S): unit i is taken with probability
    need/(n - i), so every column holds exactly k ones and all C(n, k) subsets
    are equally likely. The words are drawn up front in one fused pass; the scan
    over units only compares and counts.
    """
    if not 0 <= k <= n:
        raise ValueError(f"subset size {k} not in [0, {n}]")
    words = random_words(key, (n, reps))
    remaining = jnp.uint32(n) - lax.iota(jnp.uint32, n)

    def body(need, x):
        w, rem = x
        take = mulhi32(w, rem) < need  # uniform integer in [0, rem) < need
        return need - take.astype(jnp.uint32), take.astype(dtype)

    _, takes = lax.scan(body, jnp.full((reps,), k, jnp.uint32), (words, remaining))
    return takes


def host_rng(key) -> np.random.Generator:
    """A NumPy generator seeded from the words of a JAX key (the same on every device)."""
    words = np.asarray(jax.random.key_data(key), np.uint32).reshape(-1)
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence([int(w) for w in words])))


def multinomial_counts(rng: np.random.Generator, counts: np.ndarray, resamples: int) -> np.ndarray:
    """Bootstrap resamples as counts per value: Mult(n, counts/n), [R, D] float64."""
    counts = np.asarray(counts, np.int64)
    n = int(counts.sum())
    return rng.multinomial(n, counts / n, size=resamples).astype(np.float64)


def hypergeometric_counts(rng: np.random.Generator, counts: np.ndarray, n_take: int, reps: int):
    """Counts per value of `reps` uniform n_take-subsets of the units: [reps, D] float64."""
    counts = np.asarray(counts, np.int64)
    return rng.multivariate_hypergeometric(counts, int(n_take), size=reps, method="marginals").astype(
        np.float64
    )


def key_record(key) -> dict:
    """stats.json's record of the comparison's key: the int seed (if one) and the key's words."""
    k = as_key(key)
    return {
        "seed": key if isinstance(key, int) else None,
        "key_data": np.asarray(jax.random.key_data(k)).tolist(),
    }
