"""The comparison at 10^5–10^6 and more seeds per method (SPEC §6): the large-N path.

While neither method has more than `LARGE_N` seeds, `compare` draws seed indices and
labels one by one (`resample`): O(N) work per resample, and results bit for bit as
before. Above `LARGE_N` seeds in either method (`is_large`) every analysis of the report
takes O(N) (ranks: O(N log N)) once, plus work per resample that does not grow with N:

Exact (the same law as drawing seeds one by one):

* Bootstrap of a per-seed measure with at most `MAX_DISTINCT` distinct values
  (successes, late success rate and first success for T < 1024 trials; total pins
  for T ≤ 102): seeds with equal
  values are interchangeable, so a resample of n seeds is a multinomial count per
  distinct value, Mult(n, k/n) (Efron 1979), O(D) per resample. The IQM of a
  resample comes from the same counts (sum of the k smallest from cumulative counts).
* Permutation test of such a measure: the treatment group's counts per distinct
  value under a random relabelling are multivariate hypergeometric (Fisher 1935).
* Brunner–Munzel and A12 from counts per distinct value (mid-ranks); log-rank from
  counts per (time, event); per-trial means, SEs and covariances of the curves from
  per-chunk sums of integer counts on the device (`curve_moments`).
* Calibration of the measures' tests: each random half is a multivariate
  hypergeometric count per distinct value; of the curve test: exact random halves
  of the seeds (selection sampling on the device, in blocks of seeds).

The per-value draws use NumPy's exact samplers (BTPE binomial, Kachitvichyanukul &
Schmeiser 1988; HRUA hypergeometric, Stadlober 1989) on the host, seeded from the
JAX key, so a large-N result does not depend on the device.

Asymptotically exact, and only above `LARGE_N`:

* Curves, sup-t bands: the Gaussian multiplier bootstrap (Chernozhukov, Chetverikov
  & Kato 2013). Given the data its law is exactly N(0, Σ̂/n), with Σ̂ the per-trial
  covariance from exact per-chunk sums, so it is drawn through Σ̂'s square root at
  O(T²) per draw; the sup-t critical value is the (1 − α) quantile of max_t |Z_t|/se_t
  (Montiel Olea & Plagborg-Møller 2019 define the band through this Gaussian limit;
  the seed bootstrap estimates the same quantile).
* Curves, trials where the methods differ: single-step max-T (Westfall & Young 1993)
  with the multivariate normal limit of the permutation distribution of the per-trial
  Welch t, N(0, R) with R the pooled per-trial correlation (combinatorial CLT, Hájek
  1961; studentised statistics, Janssen 1997; max-T p-values from that limit as in
  Hothorn, Bretz & Westfall 2008).
* A measure with more than `MAX_DISTINCT` distinct values (the normalised area under
  the cumulative-success curve, continuous data): the BCa intervals of the difference
  and of Hedges' g become ABC intervals (DiCiccio & Efron 1992; Efron & Tibshirani
  1993, §22.6), the analytic form of BCa; the permutation p-value becomes its normal
  limit 2Φ(−|t|) (Janssen 1997); the IQM interval (if it is the first measure) the
  BCa formula on the bootstrap's normal limit with jackknife SE and acceleration.

Why these are equivalent at that N. ABC endpoints agree with those of BCa with
infinitely many resamples to O_p(n^-3/2), a share O(1/n) of the interval's width
(DiCiccio & Efron 1992, 1996), while BCa from 10^4 resamples carries a Monte Carlo
error near 1 % of the width. The normal and Gaussian limits replace laws of two-sided
statistics (|t|, max_t |t_t|), whose O(N^-1/2) Edgeworth term is odd and cancels, so
they differ from the exact laws by O(1/N) (Hall 1992, §3.5), plus for 0/1 data a
lattice term below φ(z)/(2·sqrt(N p (1 − p))) (Esseen 1945): at N > `LARGE_N` and
per-trial rates in [0.05, 0.95] under 1e-3 on a probability, against a Monte Carlo
standard error of 2e-3 on a p-value near 0.05 from 10^4 draws. `tests/test_stats_scale.py`
checks each against the exact computation: the laws (two-sample KS) and critical
values within Monte Carlo bands just above `LARGE_N`, ABC against BCa and the normal
permutation p against exact permutations at 2·10^5 seeds.

(Just over 400 lines: the large-N building blocks and the argument for each are kept
in one module, next to the docstring that justifies them.)

(Over 400 lines on purpose: each large-N estimator sits beside the exact per-value form it
matches, with the argument that they agree.)
"""

from __future__ import annotations

import contextlib
import math
import threading
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from scipy import special

from jaxeac.bits import SuccessBits
from jaxeac.stats import closed_form as cf
from jaxeac.stats._rng import mulhi32, random_words, warm_key_programs
from jaxeac.stats.resample import cumulative
from jaxeac.stats.rundir import Coded, as_values, joint_counts

#: Above this many seeds in either method the large-N path is used.
LARGE_N = 20_000
#: A measure with at most this many distinct values (pooled) is resampled exactly per value.
MAX_DISTINCT = 1024
#: Seeds per block in the device sums (float32 sums of 0..100 stay exact integers below 2^24).
BLOCK = 65_536
#: fold_in index of the curve draws under the bootstrap and permutation keys (measures use 0..M-1).
CURVE_STREAM = 1_000_000

REFERENCES = {
    "bootstrap_per_value": "exact: multinomial counts per distinct value (Efron 1979)",
    "permutation_per_value": "exact: multivariate hypergeometric counts per distinct value (Fisher 1935)",
    "abc": "ABC interval, analytic BCa (DiCiccio & Efron 1992)",
    "normal_permutation": "normal limit of the studentised permutation test, 2Φ(−|t|) (Janssen 1997)",
    "normal_bca": "BCa on the normal limit, jackknife SE and acceleration (Efron 1987)",
    "sup_t_gaussian": "Gaussian multiplier sup-t band, N(0, Σ̂) from per-chunk sums "
    "(Chernozhukov, Chetverikov & Kato 2013; Montiel Olea & Plagborg-Moller 2019)",
    "max_t_gaussian": "single-step max-T, multivariate normal limit of the permutation law "
    "(Westfall & Young 1993; Hajek 1961; Janssen 1997; Hothorn, Bretz & Westfall 2008)",
}


class HostBudget:
    """Bytes of host temporaries that jobs on threads may hold at once: a job waits until its
    share is free (one larger than the whole budget runs alone), so the analyses of the
    measures run side by side while they are small and one at a time when each needs hundreds
    of MB. Each job draws from its own keys, so its results do not depend on the order."""

    def __init__(self, total: int):
        self.total = self.free = int(total)
        self._cond = threading.Condition()

    @contextlib.contextmanager
    def hold(self, nbytes: int):
        need = min(int(nbytes), self.total)
        with self._cond:
            self._cond.wait_for(lambda: self.free >= need)
            self.free -= need
        try:
            yield
        finally:
            with self._cond:
                self.free += need
                self._cond.notify_all()


#: Host temporaries the comparison's jobs on threads may hold at once.
HOST_BUDGET = HostBudget(512 << 20)


def job_bytes(*n: int) -> int:
    """Temporaries of one measure's analysis of samples of n seeds: the pooled float64 values
    and two more per-seed columns (centred values, squares, an interval's influence values)."""
    return 8 * 4 * sum(int(k) for k in n)


RAW, PER_VALUE, ASYMPTOTIC = "raw draws", "exact per-value counts", "asymptotic"
PATH_RULE = (
    f"seeds resampled one by one up to {LARGE_N} seeds per group; above, counts per distinct "
    f"value (exact) where a group has at most {MAX_DISTINCT} distinct values, else the normal "
    "limit of the bootstrap (jackknife standard error and acceleration)"
)


def few_values(distinct: int) -> bool:
    """Whether `distinct` values are few enough to resample as exact counts per value."""
    return int(distinct) <= MAX_DISTINCT


def resampling_path(n: int, distinct: int) -> str:
    """The one rule (`PATH_RULE`) for a group of n seeds with `distinct` values: `RAW` up to
    `LARGE_N` seeds, then `PER_VALUE` where the values are few (`few_values`), else `ASYMPTOTIC`.
    (Paired differences, `jaxeac.stats.paired`, take per-value counts wherever their values are
    few, at any n: the same law as raw draws, and the numbers its run folders have always had.)"""
    if int(n) <= LARGE_N:
        return RAW
    return PER_VALUE if few_values(distinct) else ASYMPTOTIC


def is_large(*n: int) -> bool:
    """Whether a comparison with these seeds per method leaves raw draws (`resampling_path`)."""
    return any(resampling_path(k, 0) != RAW for k in n)


def host_rng(key) -> np.random.Generator:
    """A NumPy generator seeded from the words of a JAX key (the same on every device)."""
    words = np.asarray(jax.random.key_data(key), np.uint32).reshape(-1)
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence([int(w) for w in words])))


# ---------------------------------------------------------------- per-value tables
class ValueTable:
    """Distinct values of a pooled sample and the counts of each group (ascending values).
    Samples given as `Coded` are counted from their codes (O(N), no float64 copies)."""

    def __init__(self, x_baseline, x_treatment):
        if isinstance(x_baseline, Coded) and isinstance(x_treatment, Coded):
            self.nb, self.nt = x_baseline.size, x_treatment.size
            self.values, self.kb, self.kt = joint_counts(x_baseline, x_treatment)
            return
        xb, xt = np.asarray(x_baseline, np.float64), np.asarray(x_treatment, np.float64)
        self.nb, self.nt = int(xb.size), int(xt.size)
        pooled = np.concatenate([xb, xt])
        lo, hi = pooled.min(), pooled.max()
        if hi - lo < 2**22 and np.array_equal(pooled, np.round(pooled)):  # small integers: O(N), no sort
            span = int(hi - lo) + 1
            kb = np.bincount((xb - lo).astype(np.int64), minlength=span)
            kt = np.bincount((xt - lo).astype(np.int64), minlength=span)
            keep = (kb + kt) > 0
            self.values = (np.arange(span, dtype=np.float64) + lo)[keep]
            self.kb, self.kt = kb[keep], kt[keep]
            return
        self.values, inv = np.unique(pooled, return_inverse=True)
        inv = inv.reshape(-1)
        U = self.values.size
        self.kb = np.bincount(inv[: self.nb], minlength=U)
        self.kt = np.bincount(inv[self.nb :], minlength=U)

    @property
    def distinct(self) -> int:
        return int(self.values.size)

    @property
    def exact(self) -> bool:
        return few_values(self.distinct)


def _column_sums(blocks) -> np.ndarray:
    """Column sums of consecutive blocks of rows [k, M > 1] as NumPy sums one C-ordered [n, M]
    array down its rows, one row after another: the blocks continue the same running sums, so
    the result is that of the whole array bit for bit, without it."""
    run = None
    for rows in blocks:
        run = np.add.reduce(rows if run is None else np.vstack([run, rows]), axis=0, keepdims=True)
    return run[0]


def stacked_means(columns, n: int, block: int = 1 << 16) -> np.ndarray:
    """``np.stack([c[:n] for c in columns], 1).mean(0)`` (float64 values of arrays or `Coded`) bit
    for bit, without the [n, M] copy (`_column_sums`; one column is summed pairwise: whole)."""
    if len(columns) == 1:
        return np.stack([as_values(columns[0], 0, n)], 1).mean(0)
    return _column_sums(np.stack([as_values(c, i, min(n, i + block)) for c in columns], 1)
                        for i in range(0, n, block)) / n


def _units_moments(z: np.ndarray, block: int = 1 << 16) -> tuple[np.ndarray, np.ndarray]:
    """``u.mean(0), u.std(0)`` of u = [z, z²] [n, 2] bit for bit, a block of rows at a time."""
    def units(i):
        zb = z[i : i + block]
        return np.stack([zb, zb * zb], 1)

    n = z.size
    mean = _column_sums(units(i) for i in range(0, n, block)) / n
    return mean, np.sqrt(_column_sums(np.square(units(i) - mean) for i in range(0, n, block)) / n)


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


def moment_sums(c: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sums of values and squares of each row of counts c [R, D]."""
    return c @ values, c @ (values * values)


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


def jackknife_iqm_counts(counts: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Leave-one-out IQM for a unit of each distinct value (ascending values, counts > 0)."""
    drop = np.asarray(counts, np.float64)[None] - np.eye(counts.size)
    return iqm_from_counts(drop, values)


# ---------------------------------------------------------------- asymptotic intervals and tests
def _two_sample_f(statistic: str, nb: int, nt: int):
    def f(theta):
        mb, qb, mt, qt = theta
        if statistic == "mean_diff":
            return mt - mb
        return cf.hedges_from_moments(nb, nb * mb, nb * qb, nt, nt * mt, nt * qt)

    return f


def _grad_hess(f, theta: np.ndarray, h: np.ndarray):
    """Central-difference gradient and Hessian of a smooth f: R^p -> R at theta."""
    p = theta.size
    f0 = float(f(theta))
    grad = np.empty(p)
    hess = np.empty((p, p))
    e = np.eye(p) * h
    for i in range(p):
        fp, fm = float(f(theta + e[i])), float(f(theta - e[i]))
        grad[i] = (fp - fm) / (2 * h[i])
        hess[i, i] = (fp - 2 * f0 + fm) / h[i] ** 2
        for j in range(i):
            v = (
                float(f(theta + e[i] + e[j]))
                - float(f(theta + e[i] - e[j]))
                - float(f(theta - e[i] + e[j]))
                + float(f(theta - e[i] - e[j]))
            ) / (4 * h[i] * h[j])
            hess[i, j] = hess[j, i] = v
    return f0, grad, hess


def abc_two_sample(statistic: str, x: np.ndarray, y: np.ndarray, alpha: float = 0.05) -> cf.Estimate:
    """ABC interval (DiCiccio & Efron 1992; `abcnon` of Efron & Tibshirani 1993, §22.6) for
    mean(y) − mean(x) ("mean_diff") or Hedges' g ("hedges_g"), the two samples resampled
    independently: `abc_intervals` of one statistic."""
    return abc_intervals((statistic,), x, y, alpha)[statistic]


def abc_intervals(statistics, x: np.ndarray, y: np.ndarray, alpha: float = 0.05) -> dict[str, cf.Estimate]:
    """`abc_two_sample` of each of `statistics`, from one pass over the units.

    Each statistic is a smooth function f of the group means of (x, x²); the empirical
    influence values, the acceleration, the bias and curvature corrections and the
    endpoints f(θ̂ + λδ) are all closed-form sums over the units (O(n)), taken one sample
    at a time so only one sample's per-unit temporaries exist at once. The means of (x, x²)
    and the centred units are computed once for all the statistics.
    """
    nb, nt = x.size, y.size
    moments = [_units_moments(z) for z in (x, y)]
    theta = np.r_[moments[0][0], moments[1][0]]
    sd = np.r_[moments[0][1], moments[1][1]]
    h = 1e-3 * np.where(sd > 0, sd, np.maximum(1e-8 * np.abs(theta), 1e-12))
    fs = {name: _two_sample_f(name, nb, nt) for name in statistics}
    derivs = {name: _grad_hess(f, theta, h) for name, f in fs.items()}
    parts = {name: [] for name in statistics}  # per side: sums of L², L³ and Q, and du^T L
    for k, (z, (mean, _)) in enumerate(zip((x, y), moments, strict=True)):
        du = np.empty((z.size, 2))  # [z, z²] less their means, made in place
        np.subtract(z, mean[0], out=du[:, 0])
        np.multiply(z, z, out=du[:, 1])
        du[:, 1] -= mean[1]
        gram = du.T @ du  # Σ_i du_i du_iᵀ: the quadratic terms Σ_i du_iᵀ H du_i are sums of H ∘ gram
        for name, (t0, grad, hess) in derivs.items():
            if not np.isfinite(t0):
                continue
            g_k, h_k = grad[2 * k : 2 * k + 2], hess[2 * k : 2 * k + 2, 2 * k : 2 * k + 2]
            L = du @ g_k
            L2 = np.square(L)
            l2, l3, dl = L2.sum(), np.dot(L2, L), du.T @ L  # (products, not pow: 10x faster)
            del L, L2
            parts[name].append((l2, l3, float((h_k * gram).sum()), dl, z.size))
        del du
    return {name: _abc_endpoints(fs[name], theta, *derivs[name], parts[name], alpha) for name in statistics}


def _abc_endpoints(f, theta: np.ndarray, t0: float, grad, hess, parts: list, alpha: float) -> cf.Estimate:
    """The ABC interval of f at theta from its derivatives and both sides' sums (`abc_intervals`)."""
    if not np.isfinite(t0):
        return cf.Estimate(t0, t0, t0, 1 - alpha)
    var = sum(l2 / n**2 for l2, _, _, _, n in parts)
    if not var > 0:
        return cf.Estimate(t0, t0, t0, 1 - alpha)
    sig = math.sqrt(var)
    a = sum(l3 / n**3 for _, l3, _, _, n in parts) / (6 * sig**3)
    direction = np.concatenate([dl / (n**2 * sig) for _, _, _, dl, n in parts])  # δ in θ-space
    bhat = sum(q / (2 * n**2) for _, _, q, _, n in parts)
    cq = direction @ hess @ direction / (2 * sig)
    curv = bhat / sig - cq
    z0 = special.ndtri(2 * special.ndtr(a) * special.ndtr(-curv))
    ends = []
    for q in (alpha / 2, 1 - alpha / 2):
        w = z0 + special.ndtri(q)
        lam = w / (1 - a * w) ** 2
        ends.append(float(f(theta + lam * direction)))
    return cf.Estimate(t0, min(ends), max(ends), 1 - alpha)


def normal_bca(est: float, jackknife: np.ndarray, alpha: float = 0.05) -> tuple[float, float]:
    """BCa endpoints with the bootstrap law replaced by its normal limit N(est, se²): z0 = 0,
    se and acceleration from the jackknife values (Efron 1987)."""
    jk = np.asarray(jackknife, np.float64)
    n = jk.size
    u = (n - 1) * (jk.mean() - jk)
    se = math.sqrt(((jk - jk.mean()) ** 2).sum() * (n - 1) / n)
    dens = (u**2).sum()
    a = (u**3).sum() / (6 * dens**1.5) if dens > 0 else 0.0
    out = []
    for q in (alpha / 2, 1 - alpha / 2):
        z = special.ndtri(q)
        out.append(est + se * z / (1 - a * z))
    return float(out[0]), float(out[1])


def normal_permutation_p(t_obs) -> np.ndarray:
    """Two-sided p of the studentised permutation test from its N(0, 1) limit (Janssen 1997)."""
    t = np.abs(np.asarray(t_obs, np.float64))
    return np.where(np.isfinite(t), 2 * special.ndtr(-t), 0.0)


# ---------------------------------------------------------------- curves from per-chunk sums
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

        def wait_bits():
            g, s = (np.asarray(v, np.float64) for v in dev)
            return {"n": c.shape[0], "s": s, "G": g}

        return wait_bits
    c = np.asarray(c)
    if _small_integers(c):
        dev = _gram(jnp.asarray(c.astype(np.int8) if c.dtype != np.bool_ else c), BLOCK)

        def wait():
            g, s = (np.asarray(v, np.float64) for v in dev)
            return {"n": c.shape[0], "s": s, "G": g}

        return wait
    x = c.astype(np.float64)
    res = {"n": c.shape[0], "s": x.sum(0), "G": x.T @ x}
    return lambda: res


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


# ---------------------------------------------------------------- calibration: exact random halves
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


def compile_ahead(n: int, trials: int, splits: int, block: int = 4096) -> None:
    """Compile the large-N path's device programs for success bits of n seeds per method and T
    trials (curve sums, calibration halves) before the data exists: `jaxeac grid` calls it on a
    thread while the run computes. The programs land in the persistent compilation cache, so
    the comparison loads them instead of compiling them (with the cache off they compile again).
    The comparison's key derivations are run once here too (`warm_key_programs`, any n): those
    stay compiled in this process, cache or not."""
    warm_key_programs()
    if not is_large(n):
        return
    width = -(-trials // 8)
    h = n // 2
    for rows in {n, 2 * h}:
        bits = jax.ShapeDtypeStruct((rows, width), jnp.uint8)
        _unpack_bits.lower(bits, trials).compile()
    _gram.lower(jax.ShapeDtypeStruct((n, trials), jnp.bool_), BLOCK).compile()
    if splits > 0:
        nblocks = -(-2 * h // block)
        key = jax.random.key(0)
        _subset_sums.lower(key, jax.ShapeDtypeStruct((2 * h, trials), jnp.bool_),
                           jax.ShapeDtypeStruct((splits, nblocks), jnp.int32), block, True, 32).compile()
