"""Per-chunk sums of the curves on the device, the Gaussian draws built on them, and exact
random halves of the seeds for the calibration: the large-N path's curve pieces (SPEC §6 "At
very many seeds"; methods and references in `jaxeac.stats.large`).
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxeac.bits import SuccessBits, trial_masks
from jaxeac.stats._rng import host_rng, hypergeometric_counts, mulhi32, random_words

#: Seeds per block in the device sums (float32 sums of 0..100 stay exact integers below 2^24).
BLOCK = 65_536


@partial(jax.jit, static_argnames=("block",))
def _gram(c, block: int):
    n, T = c.shape
    pad = (-n) % block
    c = jnp.pad(c, ((0, pad), (0, 0))).reshape(-1, block, T)

    def body(acc, x):
        x = x.astype(jnp.float32)
        g = lax.dot_general(x, x, (((0,), (0,)), ((), ())), preferred_element_type=jnp.float32)
        return (acc[0] + g.astype(jnp.int32), acc[1] + x.sum(0).astype(jnp.int32)), None

    init = (jnp.zeros((T, T), jnp.int32), jnp.zeros((T,), jnp.int32))
    (g, s), _ = lax.scan(body, init, c)
    return g, s


#: Seeds per call of `device_codes` (at 200 trials: 100 MB of bits in, 64 MB of integers out).
CODES_BLOCK = 1 << 22


@partial(jax.jit, static_argnames=("trials", "late"))
def _codes(bits, trials: int, late: int):
    """`jaxeac.stats.measures._codes_of_bits` on the device, the same integers (int32 [n] each):
    per byte its set bits and the sum of their positions, by population counts."""
    n, width = bits.shape
    keep, in_late = trial_masks(width, trials, late)
    b = bits & jnp.asarray(keep)

    def ones(x):
        return lax.population_count(x).astype(jnp.int32)

    per_byte = ones(b)
    count = per_byte.sum(1)
    late_count = ones(b & jnp.asarray(in_late)).sum(1)
    nonzero = b != 0
    j = jnp.argmax(nonzero, axis=1).astype(jnp.int32)
    x = jnp.take_along_axis(b, j[:, None], axis=1)[:, 0]
    lowest = ones((x & (jnp.uint8(0) - x)) - jnp.uint8(1))  # the lowest set bit's position
    first = jnp.where(nonzero.any(1), 8 * j + lowest + 1, trials + 1)
    positions = ones(b & jnp.uint8(0xAA)) + 2 * ones(b & jnp.uint8(0xCC)) + 4 * ones(b & jnp.uint8(0xF0))
    weights = jnp.asarray(trials - 8 * np.arange(width), jnp.int32)
    area = (per_byte * weights).sum(1) - positions.sum(1)  # integer products: exact
    return count, late_count, first, area


def device_codes(c: SuccessBits, late: int) -> tuple[np.ndarray, ...]:
    """(successes, late successes, first success or T + 1, Σ_t success_t (T − t)) of every row of
    `c`, as `jaxeac.stats.measures` computes them on the host (int32 [n] each), on the device:
    the packed rows travel, `CODES_BLOCK` seeds a call, all dispatched before any is read."""
    parts = [_codes(jnp.asarray(c.bits[i:i + CODES_BLOCK]), c.trials, late)
             for i in range(0, c.bits.shape[0], CODES_BLOCK)]
    return tuple(np.concatenate([np.asarray(p[k]) for p in parts]) for k in range(4))


def _small_integers(c: np.ndarray, block: int = BLOCK, power: int = 2) -> bool:
    """Whether c fits int8 and per-block float32 sums of products of `power` entries are exact
    (below 2^24) with int32 totals."""
    if c.dtype == np.bool_:
        return c.shape[0] < 2**31
    if not np.issubdtype(c.dtype, np.integer):
        return False
    m = int(np.abs(c).max(initial=0)) ** power
    return m <= 127**power and m * block < 2**24 and m * c.shape[0] < 2**31


@partial(jax.jit, static_argnames=("trials",))
def _unpack_bits(bits, trials: int):
    """bool [n, T] on the device from `SuccessBits.bits` [n, ⌈T/8⌉] (bit t of a row = trial t)."""
    shifts = jnp.arange(8, dtype=jnp.uint8)
    unpacked = (bits[:, :, None] >> shifts) & jnp.uint8(1)
    return unpacked.reshape(bits.shape[0], -1)[:, :trials].astype(jnp.bool_)


def on_device(c):
    """Curves on the device: `SuccessBits` travel packed (1/8 of the bytes) and unpack there."""
    if isinstance(c, SuccessBits):
        return _unpack_bits(jnp.asarray(c.bits), c.trials)
    return jnp.asarray(c)


def curve_moments(c) -> dict:
    """Seeds n, per-trial sums s [T] and cross-products G = cᵀc [T, T] of curves [n, T].

    Integer curves (success, pins) are summed on the device in blocks of `BLOCK` seeds
    (float32 products, exact below 2^24, totals in int32), others in float64 on the host.
    `SuccessBits` are unpacked on the device. Returns a function that waits for the device
    and gives the dict.
    """
    if isinstance(c, SuccessBits):
        dev = _gram(on_device(c), BLOCK)
    elif _small_integers(c := np.asarray(c)):
        dev = _gram(jnp.asarray(c.astype(np.int8) if c.dtype != np.bool_ else c), BLOCK)
    else:
        x = c.astype(np.float64)
        res = {"n": c.shape[0], "s": x.sum(0), "G": x.T @ x}
        return lambda: res

    def wait():
        g, s = (np.asarray(v, np.float64) for v in dev)
        return {"n": c.shape[0], "s": s, "G": g}

    return wait


def covariance(m: dict) -> np.ndarray:
    """Unbiased per-trial covariance from curve moments."""
    n, s, G = m["n"], m["s"], m["G"]
    mean = s / n
    return (G - n * np.outer(mean, mean)) / (n - 1)


def _sqrt_psd(cov: np.ndarray) -> np.ndarray:
    w, v = np.linalg.eigh((cov + cov.T) / 2)
    return v * np.sqrt(np.clip(w, 0, None))


def gaussian_draws(rng: np.random.Generator, cov: np.ndarray, reps: int, chunk: int = 2000):
    """`reps` draws of N(0, cov) as rows [reps, T] (through the symmetric square root)."""
    root = _sqrt_psd(cov)
    out = np.empty((reps, cov.shape[0]))
    for i in range(0, reps, chunk):
        k = min(chunk, reps - i)
        out[i : i + k] = rng.standard_normal((k, cov.shape[0])) @ root.T
    return out


def gaussian_max_abs(rng: np.random.Generator, cov: np.ndarray, reps: int) -> np.ndarray:
    """max_t |Z_t| over trials with positive variance, Z ~ N(0, corr(cov)), `reps` draws."""
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    ok = sd > 0
    if not ok.any():
        return np.zeros(reps)
    corr = cov[np.ix_(ok, ok)] / np.outer(sd[ok], sd[ok])
    return np.abs(gaussian_draws(rng, corr, reps)).max(1)


@partial(jax.jit, static_argnames=("block", "exact", "steps"))
def _subset_sums(key, c, need, block: int, exact: bool, steps: int = 32):
    """Column sums of c [n, T] over uniform subsets given their counts per block of `block`
    seeds, need [S, B]: selection sampling (Knuth Algorithm S) inside every (subset, block)
    at once, one scan step per position in the block (words of position i from
    fold_in(key, i)); the sums are taken `steps` positions at a time, as one matmul."""
    n, T = c.shape
    S, B = need.shape
    pad = B * block - n
    cb = jnp.pad(c, ((0, pad), (0, 0))).reshape(B, block // steps, steps, T).transpose(1, 2, 0, 3)
    sizes = jnp.minimum(n - jnp.arange(B, dtype=jnp.int32) * block, block)  # seeds in each block
    acc_type = jnp.int32 if exact else jnp.float32

    def select(need, i):
        rem = sizes - i  # seeds left in each block, this one included; <= 0: padding
        words = random_words(jax.random.fold_in(key, i), (S, B))
        take = (mulhi32(words, jnp.maximum(rem, 1).astype(jnp.uint32)[None]) < need) & (rem > 0)[None]
        return need - take.astype(jnp.uint32), take

    def chunk(carry, xs):
        need, acc = carry
        j, x = xs  # x: [steps, B, T], the seeds at positions j·steps ... in every block
        need, takes = lax.scan(select, need, j * steps + jnp.arange(steps))  # [steps, S, B]
        part = lax.dot_general(
            takes.astype(jnp.float32),
            x.astype(jnp.float32),
            (((0, 2), (0, 1)), ((), ())),
            preferred_element_type=jnp.float32,
        )
        return (need, acc + part.astype(acc_type)), None

    init = (need.astype(jnp.uint32), jnp.zeros((S, T), acc_type))
    (left, acc), _ = lax.scan(chunk, init, (jnp.arange(block // steps), cb))
    return acc, left


def dispatch_subset_sums(key, c: np.ndarray, k: int, reps: int, block: int = 4096):
    """Start the column sums [reps, T] of c [n, T] over `reps` uniform k-of-n subsets of the
    seeds, exactly: the subset's counts per block of `block` seeds are multivariate
    hypergeometric (drawn on the host under `key`), then each block's members come from
    selection sampling on the device (under fold_in(key, 1)). Sums are exact for small
    integers (success, pins and their squares), float32 otherwise. `SuccessBits` are
    unpacked on the device."""
    bits = isinstance(c, SuccessBits)
    c = c if bits else np.asarray(c)
    n = c.shape[0]
    nblocks = -(-n // block)
    sizes = np.minimum(n - np.arange(nblocks) * block, block)
    need = hypergeometric_counts(host_rng(key), sizes, k, reps).astype(np.int32)
    steps = 32 if block % 32 == 0 else 1  # positions per matmul
    if bits:
        exact, dev = True, on_device(c)
    else:
        exact = _small_integers(c, block=steps * nblocks, power=1)
        dev = jnp.asarray(c if c.dtype == np.bool_ else c.astype(np.int8) if exact else c.astype(np.float32))
    acc, left = _subset_sums(jax.random.fold_in(key, 1), dev, jnp.asarray(need), block, exact, steps)

    def wait():
        if np.asarray(left).any():  # Algorithm S takes exactly the count asked of each block
            raise AssertionError("subset draw left units unselected")
        return np.asarray(acc, np.float64)

    return wait
