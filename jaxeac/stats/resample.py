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
chunk c uses `jax.random.fold_in(key, c)`, so results depend only on
(key, R, chunk).
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from jaxeac.stats._rng import random_subsets, uniform_index


@partial(jax.jit, static_argnames=("chunk", "iqm"))
def _boot_chunk(key, z, bins, values, chunk: int, iqm: bool):
    n = z.shape[0]
    idx = uniform_index(key, (chunk, n), n)
    rows = jnp.broadcast_to(jnp.arange(chunk)[:, None], idx.shape)
    counts = jnp.zeros((chunk, n), jnp.float32).at[rows, idx].add(1.0)
    sums = counts @ z
    if not iqm:
        return sums, jnp.zeros((chunk,), jnp.float32)
    # IQM of each resample without sorting it: histogram the drawn values over the
    # sorted distinct values; distinct value u fills positions [C_{u-1}, C_u) of the
    # sorted resample, of which [g, n - g) are kept (g = floor(n/4)).
    hist = jnp.zeros((chunk, values.shape[0]), jnp.float32).at[rows, bins[idx]].add(1.0)
    g = n // 4
    hi = jnp.cumsum(hist, axis=1)
    w = jnp.clip(jnp.minimum(hi, n - g) - jnp.maximum(hi - hist, g), 0.0)
    return sums, (w @ values) / (n - 2 * g)


@partial(jax.jit, static_argnames=("chunk", "n_treat"))
def _perm_chunk(key, z, chunk: int, n_treat: int):
    labels = random_subsets(key, z.shape[0], n_treat, chunk)
    return labels.astype(jnp.float32).T @ z


def _chunks(resamples: int, chunk: int, progress: bool, desc: str):
    n_chunks = -(-resamples // chunk)
    it = range(n_chunks)
    if progress:
        from tqdm.auto import tqdm

        it = tqdm(it, desc=desc, leave=False)
    return it


def bootstrap_sums(
    key,
    z,
    resamples: int,
    *,
    chunk: int = 1000,
    iqm: bool = False,
    progress: bool = False,
    desc: str = "bootstrap",
):
    """Column sums of `resamples` bootstrap resamples of the rows of z [n, K].

    Returns (sums [R, K] float64, iqm [R] float64 or None). With iqm=True the IQM
    (25 % trimmed mean, as `scipy.stats.trim_mean(x, 0.25)`) of column 0 of each
    resample is returned too.
    """
    values, bins = np.unique(np.asarray(z)[:, 0], return_inverse=True)
    values = jnp.asarray(values, jnp.float32)
    bins = jnp.asarray(bins.reshape(-1), jnp.int32)
    z = jnp.asarray(z, jnp.float32)
    chunk = max(1, min(chunk, resamples))
    sums, iqms = [], []
    for c in _chunks(resamples, chunk, progress, desc):
        s, q = _boot_chunk(jax.random.fold_in(key, c), z, bins, values, chunk, iqm)
        sums.append(s)
        iqms.append(q)
    sums = np.asarray(jnp.concatenate(sums), np.float64)[:resamples]
    q = np.asarray(jnp.concatenate(iqms), np.float64)[:resamples] if iqm else None
    return sums, q


def permutation_sums(
    key,
    z_pool,
    n_treat: int,
    resamples: int,
    *,
    chunk: int = 2000,
    progress: bool = False,
    desc: str = "permutation",
):
    """Treatment-group column sums [R, K] under `resamples` random relabellings of z_pool [N, K]."""
    z = jnp.asarray(z_pool, jnp.float32)
    chunk = max(1, min(chunk, resamples))
    out = [
        _perm_chunk(jax.random.fold_in(key, c), z, chunk, int(n_treat))
        for c in _chunks(resamples, chunk, progress, desc)
    ]
    return np.asarray(jnp.concatenate(out), np.float64)[:resamples]


def subset_masks(key, n: int, k: int, reps: int) -> np.ndarray:
    """bool [reps, n]: uniform random k-of-n subsets (for splits)."""
    return np.asarray(jax.jit(random_subsets, static_argnums=(1, 2, 3))(key, n, k, reps)).T
