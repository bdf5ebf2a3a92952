"""Aggregates across tasks (Agarwal et al. 2021, "Deep RL at the edge of the statistical precipice").

Scores are first put on one scale per task: min–max against stated reference scores
(``(x − low) / (high − low)``, e.g. random and human scores), relative to a baseline algorithm
(``x / mean of the baseline on that task``), or as they are (``"none"``, for scores already on
one scale). Then, per algorithm, over all runs of all tasks pooled (as rliable does on its
``[runs, tasks]`` arrays, so a task with more seeds weighs more): the mean, the median, the IQM
(``scipy.stats.trim_mean(x, 0.25)``) and the optimality gap ``γ − mean(min(x, γ))``, γ = 1;
per pair, the probability of improvement averaged over tasks (P(X > Y) + ½ P(X = Y) per task,
Mann–Whitney); and performance profiles, the share of runs scoring above τ on a grid of
thresholds. Intervals are percentile intervals (rliable's default) of the stratified
bootstrap: seeds resampled within each task and algorithm; where every algorithm of a task
ran the same seed ids, one draw of those seeds serves all of them (paired across tasks).
"""

from __future__ import annotations

import math

import jax
import numpy as np

from jaxeac.errors import UsageError
from jaxeac.stats import large
from jaxeac.stats.inputs import PerSeed, excerpt
from jaxeac.stats.resample import boot_counts

NORMALIZATIONS = ("minmax", "baseline", "none")
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


def normalized(per: PerSeed, normalize, reference, baseline) -> tuple[dict, dict]:
    """{task: {algo: scores on one scale}} and the normalisation's record."""
    out = {}
    for t in per.tasks:
        if normalize == "minmax":
            low, high = (float(v) for v in reference[t])
            out[t] = {a: (x - low) / (high - low) for a, x in per.values[t].items()}
        elif normalize == "baseline":
            m = float(per.values[t][baseline].mean())
            out[t] = {a: x / m for a, x in per.values[t].items()}
        else:
            out[t] = dict(per.values[t])
    text = {
        "minmax": "min–max normalised per task, (x − low) / (high − low) with the stated reference scores",
        "baseline": f"relative to {baseline}: x / mean of {baseline} on the task",
        "none": "raw scores, taken to be on one scale",
    }[normalize]
    rec = {"method": normalize, "text": text}
    if normalize == "minmax":
        rec["reference"] = {t: [float(v) for v in reference[t]] for t in per.tasks}
    return out, rec


def _draws(per: PerSeed, scores: dict, task_index: int, task, key, resamples: int, shared: bool, only=None):
    """Per algorithm of one task: (values sorted, counts [R, n] float32 in that order)."""
    tkey = jax.random.fold_in(key, task_index)
    algos = per.algos
    ids = None if (per.seeds is None or not shared) else per.seeds[task]
    same = ids is not None and all(np.array_equal(np.sort(ids[a]), np.sort(ids[algos[0]])) for a in algos)
    out = {}
    if same:
        n = ids[algos[0]].size
        C = boot_counts(tkey, n, resamples)
        for a in algos:
            by_id = scores[task][a][np.argsort(ids[a], kind="stable")]
            order = np.argsort(by_id, kind="stable")
            out[a] = (by_id[order], np.ascontiguousarray(C[:, order]))
            if a == only:
                return {a: out[a]}, True
        return out, True
    for j, a in enumerate(algos):
        if only is not None and a != only:
            continue
        x = np.sort(scores[task][a])
        out[a] = (x, boot_counts(jax.random.fold_in(tkey, j), x.size, resamples))
    return out, False


def _order_stat(cum: np.ndarray, v: np.ndarray, k: int) -> np.ndarray:
    """The k-th smallest (0-based) of each resample, from inclusive cumulative counts [R, N]."""
    return v[np.minimum((cum <= k).sum(1), v.size - 1)]


def point_estimates(x: np.ndarray) -> dict:
    """mean, median, IQM and optimality gap of pooled scores (rliable's definitions)."""
    from scipy import stats

    return {
        "mean": float(x.mean()),
        "median": float(np.median(x)),
        "iqm": float(stats.trim_mean(x, 0.25)),
        "optimality_gap": float(GAMMA - np.minimum(x, GAMMA).mean()),
    }


def _replicates(v: np.ndarray, C: np.ndarray, tau: np.ndarray) -> tuple[dict, np.ndarray]:
    """Aggregates [R] and profile [R, len(tau)] of each resample from counts C [R, N] (float32, exact
    integers) over ascending pooled scores v."""
    n = v.size
    cum = np.cumsum(C, axis=1)  # along the contiguous axis, no dtype cast: fast
    med = 0.5 * (_order_stat(cum, v, (n - 1) // 2) + _order_stat(cum, v, n // 2))
    reps = {
        "mean": C @ v / n,
        "median": med,
        "iqm": large.iqm_from_counts(C, v),
        "optimality_gap": GAMMA - C @ np.minimum(v, GAMMA) / n,
    }
    pos = np.searchsorted(v, tau, "right")  # runs at or below τ: the first pos scores
    below = np.concatenate([np.zeros((C.shape[0], 1), C.dtype), cum], axis=1)[:, pos]
    return reps, 1.0 - below / n


def _pair_wins(vx, cx, vy, cy) -> np.ndarray:
    lo, hi = np.searchsorted(vy, vx, "left"), np.searchsorted(vy, vx, "right")
    cum = np.concatenate([np.zeros((cy.shape[0], 1), np.float32), np.cumsum(cy, axis=1)], axis=1)
    return np.einsum("ri,ri->r", cx, cum[:, lo] + 0.5 * (cum[:, hi] - cum[:, lo])) / (vx.size * vy.size)


def prob_improvement(x, y) -> float:
    """P(X > Y) + ½ P(X = Y) over all pairs of values (Mann–Whitney U / (n m))."""
    x, y = np.sort(np.asarray(x, np.float64)), np.sort(np.asarray(y, np.float64))
    lo, hi = np.searchsorted(y, x, "left"), np.searchsorted(y, x, "right")
    return float((lo + 0.5 * (hi - lo)).sum() / (x.size * y.size))


def aggregate_across_tasks(
    per: PerSeed,
    family,
    *,
    normalize: str,
    reference=None,
    baseline=None,
    key=0,
    resamples: int = 10_000,
    level: float = 0.95,
    points: int = 101,
    shared: bool = True,
    tau=None,
) -> dict:
    """The aggregates across tasks (see the module docstring) as a JSON-ready dict."""
    from jaxeac.stats._rng import as_key

    check_normalization(per, normalize, reference, baseline)
    scores, norm = normalized(per, normalize, reference, baseline)
    key = as_key(key)
    algos, tasks = per.algos, per.tasks
    pooled = {a: np.concatenate([scores[t][a] for t in tasks]) for a in algos}
    lo_all = min(float(x.min()) for x in pooled.values())
    hi_all = max(float(x.max()) for x in pooled.values())
    tau = np.linspace(lo_all, hi_all, points) if tau is None else np.asarray(tau, np.float64)
    q = [50 * (1 - level), 50 * (1 + level)]
    # pass 1, task by task: the pairs' probability of improvement
    pair_est = {p: [] for p in family}
    pair_star = {p: np.zeros(resamples) for p in family}
    paired_tasks = 0
    for i, t in enumerate(tasks):
        drawn, same = _draws(per, scores, i, t, key, resamples, shared)
        paired_tasks += same
        for x, y in family:
            (vx, cx), (vy, cy) = drawn[x], drawn[y]
            pair_est[(x, y)].append(prob_improvement(vx, vy))
            pair_star[(x, y)] += _pair_wins(vx, cx, vy, cy)
    # pass 2, algorithm by algorithm: the same draws, pooled over tasks
    out_algos, profiles = {}, {"tau": tau.tolist()}
    for a in algos:
        parts = [_draws(per, scores, i, t, key, resamples, shared, a)[0][a] for i, t in enumerate(tasks)]
        v = np.concatenate([p[0] for p in parts])
        order = np.argsort(v, kind="stable")
        C = np.ascontiguousarray(np.concatenate([p[1] for p in parts], axis=1)[:, order])
        v = v[order]
        reps, prof = _replicates(v, C, tau)
        est = point_estimates(v)
        out_algos[a] = {k: {"estimate": est[k], "ci": np.percentile(reps[k], q).tolist()} for k in est}
        share = (v[None, :] > tau[:, None]).mean(1)
        lo, hi = np.percentile(prof, q, axis=0)
        profiles[a] = {"share": share.tolist(), "low": lo.tolist(), "high": hi.tolist()}
    pairs = [
        {
            "x": x,
            "y": y,
            "estimate": float(np.mean(pair_est[(x, y)])),
            "ci": np.percentile(pair_star[(x, y)] / len(tasks), q).tolist(),
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
            f"Per algorithm over all runs of the {len(tasks)} tasks pooled: mean, median, IQM, optimality "
            f"gap (γ = {GAMMA:g}); probability of improvement averaged over tasks; {100 * level:.6g}% "
            f"percentile intervals from {resamples:,} stratified bootstrap resamples (seeds within each "
            f"task; {paired_tasks} of {len(tasks)} tasks with shared seed ids drawn once for all "
            "algorithms). As rliable (Agarwal et al. 2021)."
        ),
        "algorithms": out_algos,
        "pairs": pairs,
        "profiles": profiles,
    }
