"""Aggregates across tasks (Agarwal et al. 2021, "Deep RL at the edge of the statistical precipice").

Scores are first put on one scale per task: min–max against stated reference scores
(``(x − low) / (high − low)``, e.g. random and human scores), relative to a baseline algorithm
(``x / mean of the baseline on that task``), or as they are (``"none"``, for scores already on
one scale). Then, per algorithm, as rliable's `metrics`: the mean and the median of the
per-task means, and over all runs of all tasks pooled (so a task with more seeds weighs more)
the IQM (``scipy.stats.trim_mean(x, 0.25)``) and the optimality gap ``γ − mean(min(x, γ))``, γ = 1;
per pair, the probability of improvement averaged over tasks (P(X > Y) + ½ P(X = Y) per task,
Mann–Whitney); and performance profiles, the share of runs scoring above τ on a grid of
thresholds. Intervals are percentile intervals (rliable's default) of the stratified
bootstrap: seeds resampled within each task and algorithm; where every algorithm of a task
ran the same seed ids, one draw of those seeds serves all of them (paired across tasks).
"""

from __future__ import annotations

import math

import numpy as np

from jaxeac.errors import UsageError
from jaxeac.perseed import PerSeed, excerpt
from jaxeac.stats import large
from jaxeac.stats.closed_form import a12_counts, iqm_sorted
from jaxeac.stats.resample import cumulative

NORMALIZATIONS = ("minmax", "baseline", "none")
#: Units × resamples of pooled counts handled at once.
BLOCK_ELEMENTS = 1 << 22
GAMMA = 1.0


def check_normalization(per: PerSeed, normalize, reference, baseline) -> None:
    if normalize not in NORMALIZATIONS:
        raise UsageError(f"--normalize must be one of {', '.join(NORMALIZATIONS)} (got {excerpt(normalize)})")
    if normalize == "minmax":
        reference = reference or {}
        missing = [t for t in per.tasks if t not in reference]
        if missing:
            raise UsageError(
                f"--normalize minmax needs reference scores (low, high) for every task; task "
                f"{excerpt(missing[0], 30)} has none (give them with --reference-scores FILE: "
                "CSV task,low,high)"
            )
        for t in per.tasks:
            low, high = (float(v) for v in reference[t])
            if not (math.isfinite(low) and math.isfinite(high) and high > low):
                raise UsageError(
                    f"reference scores of task {excerpt(t, 30)} are ({low:g}, {high:g}); they need "
                    "low < high, both finite"
                )
    if normalize == "baseline":
        if baseline is None:
            raise UsageError(
                "--normalize baseline divides each task's scores by the baseline's mean there; "
                "name it with --baseline"
            )
        for t in per.tasks:
            if per.values[t][baseline].mean() == 0:
                raise UsageError(
                    f"the baseline {excerpt(baseline, 20)} has mean 0 on task {excerpt(t, 30)}, so "
                    "scores cannot be relative to it; use --normalize minmax with reference scores"
                )


def _scales(per: PerSeed, normalize, reference, baseline) -> dict:
    """{task: the map of raw scores onto one scale}."""
    out = {}
    for t in per.tasks:
        if normalize == "minmax":
            low, high = (float(v) for v in reference[t])
            out[t] = lambda x, low=low, high=high: (x - low) / (high - low)
        elif normalize == "baseline":
            m = float(per.values[t][baseline].mean())
            out[t] = lambda x, m=m: x / m
        else:
            out[t] = lambda x: x
    return out


def normalized(per: PerSeed, normalize, reference, baseline) -> tuple[dict, dict]:
    """{task: {algo: scores on one scale}} and the normalisation's record."""
    scale = _scales(per, normalize, reference, baseline)
    out = {t: {a: scale[t](x) for a, x in per.values[t].items()} for t in per.tasks}
    text = {
        "minmax": "min–max normalised per task, (x − low) / (high − low) with the stated reference scores",
        "baseline": f"relative to {baseline}: x / mean of {baseline} on the task",
        "none": "raw scores, taken to be on one scale",
    }[normalize]
    rec = {"method": normalize, "text": text}
    if normalize == "minmax":
        rec["reference"] = {t: [float(v) for v in reference[t]] for t in per.tasks}
    return out, rec


def point_estimates(per_task: list) -> dict:
    """rliable's aggregates of scores on one scale, a list of per-task arrays: the mean and the
    median of the per-task means, the IQM and the optimality gap of all runs pooled."""
    means, x = [float(s.mean()) for s in per_task], np.concatenate(per_task)
    return {
        "mean": float(np.mean(means)),
        "median": float(np.median(means)),
        "iqm": iqm_sorted(np.sort(x)),
        "optimality_gap": float(GAMMA - np.minimum(x, GAMMA).mean()),
    }


def _replicates(v: np.ndarray, ct: np.ndarray, n: int, tau: np.ndarray) -> tuple[dict, np.ndarray]:
    """IQM and optimality gap [R] and profile [len(tau), R] of each resample from counts units
    first ct [D, R] (float32, exact integers; n units in all) over ascending pooled scores v."""
    cum = cumulative(ct, zero_row=True)  # row i: units below value i
    reps = {
        "iqm": large.iqm_from_counts(ct, v, units_first=True, cum=cum[1:]),
        "optimality_gap": GAMMA - np.minimum(v, GAMMA) @ ct.astype(np.float64) / n,
    }
    below = cum[np.searchsorted(v, tau, "right")]  # runs at or below τ
    return reps, 1.0 - below / n


def _collapsed(v: np.ndarray, ct: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ascending distinct values of v [m] and their counts [D, R]: the rows of ct [m, R] (units
    first, float32) of equal values summed, so every statistic below costs O(distinct values)
    per resample (successes over T trials: at most T + 1 values). Few values: one product with
    the rows' indicator matrix; many: the rows in ascending order, as they are. The counts are
    integers of at most the units pooled, so the float32 sums are exact below 2**24 units."""
    distinct, inverse = np.unique(v, return_inverse=True)
    if distinct.size == v.size:
        order = np.argsort(v, kind="stable")
        return distinct, ct if np.all(order[1:] > order[:-1]) else ct[order]
    if distinct.size > large.MAX_DISTINCT:  # equal values' rows added in ascending order
        order = np.argsort(v, kind="stable")
        start = np.flatnonzero(np.r_[True, np.diff(v[order]) != 0])
        return distinct, np.add.reduceat(ct[order], start, axis=0)
    onehot = (inverse[None, :] == np.arange(distinct.size)[:, None]).astype(ct.dtype)
    return distinct, onehot @ ct


def wins_replicates(vx, ctx, vy, cum_y, nx: int, ny: int) -> np.ndarray:
    """P(X > Y) + ½ P(X = Y) of each resample [R] from counts units first over ascending values:
    ctx [Dx, R] and cum_y [Dy + 1, R], y's cumulative counts with a leading zero row. Terms and
    partial sums are multiples of ½ up to nx·ny, so float32 sums are exact while nx·ny ≤ 2²²."""
    lo, hi = np.searchsorted(vy, vx, "left"), np.searchsorted(vy, vx, "right")
    s = cum_y[lo]  # per x value: y units below it ...
    tie = np.flatnonzero(hi != lo)
    if tie.size:  # ... and half of those equal to it
        s[tie] += 0.5 * (cum_y[hi[tie]] - s[tie])
    wide = {} if nx * ny <= 1 << 22 else {"dtype": np.float64}
    return np.einsum("ir,ir->r", ctx, s, **wide).astype(np.float64) / (nx * ny)


def below_half(v: np.ndarray, cum: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Per value of `at`: a sample's units below it plus half of those equal to it, from the
    sample's ascending values v and cumulative counts cum with a leading 0: the pairs
    `closed_form.a12_counts` counts, per value (for the jackknife); `wins_replicates` is its form
    per resample."""
    lo, hi = np.searchsorted(v, at, "left"), np.searchsorted(v, at, "right")
    return cum[lo] + 0.5 * (cum[hi] - cum[lo])


def prob_improvement(x, y) -> float:
    """P(X > Y) + ½ P(X = Y) over all pairs of values (Mann–Whitney U / (n m); Agarwal et al. 2021):
    A12 of X over Y (`closed_form.a12_counts`)."""
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    _, inv = np.unique(np.concatenate([y, x]), return_inverse=True)
    u = int(inv.max()) + 1
    return float(a12_counts(np.bincount(inv[: y.size], minlength=u), np.bincount(inv[y.size :], minlength=u)))


def aggregate_across_tasks(
    per: PerSeed,
    family,
    *,
    normalize: str,
    drawn: list,
    reference=None,
    baseline=None,
    level: float = 0.95,
    points: int = 101,
    tau=None,
) -> dict:
    """The aggregates across tasks (see the module docstring) as a JSON-ready dict. `drawn`, one
    entry per task, is the comparison's own draw: ({algo: (raw values, counts units first
    [rows, R]) or a function giving them}, whether the task's algorithms share one draw)."""
    check_normalization(per, normalize, reference, baseline)
    scores, norm = normalized(per, normalize, reference, baseline)
    scale = _scales(per, normalize, reference, baseline)
    algos, tasks = per.algos, per.tasks

    def got(i, a):  # one task's draw of an algorithm, on the common scale, equal values merged
        e = drawn[i][0][a]
        v, ct = e() if callable(e) else e
        return _collapsed(scale[tasks[i]](np.asarray(v, np.float64)), ct)

    pooled = {a: np.concatenate([scores[t][a] for t in tasks]) for a in algos}
    lo_all = min(float(x.min()) for x in pooled.values())
    hi_all = max(float(x.max()) for x in pooled.values())
    if tau is None and np.ndim(points):  # the thresholds themselves
        tau = points
    tau = np.linspace(lo_all, hi_all, points) if tau is None else np.asarray(tau, np.float64)
    q = [50 * (1 - level), 50 * (1 + level)]
    resamples = None
    pair_est = {p: [] for p in family}
    pair_star = {p: 0.0 for p in family}
    means, parts = {a: [] for a in algos}, {a: [] for a in algos}
    # task by task, each algorithm's draw taken once: the pairs' probability of improvement, the
    # per-task means, and the merged counts kept for pooling across tasks
    for i, t in enumerate(tasks):
        here = {a: got(i, a) for a in algos}
        cums = {}
        for x, y in family:
            (vx, cx), (vy, cy) = here[x], here[y]
            if y not in cums:
                cums[y] = cumulative(cy, zero_row=True)
            nx, ny = per.values[t][x].size, per.values[t][y].size
            pair_est[(x, y)].append(prob_improvement(scores[t][x], scores[t][y]))
            pair_star[(x, y)] = pair_star[(x, y)] + wins_replicates(vx, cx, vy, cums[y], nx, ny)
        for a, (v, ct) in here.items():  # kept where merging made them small; else drawn again
            means[a].append(v @ ct.astype(np.float64) / per.values[t][a].size)
            parts[a].append((v, ct) if ct.size <= BLOCK_ELEMENTS else i)
        del here, cums
    # algorithm by algorithm: the same draws, pooled over tasks
    out_algos, profiles = {}, {"tau": tau.tolist()}
    for a in algos:
        m = np.stack(means.pop(a))
        got_a = [got(p, a) if isinstance(p, int) else p for p in parts.pop(a)]
        v, ct = _collapsed(np.concatenate([p[0] for p in got_a]), np.concatenate([p[1] for p in got_a]))
        del got_a
        resamples = ct.shape[1]
        block = max(64, BLOCK_ELEMENTS // v.size)  # resamples at a time: the block stays in cache
        done = [_replicates(v, ct[:, r : r + block], pooled[a].size, tau) for r in range(0, resamples, block)]
        reps = {k: np.concatenate([d[0][k] for d in done]) for k in done[0][0]}
        reps.update(mean=m.mean(0), median=np.median(m, 0))
        prof = np.concatenate([d[1] for d in done], axis=1)
        est = point_estimates([scores[t][a] for t in tasks])
        out_algos[a] = {k: {"estimate": est[k], "ci": np.percentile(reps[k], q).tolist()} for k in est}
        share = (pooled[a][None, :] > tau[:, None]).mean(1)
        lo, hi = np.percentile(prof, q, axis=1)
        profiles[a] = {"share": share.tolist(), "low": lo.tolist(), "high": hi.tolist()}
    paired_tasks = sum(bool(d[1]) for d in drawn)
    pairs = [
        {
            "x": x,
            "y": y,
            "estimate": float(np.mean(pair_est[(x, y)])),
            "ci": np.percentile(np.asarray(pair_star[(x, y)]) / len(tasks), q).tolist(),
            "per_task": dict(zip(tasks, pair_est[(x, y)], strict=True)),
        }
        for x, y in family
    ]
    return {
        "tasks": tasks,
        "normalization": norm,
        "level": level,
        "resamples": resamples,
        "method": (
            f"Per algorithm: mean and median of the {len(tasks)} per-task means; IQM and optimality gap "
            f"(γ = {GAMMA:g}) over all runs of the tasks pooled; probability of improvement averaged "
            f"over tasks; {100 * level:.6g}% "
            f"percentile intervals from {resamples:,} stratified bootstrap resamples (seeds within each "
            f"task; {paired_tasks} of {len(tasks)} tasks with shared seed ids drawn once for all "
            "algorithms). As rliable (Agarwal et al. 2021)."
        ),
        "algorithms": out_algos,
        "pairs": pairs,
        "profiles": profiles,
    }
