"""Per-seed measures of `jaxeac reproduce` and their summaries (all tests from `jaxeac.stats`).

The seed is the unit of analysis: each function takes one number per seed (or the
per-seed arrays of a run folder) and returns plain JSON-ready values.
"""

from __future__ import annotations

import math
import warnings
import zlib

import numpy as np
from scipy import stats as sps

from jaxeac.experiments.common import mean_ci95


def sub_key(key: int, name: str) -> int:
    """The integer statistics key of one named analysis: (key · 7919 + crc32(name)) mod 2³¹, plus 2³¹
    for root keys of 2³¹ and above, so every root key in 0..2³²-1 gives each analysis its own key
    (mod 2³¹ alone, keys k and k + 2³¹ would share them)."""
    key = int(key)
    return (key * 7919 + zlib.crc32(name.encode())) % 2**31 + (key >> 31 << 31)


def contrast(x_baseline, x_treatment, key: int, *, resamples: int, higher_is_better: bool = True) -> dict:
    """Treatment − baseline on one per-seed measure, all from `jaxeac.stats.compare_measures`."""
    from jaxeac.stats import compare_measures

    r = compare_measures(np.asarray(x_baseline, float), np.asarray(x_treatment, float), key,
                         resamples=resamples, higher_is_better={"value": higher_is_better})["value"]
    keep = ("n_baseline", "n_treatment", "mean_baseline", "mean_treatment", "sd_baseline", "sd_treatment",
            "diff", "diff_ci95", "hedges_g", "hedges_g_ci95", "a12", "a12_ci95", "p_welch", "p_permutation",
            "seeds_for_80pct_power")
    return {k: r[k] for k in keep}


def mean_ci(x) -> dict:
    """Mean with its Student-t 95 % CI (`jaxeac.experiments.common.mean_ci95`) and the seeds' 5–95 % range."""
    x = np.asarray(x, float)
    mean, sd, lo, hi = mean_ci95(x)
    q05, q95 = np.percentile(x, [5, 95])
    return {"n": int(x.size), "mean": mean, "sd": sd, "ci95": [lo, hi], "q05": float(q05), "q95": float(q95)}


def paper_position(x, value: float) -> dict:
    """Where the paper's single run lies among our seeds: mid-rank percentile and 5–95 % check."""
    x = np.asarray(x, float)
    q05, q95 = np.percentile(x, [5, 95])
    return {
        "value": value,
        "percentile": float(100 * ((x < value).mean() + 0.5 * (x == value).mean())),
        "share_at_least": float((x >= value).mean()),
        "within_5_95": bool(q05 <= value <= q95),
        "q05": float(q05), "q95": float(q95),
    }


def greedy_reach(grid_map, policies: np.ndarray, max_steps: int) -> np.ndarray:
    """Fig. 2 as a number: per seed, the share of start cells (G3) whose greedy path reaches the goal.

    policies: int [N, S] final greedy actions (G7). Paths follow G2/G4 moves for at
    most `max_steps` moves (the chances of a trial, G5), vectorised over seeds and cells.
    """
    from jaxeac.envs.grid import transition_tables

    nxt = transition_tables(grid_map)[0].astype(np.int64)  # G4
    nxt[grid_map.goal_index] = grid_map.goal_index  # the goal is terminal
    starts = grid_map.start_cells
    policies = np.asarray(policies, np.int64)
    cur = np.broadcast_to(starts, (policies.shape[0], starts.size)).copy()
    rows = np.arange(policies.shape[0])[:, None]
    for _ in range(max_steps):
        cur = nxt[cur, policies[rows, cur]]
    return (cur == grid_map.goal_index).mean(axis=1)



def angle_measures(theta: np.ndarray, late_from: int) -> dict:
    """Per-seed late-window angle measures from [N, T, 2] angles (NaN = not thrown)."""
    late = theta[:, late_from - 1:, :]
    with warnings.catch_warnings():  # a seed with a strike in every late trial has no chance-2 angle
        warnings.simplefilter("ignore", RuntimeWarning)
        th1 = np.nanmean(late[:, :, 0], axis=1)
        th2 = np.nanmean(late[:, :, 1], axis=1)
        sd1 = np.nanstd(late[:, :, 0], axis=1)
    return {"theta1": th1, "theta2": th2, "sd_theta1": sd1}


def one_sample(x: np.ndarray, *, negative: bool) -> dict:
    """Mean angle with its t CI and one-sample t p against 0; share of seeds on the claimed side (Wilson)."""
    from jaxeac.stats import wilson_ci

    x = x[np.isfinite(x)]
    out = mean_ci(x) if x.size >= 2 else {"n": int(x.size), "mean": math.nan, "ci95": [math.nan, math.nan]}
    side = (x < 0) if negative else (x > 0)
    k = int(side.sum())
    out["share_claimed_side"] = k / x.size if x.size else math.nan
    out["share_claimed_side_ci95"] = list(wilson_ci(k, x.size)) if x.size else [math.nan, math.nan]
    out["p_ttest_vs_0"] = float(sps.ttest_1samp(x, 0.0).pvalue) if x.size >= 2 and x.std() > 0 else math.nan
    return out

