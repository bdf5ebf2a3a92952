"""One task's bootstrap groups and the rows the engine builds from them (`jaxeac.stats.engine`).

A `Group` is one algorithm on one task: its sorted values, distinct values with counts,
the bootstrap counts over them drawn by the group's path (`large.resampling_path`), units
first, and, computed once on first use, their cumulative counts and sums (`task_groups` draws a
task's groups together). `pair_row` is the unpaired comparison of two groups, `paired_row` the
paired one of per-seed differences. `shared_draw` is a task's one draw of its seed ids shared by
its algorithms (`SharedDraw`), and `aggregate_draws` what the aggregate across tasks takes of it.
"""

from __future__ import annotations

import math

import jax
import numpy as np
from scipy import special

from jaxeac.perseed import PerSeed
from jaxeac.rng import as_key
from jaxeac.stats import closed_form as cf
from jaxeac.stats import large
from jaxeac.stats._rng import host_rng, multinomial_counts
from jaxeac.stats.asymptotic import abc_two_sample
from jaxeac.stats.bca import bca_interval, bca_two_sample_counts
from jaxeac.stats.large import resampling_path
from jaxeac.stats.paired import PAIRED_TEST_FIELDS, paired_analysis, paired_tests
from jaxeac.stats.resample import boot_counts, boot_counts_binned, cumulative
from jaxeac.stats.tasks import below_half, wins_replicates

#: Bootstrap counts kept for the aggregate across tasks (beyond, drawn again from the same keys).
MAX_KEPT_BYTES = 1 << 30


class Group:
    """One algorithm on one task: its sorted values x, their distinct values with counts, and the
    bootstrap counts per distinct value, CT [D, R] float32 (exact integers), drawn by the group's
    path (raw draws of the units, counted per value on the device, or counts per value); their
    cumulative counts and sums are computed once, on first use."""

    def __init__(self, x, key, resamples: int, chunk: int = 1000, *, in_order: bool = False, counted=None,
                 draw: bool = True):
        """`in_order`: raw draws index the units in the order given (by default: sorted). `counted`:
        (ascending distinct values, their counts) in place of x: exact counts per value at any n,
        without a per-unit copy (then `x` is None). `draw` False: raw draws are left to the caller
        (`task_groups`), which sets `CT` from `bins`, each unit's value index."""
        if counted is None:
            self.x = np.sort(np.asarray(x, np.float64))
            distinct, counts = np.unique(self.x, return_counts=True)
            self.path = resampling_path(self.x.size, distinct.size)
        else:
            (distinct, counts), self.x, self.path = counted, None, large.PER_VALUE
        self.values, self.k, self.CT = distinct, counts, None
        self.n = int(counts.sum())
        if self.path == large.RAW:  # the raw draws of the units, counted per distinct value (same numbers)
            bins = np.searchsorted(distinct, x) if in_order else np.repeat(np.arange(distinct.size), counts)
            self.bins = bins.astype(np.int32)
            if draw:
                self.CT = boot_counts(key, self.n, resamples, chunk=chunk, units_first=True, bins=self.bins)
        elif self.path == large.PER_VALUE:
            c = multinomial_counts(host_rng(key), counts, resamples)  # exact in float32 below 2^24 units
            self.CT = np.ascontiguousarray(c.T, np.float32 if self.n < 1 << 24 else np.float64)
        self.mean = float(self.x.mean()) if self.x is not None else float(counts @ distinct / self.n)
        self._cum = self._sums = None

    @property
    def cum(self) -> np.ndarray:
        """Cumulative counts [D + 1, R], row i the units below value i."""
        if self._cum is None:
            self._cum = cumulative(self.CT, zero_row=True)
        return self._cum

    def sums(self):
        if self._sums is None:
            s = np.stack([self.values, self.values * self.values]) @ self.CT.astype(np.float64)
            self._sums = (s[0], s[1])
        return self._sums

    def iqm(self, alpha: float) -> list[float]:
        if self.x is None:
            est = float(large.iqm_from_counts(self.k[None], self.values)[0])
        else:
            est = cf.iqm_sorted(self.x)
        star = None if self.CT is None else large.iqm_from_counts(self.CT, self.values, units_first=True,
                                                                  cum=self.cum[1:])
        return [est, *large.iqm_interval(est, self.path, alpha, x=self.x, star=star, values=self.values,
                                         counts=self.k)]


def wins(gx: Group, gy: Group):
    """P(X > Y) + ½ P(X = Y): the estimate, its replicates (or None) and the jackknife per sample."""
    s = below_half(gy.values, np.r_[0, np.cumsum(gy.k)], gx.values)  # per x value: y units below it
    t = gx.n - below_half(gx.values, np.r_[0, np.cumsum(gx.k)], gy.values)  # per y value: x units above
    nx, ny = gx.n, gy.n
    est = float(gx.k @ s / (nx * ny))
    star = None
    if gx.CT is not None and gy.CT is not None:
        star = wins_replicates(gx.values, gx.CT, gy.values, gy.cum, nx, ny)
    total = gx.k @ s
    jx = (total - s) / ((nx - 1) * ny)
    jy = (total - t) / (nx * (ny - 1))
    return est, star, [(jx, gx.k), (jy, gy.k)]


def _normal_two(est, jks, alpha):
    """Normal-limit interval from the jackknife of two independent samples (the asymptotic path)."""
    var = 0.0
    for jk, w in jks:
        n = w.sum()
        m = (w @ jk) / n
        var += (n - 1) / n * (w @ (jk - m) ** 2)
    z = special.ndtri(1 - alpha / 2) * math.sqrt(var)
    return [est, est - z, est + z]


def two_sample_ci(statistic: str, gb: Group, gt: Group, alpha: float) -> cf.Estimate:
    """mean(treatment) − mean(baseline) ("mean_diff") or Hedges' g ("hedges_g") with its BCa interval
    (Efron 1987) from the groups' bootstrap counts, or the ABC interval where a group has none."""
    if gb.CT is not None and gt.CT is not None:
        return bca_two_sample_counts(statistic, gb.values, gb.k, gt.values, gt.k, *gb.sums(), *gt.sums(),
                                     alpha)
    return abc_two_sample(statistic, gb.x, gt.x, alpha)


def bca_ci(x_baseline, x_treatment, key, *, statistic: str = "mean_diff", resamples: int = 10_000,
           alpha: float = 0.05, chunk: int = 1000) -> cf.Estimate:
    """BCa bootstrap CI for mean(treatment) − mean(baseline) or Hedges' g (`two_sample_ci`), the two
    samples resampled independently (under split(key)), as in
    `scipy.stats.bootstrap((x_baseline, x_treatment), ..., method="BCa")`."""
    if statistic not in ("mean_diff", "hedges_g"):
        raise ValueError(f"statistic must be 'mean_diff' or 'hedges_g', got {statistic!r}")
    x, y = cf.check_sample(x_baseline, "x_baseline"), cf.check_sample(x_treatment, "x_treatment")
    kb, kt = jax.random.split(as_key(key), 2)
    groups = (Group(z, k, resamples, chunk, in_order=True) for z, k in ((x, kb), (y, kt)))
    return two_sample_ci(statistic, *groups, alpha)


def iqm_ci(x, key, *, resamples: int = 10_000, alpha: float = 0.05, chunk: int = 1000) -> cf.Estimate:
    """IQM of one method's per-seed values with a BCa bootstrap CI, on the path
    `large.resampling_path` gives (raw draws on the device, counts per value, or the normal limit)."""
    est, lo, hi = Group(cf.check_sample(x), as_key(key), resamples, chunk).iqm(alpha)
    return cf.Estimate(est, lo, hi, 1 - alpha)


def task_groups(values: dict, keys: dict, resamples: int, chunk: int = 1000) -> dict[str, Group]:
    """Every algorithm's `Group` on one task (values ``values[a]``, key ``keys[a]``), the raw draws
    of its groups of one size made together (`boot_counts_binned`): each group's own draws, bit for
    bit, in a few device calls instead of one per group."""
    groups = {a: Group(x, keys[a], resamples, chunk, draw=False) for a, x in values.items()}
    sizes: dict = {}
    for a, g in groups.items():
        if g.path == large.RAW:
            sizes.setdefault(g.n, []).append(a)
    for n, names in sizes.items():
        cts = boot_counts_binned([keys[a] for a in names], n, resamples, [groups[a].bins for a in names],
                                 chunk=chunk)
        for a, ct in zip(names, cts, strict=True):
            groups[a].CT = ct
    return groups


def pair_row(gx: Group, gy: Group, alpha: float) -> dict:
    """The unpaired comparison of one task's pair (X − Y)."""
    welch = cf.welch_t(gy.x, gx.x)
    d = two_sample_ci("mean_diff", gy, gx, alpha)
    diff_ci = [d.low, d.high]
    p_hat, star, jk = wins(gx, gy)
    p_ci = (
        list(bca_interval(p_hat, star, jk, alpha)) if star is not None else _normal_two(p_hat, jk, alpha)[1:]
    )
    return {
        "n_x": gx.n,
        "n_y": gy.n,
        "mean_x": gx.mean,
        "mean_y": gy.mean,
        "diff": gx.mean - gy.mean,
        "diff_ci": diff_ci,
        "t_welch": welch.statistic,
        "df_welch": welch.df,
        "p_welch": welch.pvalue,
        "hedges_g": cf.hedges_g(gy.x, gx.x),
        "p_improvement": p_hat,
        "p_improvement_ci": p_ci,
    }


def paired_row(d: np.ndarray, alpha: float, key, resamples: int = 10_000, *, path: str | None = None,
               per_seed: np.ndarray | None = None) -> dict:
    """The paired comparison: per-seed differences d (X − Y of the same seed id). The interval takes
    the path `resampling_path(n, distinct, paired=True)` gives (recorded as ``path``): raw draws
    from `per_seed`, the task's shared draw over its seeds [n, R], else
    `jaxeac.stats.paired.paired_analysis`, the run folders' paired analysis, which follows the same
    rule. `path`: that path, if already known."""
    n = d.size
    path = path or resampling_path(n, np.unique(d).size, paired=True)  # the one rule, as paired.py
    if per_seed is None or path != large.RAW:
        res = paired_analysis(np.zeros(n), d, key, resamples=resamples, alpha=alpha, mean_only=True)
        return {k: res[k] for k in PAIRED_TEST_FIELDS} | {"path": path, "mean_diff_ci": res["mean_diff_ci95"]}
    out = paired_tests(d) | {"path": path}
    star = d @ per_seed.astype(np.float64) / n
    out["mean_diff_ci"] = list(bca_interval(out["mean_diff"], star, [(d.sum() - d) / (n - 1)], alpha))
    return out


class SharedDraw:
    """One bootstrap draw of a task's n seed ids, shared by its algorithms (the paired bootstrap):
    as counts per seed [n, R] (`units`, drawn on first use), or, for one algorithm's values x in
    seed order, the same draws counted per distinct value of x on the device (`per_value`: the
    ascending distinct values and their counts [D, R]), so the host never holds [n, R] unless a
    paired row resamples continuous differences."""

    def __init__(self, key, n: int, resamples: int, chunk: int):
        self.key, self.n, self.resamples, self.chunk = key, n, resamples, chunk
        self._units = None

    def units(self) -> np.ndarray:
        if self._units is None:
            self._units = boot_counts(self.key, self.n, self.resamples, chunk=self.chunk, units_first=True)
        return self._units

    def per_value(self, xs: dict[str, np.ndarray]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """{name: (ascending distinct values of xs[name], the draws' counts per value [D, R])}, the
        one draw binned for every array of `xs` at once (`boot_counts_binned`)."""
        split = {a: np.unique(x, return_inverse=True) for a, x in xs.items()}
        counts = boot_counts_binned(self.key, self.n, self.resamples,
                                    [inverse.astype(np.int32) for _, inverse in split.values()], chunk=self.chunk)
        return {a: (d[0], c) for (a, d), c in zip(split.items(), counts, strict=True)}


def shared_draw(per: PerSeed, task, used, paired, key, resamples, chunk):
    """Where the algorithms of a task share seed ids: their values in one seed order, and one
    draw of those seeds (a `SharedDraw`, the paired bootstrap); else (None, None)."""
    if paired == "unpaired" or per.seeds is None:
        return None, None
    ids = {a: per.seeds[task][a] for a in used}
    ref = np.sort(ids[used[0]])
    order = {}
    for a in used:
        s = np.sort(ids[a])
        if s.shape == ref.shape and np.array_equal(s, ref):
            order[a] = per.values[task][a][np.argsort(ids[a], kind="stable")]
    if len(order) < 2:
        return None, None
    n = ref.size
    if resampling_path(n, n) != large.RAW:
        return None, order
    return SharedDraw(key, n, resamples, chunk), order


def aggregate_draws(per: PerSeed, task, tkey, groups, shared, order, resamples, chunk, keep):
    """The task's draws for the aggregate across tasks: the shared draw where every algorithm ran
    the same seed ids (counted per value of each), else each group's own (drawn again from its
    key when not kept, by raw draws where its path has none)."""
    if shared is not None and len(order) == len(per.algos):
        # drawn now (on the task's thread), binned for every algorithm at once, where every task's
        # counts per value (float32 [D, R] per algorithm) would fit; else the aggregate draws each
        # task again after the last (11 tasks of 1,000 seeds arriving 2.5 s apart, 2-core CPU:
        # 6.6-8.7 s left after the last, 1.9-2.1 s kept)
        values = sum(np.unique(x).size for x in order.values())
        if keep or values * resamples * 4 * len(per.tasks) <= MAX_KEPT_BYTES:
            return shared.per_value(order), True
        left: dict = {}  # binned for every algorithm at the first call, each handed out once
        taken: set = set()

        def take(a):
            if not taken:
                left.update(shared.per_value(order))
            taken.add(a)
            return left.pop(a) if a in left else shared.per_value({a: order[a]})[a]

        return {a: (lambda a=a: take(a)) for a in per.algos}, True

    def one(j, a):
        g = groups[a] if keep or held(a) else Group(per.values[task][a], jax.random.fold_in(tkey, j), resamples,
                                                      chunk)
        if g.CT is None:
            key = jax.random.fold_in(tkey, j)
            return g.x, boot_counts(key, g.n, resamples, chunk=chunk, units_first=True)
        return g.values, g.CT

    def held(a):  # counts per value, small whatever the seeds: kept if every group's would fit
        ct = groups[a].CT
        return ct is not None and ct.nbytes * len(per.algos) * len(per.tasks) <= MAX_KEPT_BYTES

    return {a: one(j, a) if keep or held(a) else (lambda j=j, a=a: one(j, a))
            for j, a in enumerate(per.algos)}, False
