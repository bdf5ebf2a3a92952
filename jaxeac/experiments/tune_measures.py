"""What `jaxeac.experiments.tune` measures beyond the selections: sensitivity curves and numbers,
and EAC head to head with AC, Q-learning and SARSA (pure NumPy on the runs' per-seed successes).

- `curves`: per key, mean successes at each value with the other keys at the selection, a 95 % t
  band over the tuning seeds.
- `sensitivity`: best − median over the grid (Patterson et al. 2024's sensitivity, on mean
  successes / T), per task and of the cross-task score, with 95 % percentile intervals from
  resampling the tuning seeds within each task — one set of draws for all algorithms (they ran the
  same seeds), so differences from AC are paired; `claim` reads "EAC is less sensitive" off EAC − AC.
- `head_to_head`: EAC − X per task (Welch 95 %, `welch_diff_ci95`) and the mean over tasks of
  (EAC − X) / T with a normal interval from the per-task variances (tasks run independently).
"""

from __future__ import annotations

import math

import numpy as np

from jaxeac.experiments.common import welch_diff_ci95

#: The baselines EAC meets head to head.
RIVALS = ("ac", "q_learning", "sarsa")


def _band(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per row of `x` [points, seeds]: mean and its 95 % t interval over the seeds."""
    from scipy import special

    n = x.shape[1]
    mean = x.mean(axis=1)
    half = special.stdtrit(n - 1, 0.975) * x.std(axis=1, ddof=1) / math.sqrt(n)
    return mean, mean - half, mean + half


def curves(points: list[dict], chosen: int, x: np.ndarray) -> dict:
    """Per key with two or more values: mean successes at each of its values, the other keys at
    ``points[chosen]``, with 95 % t intervals over the tuning seeds (`x`: [points, seeds])."""
    mean, lo, hi = _band(x.astype(np.float64))
    out = {}
    for k in points[chosen] if points else ():
        idx = [i for i, p in enumerate(points) if all(p[o] == v for o, v in points[chosen].items() if o != k)]
        if len(idx) > 1:
            out[k] = {"values": [points[i][k] for i in idx], "mean": mean[idx].tolist(),
                      "ci95": [[float(lo[i]), float(hi[i])] for i in idx], "chosen": points[chosen][k]}
    return out


def sensitivity(scores: dict, tasks: list, trials: int, *, resamples: int, key: int, same_keys=lambda a: True) -> dict:
    """Best − median of each algorithm's grid, of its cross-task score and per task (scores / T),
    with 95 % percentile intervals from resampling the tuning seeds within each task (one set of
    draws for all algorithms, which ran the same seeds), and each algorithm's difference from AC."""
    rng = np.random.default_rng(key)
    n = next(iter(scores.values()))[tasks[0]].shape[1]
    weights = [rng.multinomial(n, np.full(n, 1.0 / n), size=resamples).T / n for _ in tasks]  # [seeds, B]

    def spread(m):  # [points, ...] → best − median over the points
        return m.max(axis=0) - np.median(m, axis=0)

    draws, out = {}, {}
    for a, per in scores.items():
        boot = np.stack([per[t].astype(np.float64) @ w for t, w in zip(tasks, weights, strict=True)]) / trials
        point = np.stack([per[t].mean(axis=1) for t in tasks]) / trials  # [tasks, points]
        draws[a] = (spread(boot.mean(axis=0)), spread(np.moveaxis(boot, 1, 0)))  # [B], [tasks, B]
        out[a] = {"estimate": float(spread(point.mean(axis=0))),
                  "ci95": np.percentile(draws[a][0], [2.5, 97.5]).tolist(),
                  "per_task": {t: {"estimate": float(spread(point[i])),
                                   "ci95": np.percentile(draws[a][1][i], [2.5, 97.5]).tolist()}
                               for i, t in enumerate(tasks)}}
    if "ac" in draws:
        for a in draws:
            d, dt = draws[a][0] - draws["ac"][0], draws[a][1] - draws["ac"][1]
            out[a]["minus_ac"] = {"estimate": out[a]["estimate"] - out["ac"]["estimate"],
                                  "ci95": np.percentile(d, [2.5, 97.5]).tolist(),
                                  "same_keys": same_keys(a),
                                  "tasks_less": int((np.percentile(dt, 97.5, axis=1) < 0).sum()),
                                  "tasks_more": int((np.percentile(dt, 2.5, axis=1) > 0).sum())}
    return {"resamples": resamples, "key": key, "algorithms": out,
            "method": "best − median over the grid of mean successes / T (per task, and of the mean over tasks); "
                      "95 % percentile interval from resampling the tuning seeds within each task, the same "
                      "draws for every algorithm"}


def claim(sens: dict) -> dict:
    """"EAC is less sensitive to its rates (than AC)": holds, refuted or not shown, from EAC − AC."""
    m = sens["algorithms"].get("eac", {}).get("minus_ac")
    if m is None:
        return {"verdict": "not tested (needs ac and eac)"}
    lo, hi = m["ci95"]
    verdict = "holds" if hi < 0 else "refuted: EAC is more sensitive" if lo > 0 else \
        "not shown: the interval includes 0"
    return {"verdict": verdict, **m}


def head_to_head(conditions: dict, trials: int) -> dict:
    """EAC − AC, Q-learning and SARSA per task (Welch 95 %) and over tasks (mean of (EAC − X) / T,
    its 95 % normal interval from the per-task Welch variances; tasks independent), per condition,
    with each task's leader (highest mean) and whether tuning changed it."""
    out: dict = {}
    for c, per in conditions.items():
        tasks = list(per)
        rivals = [r for r in RIVALS if "eac" in per[tasks[0]] and r in per[tasks[0]]]
        rows = {}
        for r in rivals:
            cells, var = {}, []
            for t in tasks:
                x, y = np.asarray(per[t]["eac"], np.float64), np.asarray(per[t][r], np.float64)
                d, lo, hi = welch_diff_ci95(y, x)
                cells[t] = {"diff": d, "ci95": [lo, hi], "verdict": "higher" if lo > 0 else "lower" if hi < 0 else "tie"}
                var.append(x.var(ddof=1) / x.size + y.var(ddof=1) / y.size)
            mean = float(np.mean([cells[t]["diff"] for t in tasks])) / trials
            half = 1.959964 * math.sqrt(sum(var)) / len(tasks) / trials
            rows[r] = {"per_task": cells, "over_tasks": {"diff": mean, "ci95": [mean - half, mean + half]},
                       "higher": sum(v["verdict"] == "higher" for v in cells.values()),
                       "lower": sum(v["verdict"] == "lower" for v in cells.values())}
        leaders = {t: max(per[t], key=lambda a, t=t: float(np.mean(per[t][a]))) for t in tasks}
        out[c] = {"rivals": rows, "leaders": leaders}
    if "preset" in out:
        for c in out:
            out[c]["leader_changed"] = [t for t, a in out[c]["leaders"].items() if a != out["preset"]["leaders"][t]]
    return out
