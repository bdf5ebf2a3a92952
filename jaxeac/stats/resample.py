"""Chunked, jitted bootstrap and permutation draws reduced to column sums (SPEC §6).

Every statistic in the comparison is a function of per-group sums of a few
columns (a measure, its square, the per-trial successes), so one draw of
resampling weights serves all of them:

* bootstrap: multinomial counts c [R, n] (n uniform indices per resample,
  scatter-added), then sums = c @ Z — one BLAS matmul (Efron 1979);
* permutation: exactly-n_t-of-N label sets L [N, R] (Knuth Algorithm S), then
  treatment sums = Lᵀ @ Z (Fisher 1935; Pitman 1937).

Draws are made `chunk` resamples at a time under one jitted function with
static shapes, so memory stays bounded (≈ chunk · n floats) for any R;
chunk c uses `jax.random.fold_in(key, c)` (inside the jitted function, so
dispatching the next chunk never waits for the last), and results depend only
on (key, R, chunk). This is the path up to `large.LARGE_N` seeds per method; above
it, work per resample must not grow with the seeds (`jaxeac.stats.large`).
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from jaxeac.stats._rng import random_subsets, uniform_index

IQM_BLOCK = 128
# chunk x units per draw: ~80 MB per [chunk, n] float32 buffer; keeps the flat int32 index < 2^31
MAX_CHUNK_ELEMENTS = 20_000_000


def _cap(chunk: int, resamples: int, n: int) -> int:
    """Chunk size, lowered for very many seeds so one chunk's buffers stay bounded."""
    return max(1, min(chunk, resamples, MAX_CHUNK_ELEMENTS // max(n, 1)))


def _smallest_sum(k, counts_b, values_b, bc, bcv_cum, h_cum):
    """Sum of the k smallest values of each resample, from counts over value-sorted units.

    counts_b / values_b: [C, nb, B] counts and values in blocks; bc: block counts;
    h_cum / bcv_cum: inclusive cumulative block counts / count-weighted sums.
    """
    chunk = counts_b.shape[0]
    j = jnp.sum(h_cum < k, axis=1)  # block holding position k (0-based, 1 per row)
    j = jnp.minimum(j, bc.shape[1] - 1)
    rows = jnp.arange(chunk)
    before_c = h_cum[rows, j] - bc[rows, j]
    before_s = jnp.where(j > 0, bcv_cum[rows, jnp.maximum(j - 1, 0)], 0.0)
    c = counts_b[rows, j]  # [C, B]
    v = values_b[j]  # [C, B]
    need = (k - before_c)[:, None]
    cc = jnp.cumsum(c, axis=1) - c
    part = jnp.clip(need - cc, 0.0, c)
    return before_s + jnp.sum(part * v, axis=1)


def _counts(key, c, n: int, chunk: int):
    """The bootstrap draw, defined once: chunk c's resamples as counts per unit [chunk, n] (n uniform
    indices per resample under fold_in(key, c), scatter-added)."""
    idx = uniform_index(jax.random.fold_in(key, c), (chunk, n), n)
    flat = (idx + (jnp.arange(chunk, dtype=jnp.int32) * n)[:, None]).reshape(-1)
    counts = jnp.zeros((chunk * n,), jnp.float32).at[flat].add(1.0, mode="promise_in_bounds")
    return counts.reshape(chunk, n)


_counts_chunk = jax.jit(_counts, static_argnames=("n", "chunk"))
_counts_chunk_t = jax.jit(lambda key, c, n, chunk: _counts(key, c, n, chunk).T,
                          static_argnames=("n", "chunk"))


def boot_counts(key, n: int, resamples: int, *, chunk: int = 1000, units_first: bool = False) -> np.ndarray:
    """Bootstrap resamples of n units as counts per unit, [resamples, n] float32 ([n, resamples]
    with `units_first`, the layout in which cumulative counts over units and row gathers are fast
    in NumPy): the draws `bootstrap_sums` makes under the same key (so its sums are these counts
    times the rows)."""
    chunk = _cap(chunk, resamples, n)
    if units_first:
        parts = [_counts_chunk_t(key, c, n, chunk) for c in range(-(-resamples // chunk))]
        return np.concatenate([np.asarray(p) for p in parts], axis=1)[:, :resamples]
    parts = [_counts_chunk(key, c, n, chunk) for c in range(-(-resamples // chunk))]
    return np.concatenate([np.asarray(p) for p in parts])[:resamples]


def cumulative(ct: np.ndarray, *, zero_row: bool = False) -> np.ndarray:
    """Inclusive cumulative sums over the rows of ct [D, R] (units first), row by row: NumPy's
    cumsum along axis 0 is several times slower; the additions are in the same order. With
    `zero_row` a row of zeros leads, so row i holds the sum of the first i rows."""
    out = np.empty((ct.shape[0] + 1, ct.shape[1]), ct.dtype)
    out[0] = 0
    for i in range(ct.shape[0]):
        np.add(out[i], ct[i], out=out[i + 1])
    return out if zero_row else out[1:]


@partial(jax.jit, static_argnames=("chunk", "iqm"))
def _boot_chunk(key, c, z, chunk: int, iqm: bool):
    n = z.shape[0]
    counts = _counts(key, c, n, chunk)
    sums = counts @ z
    if not iqm:
        return sums, jnp.zeros((chunk,), jnp.float32)
    # IQM of each resample without sorting it (rows of z sorted by column 0): the kept
    # positions [g, n - g) of the sorted resample sum to F(n - g) - F(g), F(k) = sum of
    # the k smallest; F comes from block sums plus one within-block cumsum per row.
    g = n // 4
    pad = (-n) % IQM_BLOCK
    nb = (n + pad) // IQM_BLOCK
    counts_b = jnp.pad(counts, ((0, 0), (0, pad))).reshape(chunk, nb, IQM_BLOCK)
    values_b = jnp.pad(z[:, 0], (0, pad)).reshape(nb, IQM_BLOCK)
    bc = counts_b.sum(-1)
    bcv_cum = jnp.cumsum((counts_b * values_b).sum(-1), axis=1)
    h_cum = jnp.cumsum(bc, axis=1)
    args = (counts_b, values_b, bc, bcv_cum, h_cum)
    trimmed = _smallest_sum(n - g, *args) - _smallest_sum(g, *args)
    return sums, trimmed / (n - 2 * g)


@partial(jax.jit, static_argnames=("chunk", "n_treat"))
def _perm_chunk(key, c, z, chunk: int, n_treat: int):
    labels = random_subsets(jax.random.fold_in(key, c), z.shape[0], n_treat, chunk)
    return labels.astype(jnp.float32).T @ z


def dispatch_bootstrap(key, z, resamples: int, *, chunk: int = 1000, iqm: bool = False):
    """Start the bootstrap chunks without waiting (JAX dispatches asynchronously).

    Returns a function that waits and gives (sums [R, K] float64, iqm [R] float64 or None).
    """
    z = np.asarray(z)
    if iqm:  # sums do not depend on the order of rows; the IQM needs them sorted by column 0
        z = z[np.argsort(z[:, 0], kind="stable")]
    z = jnp.asarray(z, jnp.float32)
    chunk = _cap(chunk, resamples, z.shape[0])
    parts = [_boot_chunk(key, c, z, chunk, iqm) for c in range(-(-resamples // chunk))]

    def result():
        sums = np.concatenate([np.asarray(s, np.float64) for s, _ in parts])[:resamples]
        q = np.concatenate([np.asarray(q, np.float64) for _, q in parts])[:resamples] if iqm else None
        return sums, q

    return result


def bootstrap_sums(key, z, resamples: int, *, chunk: int = 1000, iqm: bool = False):
    """Column sums of `resamples` bootstrap resamples of the rows of z [n, K].

    Returns (sums [R, K] float64, iqm [R] float64 or None). With iqm=True the IQM
    (25 % trimmed mean, as `scipy.stats.trim_mean(x, 0.25)`) of column 0 of each
    resample is returned too.
    """
    return dispatch_bootstrap(key, z, resamples, chunk=chunk, iqm=iqm)()


def dispatch_permutation(key, z_pool, n_treat: int, resamples: int, *, chunk: int = 1000):
    """Start the permutation chunks without waiting; returns a function giving sums [R, K]."""
    z = jnp.asarray(z_pool, jnp.float32)
    chunk = _cap(chunk, resamples, z.shape[0])
    parts = [_perm_chunk(key, c, z, chunk, int(n_treat)) for c in range(-(-resamples // chunk))]
    return lambda: np.concatenate([np.asarray(p, np.float64) for p in parts])[:resamples]


def permutation_sums(key, z_pool, n_treat: int, resamples: int, *, chunk: int = 1000):
    """Treatment-group column sums [R, K] under `resamples` random relabellings of z_pool [N, K]."""
    return dispatch_permutation(key, z_pool, n_treat, resamples, chunk=chunk)()


_subsets = jax.jit(random_subsets, static_argnums=(1, 2, 3))


def dispatch_subsets(key, n: int, k: int, reps: int):
    """Start drawing `reps` uniform k-of-n subsets; returns a function giving bool [reps, n]."""
    out = _subsets(key, n, k, reps)
    return lambda: np.asarray(out).T
