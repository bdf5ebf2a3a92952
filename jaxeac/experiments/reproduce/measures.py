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

from jaxeac import paper
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


def rate_change(success: np.ndarray, at: int, width: int) -> dict[str, np.ndarray]:
    """Fig. 3's slope before and after trial `at` (1-based), per seed (claim GRID-4).

    The slope of a cumulative success curve across a window of trials is its rise over the
    window's width: the success rate (successes per trial) in the window. From success [N, T],
    the rates over three windows of `width` trials, `earlier` (trials at − 2·width + 1 … at − width),
    `before` (… at) and `after` (at + 1 … at + width); the `rise` at trial `at`, after − before; and
    the `bend`, that rise minus the rise one window earlier (before − earlier): above 0 when the
    curve steepens more at `at` than it did before.
    """
    s = np.asarray(success, np.float64)
    if width < 1 or at < 2 * width or at + width > s.shape[1]:
        raise ValueError(f"windows of {width} trials around trial {at} do not fit in {s.shape[1]} trials")
    earlier, before, after = (s[:, a:a + width].mean(axis=1) for a in (at - 2 * width, at - width, at))
    return {"earlier": earlier, "before": before, "after": after, "rise": after - before,
            "bend": (after - before) - (before - earlier)}


def path_ratios(success: np.ndarray, steps: np.ndarray, starts: np.ndarray,
                shortest: np.ndarray) -> np.ndarray:
    """Fig. 2's "more optimized" paths as numbers (claim GRID-5): float [N, T], the chances a
    successful trial used over the fewest moves from its start cell to the goal (`shortest`, per
    cell, from `jaxeac.envs.grid.shortest_steps`); 1 = a shortest path, NaN where the trial failed."""
    success = np.asarray(success, bool)
    fewest = np.asarray(shortest)[np.asarray(starts)]
    if (fewest[success] < 1).any():
        raise ValueError("a successful trial starts where the goal is out of reach; wrong start cells?")
    return np.where(success, np.asarray(steps, np.float64) / fewest, np.nan)


def path_window(ratios: np.ndarray, window: slice) -> dict[str, np.ndarray]:
    """Per seed, over the trials of `window` of `path_ratios` [N, T]: the mean `ratio` of its
    successful trials and the share of them on a shortest path (`optimal`, ratio 1); NaN for a
    seed with no successful trial there."""
    r = np.asarray(ratios, np.float64)[:, window]
    done = np.isfinite(r).sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(np.isfinite(r), r, 0.0).sum(axis=1) / done
        optimal = (r == 1.0).sum(axis=1) / done
    return {"ratio": ratio, "optimal": optimal}


def trial_means(x: np.ndarray) -> dict[str, list[float]]:
    """Per trial (column) of [N, T], the mean over seeds of its finite entries with a pointwise Student-t
    95 % CI (`jaxeac.experiments.common.mean_ci95`; NaN where fewer than two seeds count) and n."""
    x = np.asarray(x, np.float64)
    rows = [mean_ci95(col[np.isfinite(col)]) if np.isfinite(col).any() else (math.nan,) * 4 for col in x.T]
    mean, _, lo, hi = (list(v) for v in zip(*rows, strict=True))
    return {"mean": mean, "lo": lo, "hi": hi, "n": np.isfinite(x).sum(axis=0).tolist()}


def chance_split(knocked: np.ndarray) -> dict[str, np.ndarray]:
    """Table I's split of pins between the chances, per seed (claim BOWL-4): from pins per chance
    [N, T, 2] (B5; a strike's trial has no chance 2, its pins count for chance 1), the pins of
    chance 1 and of chance 2 over all T trials and the share of the seed's pins knocked with chance
    2 (NaN for a seed that knocked none)."""
    k = np.asarray(knocked, np.int64)
    c1, c2 = k[..., 0].sum(axis=1), k[..., 1].sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        share = c2 / (c1 + c2)
    return {"chance1": c1, "chance2": c2, "share_chance2": share}


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
    """Mean (an angle, a change of rate) with its t CI and one-sample t p against 0; share of seeds on
    the claimed side, below 0 if `negative` else above (Wilson). NaN entries are left out."""
    from jaxeac.stats import wilson_ci

    x = x[np.isfinite(x)]
    out = mean_ci(x) if x.size >= 2 else {"n": int(x.size), "mean": math.nan, "ci95": [math.nan, math.nan]}
    side = (x < 0) if negative else (x > 0)
    k = int(side.sum())
    out["share_claimed_side"] = k / x.size if x.size else math.nan
    out["share_claimed_side_ci95"] = list(wilson_ci(k, x.size)) if x.size else [math.nan, math.nan]
    out["p_ttest_vs_0"] = float(sps.ttest_1samp(x, 0.0).pvalue) if x.size >= 2 and x.std() > 0 else math.nan
    return out


def finite(x: np.ndarray) -> np.ndarray:
    """The entries of a per-seed measure that exist (NaN: the seed has none, e.g. no success)."""
    x = np.asarray(x, float)
    return x[np.isfinite(x)]


def speedup_summary(success: dict, width: int) -> dict:
    """GRID-4: each method's success rate (the slope of Fig. 3's curve) in the last `width` trials (after
    trial ~180 when T = 200) and in the two windows before, per seed (`rate_change`); the rise and the
    bend tested against 0 over seeds (`one_sample`)."""
    trials = next(iter(success.values())).shape[1]
    width = min(width, trials // 3)
    at = trials - width
    out = {"at": at, "width": width, "windows": [[at - 2 * width + 1, at - width], [at - width + 1, at],
                                                  [at + 1, at + width]]}
    for a, s in success.items():
        m = rate_change(s, at, width)
        out[a] = {"rates": {w: mean_ci(m[w]) for w in ("earlier", "before", "after")},
                  "rise": one_sample(m["rise"], negative=False),
                  "bend": one_sample(m["bend"], negative=False)}
    return out


def path_summary(ratios: dict, width: int, key: int, resamples: int) -> dict:
    """GRID-5 from each method's `path_ratios` [N, T]: per seed over the last `width` trials
    (`path_window`), EAC − AC on the mean ratio (lower is better) and on the share of shortest paths;
    each method over all trials; and per-trial means (`curves`, for the figure)."""
    trials = next(iter(ratios.values())).shape[1]
    width = min(width, trials)
    per_seed, out = {}, {"window": [trials - width + 1, trials], "curves": {}}
    for a, ratio in ratios.items():
        per_seed[a] = path_window(ratio, slice(trials - width, trials))
        optimal = np.where(np.isfinite(ratio), ratio == 1.0, np.nan)
        out["curves"][a] = {"ratio": trial_means(ratio), "optimal": trial_means(optimal), "n": ratio.shape[0]}
        out[a] = {"ratio": mean_ci(finite(per_seed[a]["ratio"])),
                  "optimal": mean_ci(finite(per_seed[a]["optimal"])),
                  "seeds_without_success": int(np.isnan(per_seed[a]["ratio"]).sum()),
                  "all_trials": {"ratio": float(np.nanmean(ratio)), "optimal": float(np.nanmean(optimal)),
                                 "successful_trials": int(np.isfinite(ratio).sum())}}
    for name, higher in (("ratio", False), ("optimal", True)):
        out[f"contrast_{name}"] = contrast(finite(per_seed["ac"][name]), finite(per_seed["eac"][name]),
                                           sub_key(key, name), resamples=resamples, higher_is_better=higher)
    return out


def split_summary(knocked: dict, key: int, resamples: int) -> dict:
    """BOWL-4 from each method's pins per chance [N, T, 2]: per seed the pins of each chance and the
    share knocked with chance 2 (`chance_split`), the paper's single runs (Table I) and where they lie
    among our seeds (`paper_position`), and EAC − AC on the share."""
    split = {a: chance_split(k) for a, k in knocked.items()}
    out = {}
    for a, s in split.items():
        table = chance_split(np.asarray(paper.TABLE_ONE[a])[None])  # the paper's single run
        c1, c2, share = int(table["chance1"][0]), int(table["chance2"][0]), float(table["share_chance2"][0])
        ours = finite(s["share_chance2"])
        out[a] = {"chance1": mean_ci(s["chance1"]), "chance2": mean_ci(s["chance2"]),
                  "share_chance2": mean_ci(ours),
                  "seeds_without_pins": int(s["share_chance2"].size - ours.size),
                  "paper": {"chance1": c1, "chance2": c2, "share_chance2": share},
                  "paper_chance1_position": paper_position(s["chance1"], c1),
                  "paper_chance2_position": paper_position(s["chance2"], c2)}
    out["paper_position"] = {a: paper_position(finite(s["share_chance2"]), out[a]["paper"]["share_chance2"])
                             for a, s in split.items()}
    out["contrast"] = contrast(finite(split["ac"]["share_chance2"]), finite(split["eac"]["share_chance2"]),
                               key, resamples=resamples)
    return out


#: BOWL-5: a chance-2 throw aims at a side when its angle has that side's sign (θ > 0: the thrower's
#: left, +y, B2) and the pins standing after chance 1 lie on it, their mean lateral position at least
#: this far (m) from the lane's centre line; throws at θ = 0 or at a centred rack count for no side.
AIM_SIDE_MIN = 0.05


def toward_standing(standing: np.ndarray, angle: np.ndarray, pin_xy: np.ndarray,
                    first_trial: int) -> np.ndarray:
    """Per seed, from trial `first_trial` (1-based) on: the share of its chance-2 throws that aim
    at the side where the pins standing after chance 1 lie (BOWL-5; `AIM_SIDE_MIN`), NaN for a seed
    without such a throw. standing int [N, T, 2]: masks after each chance (bit i: pin i+1, −1: not
    thrown); angle [N, T, 2] rad (NaN: not thrown); pin_xy [10, 2] of the run's scene."""
    mask = np.asarray(standing)[:, first_trial - 1:, 0].astype(np.int64)
    theta2 = np.asarray(angle, float)[:, first_trial - 1:, 1]
    bits = (mask[..., None] >> np.arange(10)) & 1
    n_up = bits.sum(-1)
    y = np.where(n_up > 0, (bits * np.asarray(pin_xy)[:, 1]).sum(-1) / np.maximum(n_up, 1), 0.0)
    sided = np.isfinite(theta2) & (mask > 0) & (np.abs(y) >= AIM_SIDE_MIN) & (theta2 != 0)
    toward = sided & (np.sign(np.nan_to_num(theta2)) == np.sign(y))
    n = sided.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, toward.sum(axis=1) / np.maximum(n, 1), np.nan)


def aim_summary(standing: dict, angles: dict, pin_xy: np.ndarray, first_trial: int, key: int,
                resamples: int) -> dict:
    """BOWL-5 per method: the share of chance-2 throws aimed at the standing pins' side
    (`toward_standing`), its mean against ½ (one-sample t on share − ½), and EAC − AC."""
    share = {a: toward_standing(standing[a], angles[a], pin_xy, first_trial) for a in ("ac", "eac")}
    out = {a: {**one_sample(share[a] - 0.5, negative=False), "share": mean_ci(finite(share[a])),
               "seeds_without": int(np.isnan(share[a]).sum())} for a in ("ac", "eac")}
    out["contrast"] = contrast(finite(share["ac"]), finite(share["eac"]), key, resamples=resamples)
    out["window"] = [first_trial, int(np.asarray(standing["eac"]).shape[1])]
    out["side_min_m"] = AIM_SIDE_MIN
    return out
