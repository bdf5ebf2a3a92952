"""Chunked, jitted bootstrap and permutation draws reduced to column sums (SPEC §6).

Every statistic in the comparison is a function of per-group sums of a few
columns (a measure, its square, the per-trial successes), so one draw of
resampling weights serves all of them:

* bootstrap: multinomial counts c [R, n] (n uniform indices per resample,
  scatter-added), then sums = c @ Z — one BLAS matmul (Efron 1979);
* permutation: exactly-n_t-of-N label sets L [N, R] (Knuth Algorithm S), then
  treatment sums = Lᵀ @ Z (Fisher 1935; Pitman 1937).

The device draws the counts and label sets (exact integers); the host forms the sums in
float64, so every replicate is kept in float64 (a replicate equal to the estimate is not
moved off it by float32 rounding). Draws are made `chunk` resamples at a time under one jitted
function with static shapes, so memory stays bounded (≈ chunk · n floats) for any R;
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
from jaxeac.stats.closed_form import welch_t_stat

# chunk x units per draw: ~80 MB per [chunk, n] float32 buffer; keeps the flat int32 index < 2^31
MAX_CHUNK_ELEMENTS = 20_000_000


def _cap(chunk: int, resamples: int, n: int) -> int:
    """Chunk size, lowered for very many seeds so one chunk's buffers stay bounded."""
    return max(1, min(chunk, resamples, MAX_CHUNK_ELEMENTS // max(n, 1)))


def _counts(key, c, n: int, chunk: int, bins=None, width: int = 0):
    """The bootstrap draw, defined once: chunk c's resamples as counts per unit [chunk, n] (n uniform
    indices per resample under fold_in(key, c), scatter-added), or, given `bins` (unit -> bin, int32
    [n]) and their number `width`, the same draws counted per bin [chunk, width]."""
    idx = uniform_index(jax.random.fold_in(key, c), (chunk, n), n)
    if bins is not None:
        idx, n = bins[idx], width
    flat = (idx + (jnp.arange(chunk, dtype=jnp.int32) * n)[:, None]).reshape(-1)
    counts = jnp.zeros((chunk * n,), jnp.float32).at[flat].add(1.0, mode="promise_in_bounds")
    return counts.reshape(chunk, n)


_counts_chunk = jax.jit(_counts, static_argnames=("n", "chunk", "width"))
_counts_chunk_t = jax.jit(lambda key, c, n, chunk, bins=None, width=0:  # units first
                          _counts(key, c, n, chunk, bins, width).T, static_argnames=("n", "chunk", "width"))


def boot_counts(key, n: int, resamples: int, *, chunk: int = 1000, units_first: bool = False,
                bins: np.ndarray | None = None) -> np.ndarray:
    """Bootstrap resamples of n units as counts per unit, [resamples, n] float32 ([n, resamples]
    with `units_first`, the layout in which cumulative counts over units and row gathers are fast
    in NumPy): the draws `bootstrap_sums` makes under the same key (so its sums are these counts
    times the rows). With `bins` (unit i's bin, [n] ints from 0, e.g. the index of its
    distinct value) the same draws are counted per bin on the device, [resamples, bins] (exactly
    the per-unit counts summed over each bin's units): transfers and later work then scale with
    the bins, not the units."""
    chunk = _cap(chunk, resamples, n)
    extra, width = {}, n
    if bins is not None:  # bins padded to a power of two: one program per bucket, not per width
        width = int(bins.max(initial=-1)) + 1
        extra = {"bins": jnp.asarray(bins, jnp.int32), "width": max(16, 1 << max(width - 1, 0).bit_length())}
    fn = _counts_chunk_t if units_first else _counts_chunk
    parts = [fn(key, c, n, chunk, **extra) for c in range(-(-resamples // chunk))]  # all dispatched first
    if units_first:
        return np.concatenate([np.asarray(p)[:width] for p in parts], axis=1)[:, :resamples]
    return np.concatenate([np.asarray(p)[:, :width] for p in parts])[:resamples]


def _binned(keys, c, n: int, chunk: int, bins, width: int):
    """`_counts` with bins for K bin rows at once, units first [K, width, chunk]: bins [K, n], and
    keys [K] (row k's own draw) or [1] (one draw counted per every row's bins)."""
    idx = jax.vmap(lambda k: uniform_index(jax.random.fold_in(k, c), (chunk, n), n))(keys)
    k_rows = bins.shape[0]
    idx = jax.vmap(lambda b, i: b[i])(bins, jnp.broadcast_to(idx, (k_rows, chunk, n)))
    flat = (idx + (jnp.arange(k_rows * chunk, dtype=jnp.int32) * width).reshape(k_rows, chunk, 1)).reshape(-1)
    counts = jnp.zeros((k_rows * chunk * width,), jnp.float32).at[flat].add(1.0, mode="promise_in_bounds")
    return counts.reshape(k_rows, chunk, width).transpose(0, 2, 1)


_binned_chunk = jax.jit(_binned, static_argnames=("n", "chunk", "width"))


#: Per backend, whether `boot_counts_binned` makes its rows' draws in one program (else one call per
#: row, which the 2-core CPU runs side by side: 8 groups of 1,000 seeds × 10,000 resamples 0.23 s
#: against 0.53 s together).
BINNED_TOGETHER = {"cpu": False}


def boot_counts_binned(keys, n: int, resamples: int, bins: list[np.ndarray], *, chunk: int = 1000
                       ) -> list[np.ndarray]:
    """`boot_counts(key, n, resamples, chunk=chunk, units_first=True, bins=b)` for every b of `bins`
    (each [n] ints from 0), bit for bit, in a few device calls instead of one each: `keys` is a list
    of each b's own key, or one key drawn once for all of them (one draw of shared seeds, counted per
    value of each algorithm's). Rows go in batches of at most `MAX_CHUNK_ELEMENTS` drawn indices."""
    keys = list(keys) if isinstance(keys, list | tuple) else [keys]
    if not BINNED_TOGETHER.get(jax.default_backend(), True):
        return [boot_counts(keys[i] if len(keys) > 1 else keys[0], n, resamples, chunk=chunk, units_first=True,
                            bins=b) for i, b in enumerate(bins)]
    chunk = _cap(chunk, resamples, n)
    widths = [int(b.max(initial=-1)) + 1 for b in bins]
    width = max(16, 1 << max(max(widths) - 1, 0).bit_length())
    step = max(1, MAX_CHUNK_ELEMENTS // (chunk * n))
    out: list[np.ndarray] = []
    for start in range(0, len(bins), step):
        rows = jnp.asarray(np.stack(bins[start:start + step]), jnp.int32)
        stacked = jnp.stack(keys[start:start + step] if len(keys) > 1 else keys)
        parts = [_binned_chunk(stacked, c, n, chunk, rows, width) for c in range(-(-resamples // chunk))]
        whole = np.concatenate([np.asarray(p) for p in parts], axis=2)[:, :, :resamples]
        out.extend(whole[k, :w] for k, w in enumerate(widths[start:start + step]))
    return out


def cumulative(ct: np.ndarray, *, zero_row: bool = False) -> np.ndarray:
    """Inclusive cumulative sums over the rows of ct [D, R] (units first), row by row: NumPy's
    cumsum along axis 0 is several times slower; the additions are in the same order. With
    `zero_row` a row of zeros leads, so row i holds the sum of the first i rows."""
    out = np.empty((ct.shape[0] + 1, ct.shape[1]), ct.dtype)
    out[0] = 0
    for i in range(ct.shape[0]):
        np.add(out[i], ct[i], out=out[i + 1])
    return out if zero_row else out[1:]


def iqm_from_counts(c: np.ndarray, values: np.ndarray, *, units_first: bool = False, cum=None) -> np.ndarray:
    """IQM (25 % trimmed mean, as `scipy.stats.trim_mean(x, 0.25)`) of each resample in
    counts per ascending value c [R, D] ([D, R] with `units_first`, then `cum` may give its
    inclusive cumulative counts): (F(n − g) − F(g)) / (n − 2g), F(k) the sum of the k smallest,
    g = n // 4."""
    ct = np.asarray(c) if units_first else np.asarray(c).T
    n = int(round(float(ct[:, 0].sum())))
    g = n // 4
    if units_first:  # counts: exact in float32 too
        cum = cumulative(ct) if cum is None else cum
        cum_v = cumulative(ct * values[:, None])
    else:
        cum = np.cumsum(ct, axis=0)
        cum_v = np.cumsum(ct * values[:, None], axis=0)
    cols = np.arange(ct.shape[1])

    def smallest(k):
        j = np.minimum(rows_below(cum, k), ct.shape[0] - 1)  # value holding the k-th smallest
        before = np.where(j > 0, cum[np.maximum(j - 1, 0), cols], 0.0)
        before_v = np.where(j > 0, cum_v[np.maximum(j - 1, 0), cols], 0.0)
        return before_v + (k - before) * values[j]

    return (smallest(n - g) - smallest(g)) / (n - 2 * g)


def rows_below(cum: np.ndarray, k, *, strict: bool = True) -> np.ndarray:
    """Per column of cumulative counts cum [D, R] (nondecreasing down each column): how many
    rows hold less than k (at most k unless `strict`), by bisection: O(R log D)."""
    cols = np.arange(cum.shape[1])
    lo, hi = np.zeros(cum.shape[1], np.int64), np.full(cum.shape[1], cum.shape[0], np.int64)
    while np.any(lo < hi):
        mid = (lo + hi) // 2
        c = cum[np.minimum(mid, cum.shape[0] - 1), cols]
        below = (c < k if strict else c <= k) & (lo < hi)
        lo, hi = np.where(below, mid + 1, lo), np.where(below | (lo >= hi), hi, mid)
    return lo


def _exact_columns(z: np.ndarray) -> np.ndarray:
    """Whether each column of z [n, K] is integer-valued with every partial sum below 2^24 in
    magnitude, so float32 sums of it on the device are exact (e.g. per-trial successes)."""
    with np.errstate(invalid="ignore"):
        return np.all(z == np.round(z), axis=0) & (np.abs(z).sum(0) < 2**24)


@partial(jax.jit, static_argnames=("n", "chunk"))
def _boot_chunk(key, c, z_exact, n: int, chunk: int):
    counts = _counts(key, c, n, chunk)
    return counts, counts @ z_exact


@partial(jax.jit, static_argnames=("n", "k", "chunk"))
def _perm_chunk(key, c, z_exact, n: int, k: int, chunk: int):
    labels = random_subsets(jax.random.fold_in(key, c), n, k, chunk).T
    return labels, labels.astype(jnp.float32) @ z_exact


def _sums(draws, z: np.ndarray, exact: np.ndarray, resamples: int, iqm: bool = False):
    """Each chunk's sums [R, K] in float64: exact columns as the device summed them, the others
    on the host from the draw (counts or labels, exact integers); and the IQMs of column 0."""
    sums, q = [], []
    for w, s_exact in draws:
        w = np.asarray(w)
        out = np.empty((w.shape[0], z.shape[1]))
        out[:, exact] = np.asarray(s_exact, np.float64)
        if not exact.all():
            out[:, ~exact] = w.astype(np.float64) @ z[:, ~exact]
        sums.append(out)
        if iqm:  # units of one value merged first (exact integer counts): O(values) per resample
            start = np.flatnonzero(np.r_[True, z[1:, 0] != z[:-1, 0]])
            q.append(iqm_from_counts(np.add.reduceat(w, start, axis=1) if start.size < w.shape[1] else w,
                                     z[start, 0]))
    return np.concatenate(sums)[:resamples], np.concatenate(q)[:resamples] if iqm else None


def dispatch_bootstrap(key, z, resamples: int, *, chunk: int = 1000, iqm: bool = False):
    """Start the bootstrap chunks without waiting (JAX dispatches asynchronously).

    Returns a function that waits and gives (sums [R, K] float64, iqm [R] float64 or None): the
    device draws the counts (`boot_counts`' draw) and sums the columns it sums exactly
    (`_exact_columns`), the host sums the others in float64, so every replicate is kept in
    float64."""
    z = np.asarray(z, np.float64)
    if iqm:  # sums do not depend on the order of rows; the IQM needs them sorted by column 0
        z = z[np.argsort(z[:, 0], kind="stable")]
    n, exact = z.shape[0], _exact_columns(z)
    z_exact = jnp.asarray(z[:, exact], jnp.float32)
    chunk = _cap(chunk, resamples, n)
    draws = [_boot_chunk(key, c, z_exact, n, chunk) for c in range(-(-resamples // chunk))]
    return lambda: _sums(draws, z, exact, resamples, iqm)


def bootstrap_sums(key, z, resamples: int, *, chunk: int = 1000, iqm: bool = False):
    """Column sums of `resamples` bootstrap resamples of the rows of z [n, K].

    Returns (sums [R, K] float64, iqm [R] float64 or None). With iqm=True the IQM
    (25 % trimmed mean, as `scipy.stats.trim_mean(x, 0.25)`) of column 0 of each
    resample is returned too.
    """
    return dispatch_bootstrap(key, z, resamples, chunk=chunk, iqm=iqm)()


def dispatch_permutation(key, z_pool, n_treat: int, resamples: int, *, chunk: int = 1000):
    """Start the permutation chunks without waiting; returns a function giving the treatment
    group's sums [R, K] in float64 (exact columns from the device, the others on the host)."""
    z = np.asarray(z_pool, np.float64)
    exact = _exact_columns(z)
    z_exact = jnp.asarray(z[:, exact], jnp.float32)
    chunk = _cap(chunk, resamples, z.shape[0])
    draws = [_perm_chunk(key, c, z_exact, z.shape[0], int(n_treat), chunk)
             for c in range(-(-resamples // chunk))]
    return lambda: _sums(draws, z, exact, resamples)[0]


def permutation_sums(key, z_pool, n_treat: int, resamples: int, *, chunk: int = 1000):
    """Treatment-group column sums [R, K] under `resamples` random relabellings of z_pool [N, K]."""
    return dispatch_permutation(key, z_pool, n_treat, resamples, chunk=chunk)()


_subsets = jax.jit(random_subsets, static_argnums=(1, 2, 3))


def dispatch_subsets(key, n: int, k: int, reps: int):
    """Start drawing `reps` uniform k-of-n subsets; returns a function giving bool [reps, n]."""
    out = _subsets(key, n, k, reps)
    return lambda: np.asarray(out).T


def perm_p(t_obs, t_star):
    """Two-sided Monte-Carlo permutation p = (1 + #{|t*| ≥ |t|}) / (P + 1) (Phipson & Smyth 2010),
    |t| less a relative 1e-6, so sums of an equal labelling formed in another order count as ties."""
    a = np.abs(np.asarray(t_obs, np.float64))
    with np.errstate(invalid="ignore"):
        a = np.where(np.isfinite(a), a - 1e-6 * np.maximum(a, 1e-12), a)
    return (1 + (np.abs(t_star) >= a).sum(0)) / (t_star.shape[0] + 1)


def permutation_welch_p(nb: int, nt: int, t_obs, tot1, tot2, s1, s2) -> float:
    """The studentised permutation p of one measure (Janssen 1997), its one definition: Welch's t
    of each relabelling, from its treatment sums s1, s2 [P] and the pooled totals, against t_obs."""
    return float(perm_p(t_obs, welch_t_stat(nb, tot1 - s1, tot2 - s2, nt, s1, s2)[:, None])[0])
