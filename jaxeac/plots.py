"""Figures of the grid experiment: Fig. 3-style learning curves and Fig. 2-style policies, and the
comparison's figures (`comparison_figures`).

Matplotlib with the Agg backend; every function writes PNGs into a folder and
returns their file names.

(Over 400 lines on purpose: every figure of a run folder in one place, drawn in one style
(`jaxeac.style`).)
"""

from __future__ import annotations

import io
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402

from jaxeac import style  # noqa: E402
from jaxeac.envs.grid import ACTION_DELTAS, GridMap, transition_tables  # noqa: E402
from jaxeac.paper import GRID_SUCCESSES, GRID_TRIALS  # noqa: E402

COLORS = style.PALETTE  # one colour per algorithm, every figure (jaxeac/style.py)
LABELS = style.LABELS


def cumulative_success_figure(lines: dict[str, dict], path: Path, *, paper: dict | None = None):
    """Fig. 3: mean cumulative successes over trials per algorithm, with a pointwise 95 % CI band
    and the seeds' 5–95 % spread: `lines[algo]`, `jaxeac.stats.cumulative.cumulative_lines` of its
    per-trial counts (with the spread)."""
    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    spread = False
    for algo, line in lines.items():
        n, mean, half = line["n"], line["mean"], line["half"]
        t = mean.size
        trials = np.arange(1, t + 1)
        color = style.color(algo)
        ax.plot(trials, mean, color=color, lw=1.8, label=f"{style.label(algo)}: mean of {n:,} seeds")
        if half is not None:
            ax.fill_between(trials, mean - half, mean + half, color=color, alpha=0.25, lw=0)
            ax.plot(trials, line["low"], color=color, lw=0.7, ls=":")
            ax.plot(trials, line["high"], color=color, lw=0.7, ls=":")
            spread = True
        if paper and algo in paper and t == GRID_TRIALS:
            ax.plot([t], [paper[algo]], marker="*", ms=12, color=color, mec="black", ls="none",
                    label=f"paper's single {style.label(algo)} run: {paper[algo]}")
    handles, _ = ax.get_legend_handles_labels()
    if spread:  # one key for the marks every algorithm shares, drawn in grey
        handles += [Patch(color=style.NEUTRAL, alpha=0.25, lw=0, label="shaded: 95% CI of the mean"),
                    Line2D([], [], color=style.NEUTRAL, lw=0.7, ls=":", label="dotted: 5% and 95% of seeds")]
    ax.set_xlabel("trial")
    ax.set_ylabel("successful trials so far (cumulative)")
    ax.set_title("Cumulative successes per trial", fontsize=9)
    ax.legend(handles=handles, fontsize=7, loc="upper left")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def greedy_path(grid: GridMap, policy: np.ndarray, start: int, max_steps: int) -> list[int]:
    """Follow `policy` deterministically from `start` until the goal, a wall loop or `max_steps`."""
    next_cell = transition_tables(grid)[0]  # G4
    path, s, seen = [start], start, {start}
    for _ in range(max_steps):
        s = int(next_cell[s, int(policy[s])])
        path.append(s)
        if s == grid.goal_index or s in seen:
            break
        seen.add(s)
    return path


#: Fig. 2 draws an arrow and a tick per cell on maps of at most this many cells a side (the presets:
#: 7-21); on larger maps arrows and ticks would be too small to see and take hours to draw.
POLICY_ARROW_SIDE = 64


def policy_axes(ax, grid: GridMap, policy: np.ndarray, start: int, max_steps: int, title: str,
                color: str = style.NEUTRAL) -> list:
    """Fig. 2: one arrow per free cell (the final greedy action) and one greedy path, drawn in
    `color`; returns the legend handles of its marks (obstacle, goal, start, path, arrows)."""
    h, w = grid.height, grid.width
    ax.imshow(grid.obstacles, cmap="Greys", vmin=0, vmax=1.2, origin="upper")
    gx, gy = grid.goal
    ax.add_patch(plt.Rectangle((gx - 0.5, gy - 0.5), 1, 1, fc=style.GOAL, ec="black", lw=1))
    ys, xs = np.divmod(np.arange(h * w), w)
    free = ~grid.obstacles.reshape(-1)
    free[grid.goal_index] = False
    arrows = max(h, w) <= POLICY_ARROW_SIDE  # larger maps: too small to see, and hours to draw
    if arrows:
        d = np.array(ACTION_DELTAS)[policy.astype(int)]
        # y grows downwards (row index), as in the map, so dy is drawn as is.
        ax.quiver(xs[free], ys[free], d[free, 0], d[free, 1], angles="xy", scale_units="xy",
                  scale=2.4, width=0.006, color="0.55", pivot="middle")
    path = greedy_path(grid, policy, start, max_steps)
    py, px = np.divmod(np.array(path), w)
    ax.plot(px, py, color=color, lw=2.2, marker="o", ms=3)
    ax.plot(px[0], py[0], marker="s", ms=9, mfc="white", mec="black", mew=1.5, ls="none")
    reached = path[-1] == grid.goal_index
    moves = len(path) - 1
    ax.set_title(f"{title}\ngreedy path {'reaches' if reached else 'misses'} the goal "
                 f"({moves} move{'' if moves == 1 else 's'})"
                 + ("" if arrows else f"; {h} x {w} cells: no arrows"), fontsize=9)
    if arrows:  # a tick per cell
        ax.set_xticks(range(w))
        ax.set_yticks(range(h))
    ax.tick_params(labelsize=6)
    ax.set_xlabel("column", fontsize=8)
    ax.set_ylabel("row", fontsize=8)
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    handles = [Patch(fc="0.17", label="obstacle"),
               Patch(fc=style.GOAL, ec="black", lw=1, label="goal"),
               Line2D([], [], marker="s", ms=8, mfc="white", mec="black", mew=1.5, ls="none", label="start"),
               Line2D([], [], color=color, lw=2.2, marker="o", ms=3, label="greedy path from the start")]
    if arrows:
        handles.append(Line2D([], [], color="0.55", marker=r"$\rightarrow$", ms=9, ls="none",
                              label="greedy action in each cell"))
    return handles


def policy_figure(grid: GridMap, policies: dict[str, np.ndarray], path: Path, *, seed: int, max_steps: int):
    """Fig. 2: AC beside EAC, the final policy of one seed and the greedy path from one start."""
    start = int(grid.start_cells[0])
    fig, axes = plt.subplots(1, len(policies), figsize=(4.2 * len(policies), 5.0), squeeze=False)
    handles = []
    for ax, (algo, policy) in zip(axes[0], policies.items(), strict=True):
        marks = policy_axes(ax, grid, policy, start, max_steps, f"{style.label(algo)}, seed {seed}",
                            color=style.color(algo))
        handles += [h for h in marks if h.get_label() not in {g.get_label() for g in handles}
                    and h.get_label() != "greedy path from the start"]
    handles += [Line2D([], [], color=style.color(a), lw=2.2, marker="o", ms=3,
                       label=f"{style.label(a)}'s greedy path from the start") for a in policies]
    fig.legend(handles=handles, loc="lower center", ncol=min(len(handles), 4), fontsize=7, frameon=False)
    fig.tight_layout(rect=(0, 0.1, 1, 1))
    fig.savefig(path, dpi=130)
    plt.close(fig)


def grid_figures(folder: Path, *, lines: dict[str, dict] | None = None, grid_map: GridMap | None = None,
                 policies: dict[str, np.ndarray] | None = None, seed: int = 0, max_steps: int = 0,
                 paper: dict[str, int] | None = None) -> list[str]:
    """A run's grid figures into `folder` (`jaxeac.experiments.grid.curve_inputs` and
    `policy_inputs` give the arguments from its results); returns the file names. `lines`: Fig. 3's
    per algorithm (none: not drawn), with `paper`, the paper's successes per algorithm, marked on
    the curves; `policies`: each algorithm's final policy of seed `seed`, drawn on `grid_map`
    (Fig. 2; none without a map)."""
    names = []
    if lines is not None:
        cumulative_success_figure(lines, folder / "fig3_cumulative_successes.png", paper=paper)
        names.append("fig3_cumulative_successes.png")
    if grid_map is not None:
        policy_figure(grid_map, policies, folder / "fig2_policies.png", seed=seed, max_steps=max_steps)
        names.append("fig2_policies.png")
    return names


def angle_figure(angles: dict[str, np.ndarray], path: Path, *, seed: int = 0):
    """Fig. 5: chance-1 and chance-2 shoulder angles per trial: mean, 5–95 % band over seeds, one seed.

    The seed's angles of the first algorithm are drawn as large open markers and those of the
    next ones as smaller filled markers on top, so a trial where they agree shows both."""
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.4), sharey=True)
    markers = ("o", "D", "s", "^", "v", "P", "X", "*")
    for c, ax in enumerate(axes):
        for k, (algo, theta) in enumerate(angles.items()):
            a = theta[:, :, c]
            t = np.arange(1, a.shape[1] + 1)
            color, name = style.color(algo), style.label(algo)
            lo, hi = np.nanpercentile(a, [5, 95], axis=0)
            ax.fill_between(t, lo, hi, color=color, alpha=0.15, lw=0, label=f"{name}: 5–95% of seeds")
            ax.plot(t, np.nanmean(a, axis=0), color=color, lw=2.2, label=f"{name}: mean over seeds")
            big = k == 0
            ax.plot(t, a[seed], color=color, lw=1.6 if big else 1.0, ls="--" if big else ":",
                    marker=markers[k % len(markers)], ms=9 if big else 4,
                    mfc="none" if big else color, mew=1.5 if big else 1, zorder=3 + k,
                    label=f"{name}: seed {seed}")
        ax.axhline(0, color=style.NEUTRAL, lw=0.8)
        ax.set_title(f"chance {c + 1}", fontsize=9)
        ax.set_xlabel("trial")
        ax.set_ylabel("shoulder angle θ (rad)")
        ax.yaxis.set_tick_params(labelleft=True)
        ax.grid(alpha=0.3)
    fig.suptitle("Shoulder angle of each throw (θ < 0 aims at the right pins)", fontsize=10)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=len(angles), fontsize=7, frameon=False)
    fig.tight_layout(rect=(0, 0.17 if len(angles) > 1 else 0.1, 1, 1))
    fig.savefig(path, dpi=130)
    plt.close(fig)


def _cell_texts(ax, im, grid: np.ndarray, text, fontsize: float):
    """Write text(j, i, v) in each finite cell of an imshow, black or white by the cell's colour."""
    for (j, i), v in np.ndenumerate(grid):
        if np.isfinite(v):
            ax.text(i, j, text(j, i, v), ha="center", va="center", fontsize=fontsize,
                    color=style.text_color(im.cmap(im.norm(v))))


def sweep_heatmap(rows: list[dict], key_x: str, key_y: str, path: Path):
    """EAC − AC mean successes over two swept keys (averaged over any other swept keys)."""
    diffs: dict[tuple, list[float]] = {}
    for row in rows:
        if row["algo"] == "eac" and "eac_minus_ac" in row:
            diffs.setdefault((row[key_x], row[key_y]), []).append(row["eac_minus_ac"])
    xs = sorted({k[0] for k in diffs})
    ys = sorted({k[1] for k in diffs})
    grid = np.array([[np.mean(diffs.get((x, y), [np.nan])) for x in xs] for y in ys])
    fig, ax = plt.subplots(figsize=(1.2 * len(xs) + 3, 0.8 * len(ys) + 2.2))
    im = ax.imshow(grid, origin="lower", aspect="auto", **style.scale(grid, difference=True))
    _cell_texts(ax, im, grid, lambda j, i, v: f"{v:+.1f}", 8)
    ax.set_xticks(range(len(xs)), [str(x) for x in xs])
    ax.set_yticks(range(len(ys)), [str(y) for y in ys])
    ax.set_xlabel(key_x)
    ax.set_ylabel(key_y)
    others = {k for row in rows for k in row} & {"alpha", "beta", "gamma", "temperature", "trials",
                                                   "chances", "preset", "map_file"} - {key_x, key_y}
    note = f" (mean over {', '.join(sorted(others))})" if others else ""
    ax.set_title(f"EAC − AC mean successes per seed{note}", fontsize=9)
    fig.colorbar(im, ax=ax, shrink=0.8, label="EAC − AC mean successes")
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def sweep_lines(rows: list[dict], key: str, path: Path):
    """Mean successes per algorithm against one swept key, with each mean's 95 % CI as error bars
    (averaged over any other swept keys). rows: results.csv's rows (mean_successes, ci95_lo/hi)."""
    algos = list(dict.fromkeys(row["algo"] for row in rows))
    xs = sorted({row[key] for row in rows}, key=lambda v: (isinstance(v, str), v))
    numeric = all(isinstance(x, int | float) for x in xs)
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for algo in algos:
        pts = [[r for r in rows if r["algo"] == algo and r[key] == x] for x in xs]
        mean = np.array([np.mean([r["mean_successes"] for r in p]) if p else np.nan for p in pts])
        lo = np.array([np.mean([r["ci95_lo"] for r in p]) if p else np.nan for p in pts])
        hi = np.array([np.mean([r["ci95_hi"] for r in p]) if p else np.nan for p in pts])
        pos = np.asarray(xs, float) if numeric else np.arange(len(xs))
        ax.errorbar(pos, mean, yerr=[mean - lo, hi - mean], color=style.color(algo), marker="o", ms=5,
                    capsize=3, lw=1.6, label=style.label(algo))
    if not numeric:
        ax.set_xticks(range(len(xs)), [str(x) for x in xs])
    ax.set_xlabel(key)
    ax.set_ylabel("mean successes per seed (bars: 95% CI)")
    others = {k for row in rows for k in row} & {"alpha", "beta", "gamma", "temperature", "epsilon", "trials",
                                                   "chances", "preset", "map_file", "slip"} - {key}
    note = f"\n(mean over {', '.join(sorted(others))})" if others else ""
    ax.set_title(f"Mean successes against {key}{note}", fontsize=9)
    ax.legend(fontsize=8, title="algorithm", title_fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def cumulative_band_figure(curves: dict[str, dict], path: Path, *, paper: dict | None = None,
                           band_label: str = "simultaneous 95% band"):
    """Fig. 3 with a band that holds over all trials at once.

    curves[algo] = {"mean": [T], "band": ([T], [T]), "spread": ([T], [T]), "n": seeds}: the mean
    cumulative successes, its simultaneous band (computed by the caller, e.g. a sup-t bootstrap
    band from `jaxeac.stats.curve_bands`) and the seeds' 5–95 % spread. `paper` marks the paper's
    single-run end points at the last trial.
    """
    fig, ax = plt.subplots(figsize=(6.8, 4.6))
    for algo, c in curves.items():
        mean = np.asarray(c["mean"], float)
        t = mean.size
        trials = np.arange(1, t + 1)
        color = style.color(algo)
        name = style.label(algo)
        ax.plot(trials, mean, color=color, lw=2, label=f"{name}: mean of {c['n']:,} seeds")
        lo, hi = (np.asarray(b, float) for b in c["band"])
        half = float(np.nanmax(hi - lo)) / 2
        ax.fill_between(trials, lo, hi, color=color, alpha=0.35, lw=0,
                        label=f"{name}: {band_label} (half-width ≤ {half:.2g})")
        slo, shi = (np.asarray(b, float) for b in c["spread"])
        ax.fill_between(trials, slo, shi, color=color, alpha=0.08, lw=0)
        ax.plot(trials, slo, color=color, lw=0.7, ls=":")
        ax.plot(trials, shi, color=color, lw=0.7, ls=":", label=f"{name}: 5% and 95% of seeds (dotted)")
        if paper and algo in paper:
            ax.plot([t], [paper[algo]], marker="*", ms=14, color=color, mec="black", ls="none",
                    label=f"paper's single {name} run: {paper[algo]}")
    ax.set_xlabel("trial")
    ax.set_ylabel("successful trials so far (cumulative)")
    ax.set_title("Cumulative successes: mean with a band over all trials at once,\n"
                 "spread of seeds (dotted) and the paper's single runs (stars)", fontsize=9)
    ax.legend(fontsize=7, loc="upper left")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def calibration_landscape(points: list[dict], path: Path, *, facet: tuple[str, str] = ("preset", "chances"),
                          axes: tuple[str, str] = ("alpha", "beta"),
                          target: float = float(GRID_SUCCESSES["ac"]),
                          tolerance: float = 5.0, unit: str = "successes"):
    """EAC − AC mean `unit` (successes; bowling: pins) over a sweep: one small heatmap per (facet
    values), axes[0] × axes[1].

    points: one dict per sweep point with the swept keys, `ac` and `eac` mean successes and
    `diff`; values appear in the order of `points` (a sweep's order). Each cell shows EAC − AC
    and AC's mean; cells with |AC − target| ≤ tolerance are boxed.
    """
    rows_v, cols_v, xs, ys = (list(dict.fromkeys(p.get(k) for p in points)) for k in (*facet, *axes))
    colors = style.scale([p["diff"] for p in points], difference=True)  # one scale for every panel
    fig, grid = plt.subplots(len(rows_v), len(cols_v), squeeze=False,
                             figsize=(1.0 * len(xs) * len(cols_v) + 2.4, 0.8 * len(ys) * len(rows_v) + 1.6))
    im = None
    for r, rv in enumerate(rows_v):
        for c, cv in enumerate(cols_v):
            ax = grid[r, c]
            cells = {(p.get(axes[0]), p.get(axes[1])): p for p in points
                     if p.get(facet[0]) == rv and p.get(facet[1]) == cv}
            z = np.array([[cells[(x, y)]["diff"] if (x, y) in cells else np.nan for x in xs] for y in ys])
            im = ax.imshow(z, origin="lower", aspect="auto", **colors)
            ac = np.array([[cells[(x, y)]["ac"] if (x, y) in cells else np.nan for x in xs] for y in ys])
            _cell_texts(ax, im, z, lambda j, i, v, ac=ac: f"{v:+.0f}\nAC {ac[j, i]:.0f}", 6)
            for (j, i), _ in np.ndenumerate(z):
                p = cells.get((xs[i], ys[j]))
                if p is None:
                    continue
                if abs(p["ac"] - target) <= tolerance:
                    ax.add_patch(plt.Rectangle((i - 0.5, j - 0.5), 1, 1, fill=False, ec=style.VERMILLION
                                               if colors["cmap"] == style.SEQUENTIAL else "black", lw=2.2))
            ax.set_xticks(range(len(xs)), [str(x) for x in xs], fontsize=7)
            ax.set_yticks(range(len(ys)), [str(y) for y in ys], fontsize=7)
            ax.set_title(", ".join(f"{k}={v}" for k, v in zip(facet, (rv, cv), strict=True) if v is not None)
                         or "all points", fontsize=7)
            if r == len(rows_v) - 1:
                ax.set_xlabel(axes[0], fontsize=8)
            if c == 0:
                ax.set_ylabel(axes[1], fontsize=8)
    fig.suptitle(f"EAC − AC mean {unit} (cell text: difference, AC mean)\n"
                 f"boxed: AC within ±{tolerance:g} of the paper's {target:g}", fontsize=8)
    fig.tight_layout(rect=(0, 0, 0.9, 0.93))
    if im is not None:
        fig.colorbar(im, ax=grid.ravel().tolist(), shrink=0.6, label=f"EAC − AC mean {unit}")
    fig.savefig(path, dpi=120)
    plt.close(fig)


def path_ratio_figure(curves: dict[str, dict], path: Path, *, window: tuple[int, int] | None = None):
    """Fig. 2's "more optimized" paths over trials: per algorithm, the mean path ratio of the trials
    that succeeded (chances used over the shortest path from the trial's start; 1 = shortest) and
    the share of them on a shortest path, each with a pointwise 95 % CI.

    curves[algo] = {"ratio": {"mean", "lo", "hi"}, "optimal": {...}, "n": seeds}, one value per
    trial (`jaxeac.experiments.reproduce.measures.trial_means`); `window` (first, last trial,
    1-based) is shaded: the trials a comparison uses.
    """
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    panels = (("ratio", "steps / shortest path (successful trials)"),
              ("optimal", "share of successful trials on a shortest path"))
    for ax, (name, ylabel) in zip(axes, panels, strict=True):
        for algo, c in curves.items():
            mean, lo, hi = (np.asarray(c[name][k], float) for k in ("mean", "lo", "hi"))
            trials = np.arange(1, mean.size + 1)
            color = style.color(algo)
            ax.plot(trials, mean, color=color, lw=1.5,
                    label=f"{style.label(algo)}: mean of {c['n']:,} seeds")
            ax.fill_between(trials, lo, hi, color=color, alpha=0.25, lw=0,
                            label=f"{style.label(algo)}: pointwise 95% CI")
        if window is not None:
            ax.axvspan(window[0] - 0.5, window[1] + 0.5, color=style.NEUTRAL, alpha=0.12, lw=0,
                       label=f"trials {window[0]}-{window[1]} (compared)")
        ax.set_xlabel("trial")
        ax.set_ylabel(ylabel, fontsize=9)
        ax.grid(alpha=0.3)
    top = max((np.nanmax(np.asarray(c["ratio"]["mean"], float)) for c in curves.values()), default=2.0)
    axes[0].set_ylim(0.9, 1.1 * top + 0.1)  # ratios are ≥ 1; bands of trials few seeds succeeded in are cut
    axes[1].set_ylim(0, 1)
    axes[0].axhline(1, color=style.NEUTRAL, lw=0.8)
    axes[0].set_title("path length relative to the shortest (1 = shortest; band: pointwise 95% CI)",
                      fontsize=8)
    axes[1].set_title("shortest paths among successful trials (band: pointwise 95% CI)", fontsize=8)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=3, fontsize=7, frameon=False)
    fig.tight_layout(rect=(0, 0.14, 1, 1))
    fig.savefig(path, dpi=130)
    plt.close(fig)


def forest_figure(rows: list[dict], path: Path, *, title: str, xlabel: str):
    """Differences from AC with 95 % CIs, one row per comparison: rows = [{"label", "diff", "ci": (lo, hi)}],
    each with an optional "algo" (default "eac"): the algorithm compared with AC, whose colour its
    point takes."""
    fig, ax = plt.subplots(figsize=(8.4, 0.42 * len(rows) + 1.8))
    y = np.arange(len(rows))[::-1]
    for yi, row in zip(y, rows, strict=True):
        lo, hi = row["ci"]
        ax.plot([lo, hi], [yi, yi], color=style.NEUTRAL, lw=2)
        ax.plot([row["diff"]], [yi], marker="o", color=style.color(row.get("algo", "eac")), ms=6, ls="none")
    ax.axvline(0, color="black", lw=0.8, ls="--")
    ax.set_yticks(y, [r["label"] for r in rows], fontsize=8)
    ax.set_xlabel(xlabel, fontsize=9)
    ax.set_ylabel("comparison", fontsize=9)
    ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3, axis="x")
    algos = dict.fromkeys(row.get("algo", "eac") for row in rows)
    ax.legend(handles=[*(Line2D([], [], marker="o", color=style.color(a), ls="none",
                                label=f"{style.label(a)} − AC") for a in algos),
                       Line2D([], [], color=style.NEUTRAL, lw=2, label="95% CI"),
                       Line2D([], [], color="black", lw=0.8, ls="--", label="no difference")],
              fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1))
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def comparison_figures(stats: dict, data: dict, out: Path, files: dict[str, str], *,
                       only: tuple[str, ...] | None = None) -> None:
    """A run folder's comparison (`jaxeac.stats.run`, SPEC §6), drawn from its statistics: learning
    curves with simultaneous bands, per-seed ECDFs and the probability of improvement, saved in
    `out` under `files` (``curves``, ``distributions``, ``improvement``: the file names stats.json
    records); `only`: those of them to draw (None: all).

    data: {"measures": {name: {"baseline" | "treatment": (distinct values, their counts)}}}."""
    for name in _COMPARISON if only is None else only:
        _COMPARISON[name](stats, data, out / files[name])


def comparison_png(name: str, stats: dict, data: dict) -> bytes:
    """One figure of `comparison_figures`, as the bytes of its PNG file. The distributions need
    of `stats` only ``baseline`` and ``treatment``: they can be drawn before the statistics."""
    target = io.BytesIO()
    _COMPARISON[name](stats, data, target)
    return target.getvalue()


def _sides(stats: dict) -> tuple[str, str, dict, dict]:
    """The baseline, the treatment, and their colours and labels (the same in every figure)."""
    b, t = stats["baseline"], stats["treatment"]
    return b, t, {b: style.color(b), t: style.color(t)}, {b: style.label(b), t: style.label(t)}


def _curves_figure(stats: dict, data: dict, target) -> None:
    """Per-trial means of both methods with simultaneous bands, and their difference."""
    b, t, colors, shown = _sides(stats)
    cur = stats.get("curves")
    if cur:
        x = np.arange(1, cur["trials"] + 1)
        fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(7, 6), sharex=True, height_ratios=(2, 1))
        for side, name in (("baseline", b), ("treatment", t)):
            m = np.asarray(cur[f"mean_{side}"])
            lo, hi = (np.asarray(v) for v in cur[f"band_{side}"])
            n = stats["primary"][f"n_{side}"]
            ax1.plot(x, m, color=colors[name], label=f"{shown[name]}: mean of {n:,} seeds")
            ax1.fill_between(x, lo, hi, color=colors[name], alpha=0.25, lw=0, label=f"{shown[name]}: band")
        ax1.set_ylabel("success rate" if cur["kind"] == "success_rate" else "mean pins per trial")
        ax1.set_title(
            f"Per-trial means with {100 * (1 - stats['settings']['alpha']):.0f} % simultaneous bands"
        )
        ax1.legend(loc="best", fontsize=8)
        d = np.asarray(cur["diff"])
        lo, hi = (np.asarray(v) for v in cur["band_diff"])
        ax2.plot(x, d, color=style.NEUTRAL, lw=1, label=f"{shown[t]} − {shown[b]}")
        ax2.fill_between(x, lo, hi, color=style.NEUTRAL, alpha=0.3, lw=0, label="band of the difference")
        ax2.axhline(0, color="k", lw=0.5)
        sig = np.asarray(cur["significant_trials"], int)
        if sig.size:
            ax2.plot(
                sig,
                np.full(sig.size, ax2.get_ylim()[0]),
                "|",
                color="black",
                ms=8,
                label="trials that differ (max-T, FWER)",
            )
        ax2.legend(loc="best", fontsize=7)
        ax2.set_ylabel(f"{shown[t]} − {shown[b]}")
        ax2.set_xlabel("trial")
        fig.subplots_adjust(left=0.12, right=0.97, top=0.94, bottom=0.09, hspace=0.08)
        fig.savefig(target, dpi=80, format="png")
        plt.close(fig)


def _distributions_figure(stats: dict, data: dict, target) -> None:
    """Per-seed ECDFs of every measure, from their distinct values and counts."""
    b, t, colors, shown = _sides(stats)
    names = list(data["measures"])
    fig, axes = plt.subplots(1, len(names), figsize=(3.2 * len(names), 3))
    for ax, name in zip(np.atleast_1d(axes), names, strict=True):
        for side, algo in (("baseline", b), ("treatment", t)):
            v, cnt = data["measures"][name][side]  # the ECDF at the distinct values, with their counts
            ax.step(v, np.cumsum(cnt) / cnt.sum(), where="post", color=colors[algo], label=shown[algo])
        ax.set_title(name, fontsize=9)
        ax.set_xlabel(f"x: {name} per seed", fontsize=8)
        ax.set_ylabel("share of seeds ≤ x", fontsize=8)
    np.atleast_1d(axes)[0].legend(fontsize=8)
    fig.suptitle("Per-seed distributions (ECDF)", fontsize=10)
    fig.subplots_adjust(left=0.06, right=0.98, top=0.82, bottom=0.2, wspace=0.3)
    fig.savefig(target, dpi=80, format="png")
    plt.close(fig)


def _improvement_figure(stats: dict, data: dict, target) -> None:
    """The probability of improvement of every measure with its interval."""
    b, t, colors, shown = _sides(stats)
    res = [stats["primary"], *stats["secondary"].values()]
    fig, ax = plt.subplots(figsize=(6, 0.6 * len(res) + 1.2))
    y = np.arange(len(res))[::-1]
    est = np.array([r["prob_improvement"] for r in res])
    lo = np.array([r["prob_improvement_ci"][0] for r in res])
    hi = np.array([r["prob_improvement_ci"][1] for r in res])
    ax.errorbar(est, y, xerr=[est - lo, hi - est], fmt="o", color=colors[t], capsize=3,
                label=f"P({shown[t]} better), with its CI")
    ax.axvline(0.5, color="k", lw=0.5, ls="--", label="0.5: neither better")
    ax.legend(fontsize=7, loc="lower right")
    ax.set_ylabel("measure", fontsize=8)
    ax.set_yticks(y, [r["measure"] for r in res])
    ax.set_xlim(-0.03, 1.03)  # estimates of 0 or 1 stay visible
    ax.set_xlabel(f"P({shown[t]} better than {shown[b]}) with {100 * stats['level']:.6g} % CI")
    fig.subplots_adjust(left=0.3, right=0.96, top=0.95, bottom=0.25)
    fig.savefig(target, dpi=80, format="png")
    plt.close(fig)


#: The comparison's figures by their keys in stats.json's file names, in the order they are drawn.
_COMPARISON = {"curves": _curves_figure, "distributions": _distributions_figure,
               "improvement": _improvement_figure}
