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
"""

from __future__ import annotations

import contextlib
import threading

import jax
import jax.numpy as jnp
import numpy as np

from jaxeac.stats._rng import warm_key_programs
from jaxeac.stats.asymptotic import _column_sums, normal_bca
from jaxeac.stats.bca import bca_interval, jackknife_iqm
from jaxeac.stats.device_sums import BLOCK, CODES_BLOCK, _codes, _gram, _subset_sums, _unpack_bits
from jaxeac.stats.measures import Coded, as_values, joint_counts, late_window
from jaxeac.stats.resample import iqm_from_counts

#: Above this many seeds in either method the large-N path is used.
LARGE_N = 20_000
#: A measure with at most this many distinct values (pooled) is resampled exactly per value.
MAX_DISTINCT = 1024
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
    "limit of the bootstrap (jackknife standard error and acceleration); paired differences with "
    f"at most {MAX_DISTINCT} distinct values, each seen twice on average (distinct ≤ n / 2): counts "
    "per distinct value at any number of seeds"
)


def few_values(distinct: int) -> bool:
    """Whether `distinct` values are few enough to resample as exact counts per value."""
    return int(distinct) <= MAX_DISTINCT


def resampling_path(n: int, distinct: int, *, paired: bool = False) -> str:
    """The one rule (`PATH_RULE`, SPEC §6 "At very many seeds") for a group of n seeds with
    `distinct` values: `RAW` up to `LARGE_N` seeds, then `PER_VALUE` where the values are few
    (`few_values`), else `ASYMPTOTIC`. `paired` (per-seed differences, SPEC §6 "Paired where the
    design is paired"): `PER_VALUE` wherever the values are few, at any n — the same law as raw
    draws, and the numbers run folders have always had. Every resampling in `jaxeac.stats` asks
    this function, and each result records the path it took."""
    if paired and few_values(distinct) and 2 * int(distinct) <= int(n):  # values repeat: fewer draws
        return PER_VALUE
    return RAW if int(n) <= LARGE_N else path_above(distinct)


def path_above(distinct: int) -> str:
    """`resampling_path` above `LARGE_N` seeds, for the large-N analyses that only run there."""
    return PER_VALUE if few_values(distinct) else ASYMPTOTIC


def is_large(*n: int) -> bool:
    """Whether a comparison with these seeds per method leaves raw draws (`resampling_path`)."""
    return any(resampling_path(k, 0) != RAW for k in n)


def path_record(res: dict, nb: int, nt: int, calibration_splits: int) -> dict:
    """Which path the statistics took, and above `LARGE_N` which method each piece used."""
    out = {
        "large_n_threshold": LARGE_N,
        "max_distinct_values_exact": MAX_DISTINCT,
        "path": "large-N" if is_large(nb, nt) else "seed resampling",
    }
    if out["path"] == "large-N":
        out["measures"] = res["scale"]
        if res["curves"] is not None:
            out["curves"] = {
                "bands": res["curves"]["band_method"],
                "trials_differ": res["curves"]["test_method"],
            }
        out["calibration"] = (
            "per-value halves (measures), exact halves of the seeds (curves)"
            if is_large(nb) and calibration_splits > 0
            else "seed halves as below the threshold"
        )
        out["note"] = (
            f"above {LARGE_N} seeds per method: resampling per distinct value (exact) for measures "
            f"with at most {MAX_DISTINCT} distinct values; asymptotically exact methods otherwise "
            "and for the curves (see jaxeac.stats.large)"
        )
    return out


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
        return path_above(self.distinct) == PER_VALUE


def stacked_means(columns, n: int, block: int = 1 << 16) -> np.ndarray:
    """``np.stack([c[:n] for c in columns], 1).mean(0)`` (float64 values of arrays or `Coded`) bit
    for bit, without the [n, M] copy (`_column_sums`; one column is summed pairwise: whole)."""
    if len(columns) == 1:
        return np.stack([as_values(columns[0], 0, n)], 1).mean(0)
    return _column_sums(np.stack([as_values(c, i, min(n, i + block)) for c in columns], 1)
                        for i in range(0, n, block)) / n


def moment_sums(c: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sums of values and squares of each row of counts c [R, D]."""
    return c @ values, c @ (values * values)


def jackknife_iqm_counts(counts: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Leave-one-out IQM for a unit of each distinct value (ascending values, counts > 0)."""
    drop = np.asarray(counts, np.float64)[None] - np.eye(counts.size)
    return iqm_from_counts(drop, values)


def iqm_interval(est: float, path: str, alpha: float, *, x=None, star=None, values=None, counts=None):
    """The IQM's interval on `path` (`resampling_path`), its one definition: BCa (Efron 1987) of the
    replicates `star` with the jackknife of the units x (`RAW`) or of a unit of each distinct value
    (`PER_VALUE`: `values` with `counts`), or BCa on the bootstrap's normal limit (`ASYMPTOTIC`)."""
    if path == ASYMPTOTIC:
        return normal_bca(est, jackknife_iqm(x), alpha)
    jk = [jackknife_iqm(x)] if path == RAW else [(jackknife_iqm_counts(counts, values), counts)]
    return bca_interval(est, star, jk, alpha)


def compile_ahead(n: int, trials: int, splits: int, block: int = 4096) -> None:
    """Compile the large-N path's device programs for success bits of n seeds per method and T
    trials (per-seed measures, curve sums, calibration halves) before the data exists: `jaxeac
    grid` calls it on a thread while the run computes. The programs land in the persistent
    compilation cache, so the comparison loads them instead of compiling them (with the cache off
    they compile again).
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
    for rows in {min(n, CODES_BLOCK), n % CODES_BLOCK} - {0}:  # the per-seed measures (`device_codes`)
        _codes.lower(jax.ShapeDtypeStruct((rows, width), jnp.uint8), trials, late_window(trials)).compile()
    _gram.lower(jax.ShapeDtypeStruct((n, trials), jnp.bool_), BLOCK).compile()
    if splits > 0:
        nblocks = -(-2 * h // block)
        key = jax.random.key(0)
        _subset_sums.lower(key, jax.ShapeDtypeStruct((2 * h, trials), jnp.bool_),
                           jax.ShapeDtypeStruct((splits, nblocks), jnp.int32), block, True, 32).compile()
