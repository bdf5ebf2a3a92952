"""Figures of the grid experiment: Fig. 3-style learning curves and Fig. 2-style policies.

Matplotlib with the Agg backend; every function writes PNGs into a folder and
returns their file names.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from scipy import stats as sps  # noqa: E402

from envs.grid import ACTION_DELTAS, GridMap  # noqa: E402

COLORS = {"ac": "tab:blue", "eac": "tab:red"}
LABELS = {"ac": "AC", "eac": "EAC"}


def cumulative_success_figure(success: dict[str, np.ndarray], path: Path, *, paper: dict | None = None):
    """Fig. 3: mean cumulative successes over trials per algorithm, with a pointwise 95 % CI band."""
    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    for algo, s in success.items():
        cum = np.cumsum(s, axis=1, dtype=np.float64)
        n, t = cum.shape
        mean = cum.mean(axis=0)
        trials = np.arange(1, t + 1)
        color = COLORS.get(algo)
        ax.plot(trials, mean, color=color, label=f"{LABELS.get(algo, algo)} (mean of {n} seeds)")
        if n > 1:
            half = sps.t.ppf(0.975, n - 1) * cum.std(axis=0, ddof=1) / np.sqrt(n)
            ax.fill_between(trials, mean - half, mean + half, color=color, alpha=0.25, lw=0)
            lo, hi = np.percentile(cum, [5, 95], axis=0)
            ax.plot(trials, lo, color=color, lw=0.6, ls=":")
            ax.plot(trials, hi, color=color, lw=0.6, ls=":")
        if paper and algo in paper and t == 200:
            ax.plot([t], [paper[algo]], marker="*", ms=12, color=color, ls="none",
                    label=f"paper's single {LABELS.get(algo, algo)} run: {paper[algo]}")
    ax.set_xlabel("trial")
    ax.set_ylabel("successful trials so far")
    ax.set_title("Cumulative successes (band: 95% CI of the mean; dotted: 5-95% of seeds)", fontsize=9)
    ax.legend(fontsize=8, loc="upper left")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def greedy_path(grid: GridMap, policy: np.ndarray, start: int, max_steps: int) -> list[int]:
    """Follow `policy` deterministically from `start` until the goal, a wall loop or `max_steps`."""
    path, s, seen = [start], start, {start}
    for _ in range(max_steps):
        y, x = divmod(s, grid.width)
        dx, dy = ACTION_DELTAS[int(policy[s])]
        nx, ny = x + dx, y + dy
        if 0 <= nx < grid.width and 0 <= ny < grid.height and not grid.obstacles[ny, nx]:
            s = ny * grid.width + nx
        path.append(s)
        if s == grid.goal_index or s in seen:
            break
        seen.add(s)
    return path


def policy_axes(ax, grid: GridMap, policy: np.ndarray, start: int, max_steps: int, title: str):
    """Fig. 2: one arrow per free cell (the final greedy action) and one greedy path."""
    h, w = grid.height, grid.width
    ax.imshow(grid.obstacles, cmap="Greys", vmin=0, vmax=1.5, origin="upper")
    gx, gy = grid.goal
    ax.add_patch(plt.Rectangle((gx - 0.5, gy - 0.5), 1, 1, color="tab:red", alpha=0.8))
    ys, xs = np.divmod(np.arange(h * w), w)
    free = ~grid.obstacles.reshape(-1)
    free[grid.goal_index] = False
    d = np.array(ACTION_DELTAS)[policy.astype(int)]
    # y grows downwards (row index), as in the map, so dy is drawn as is.
    ax.quiver(xs[free], ys[free], d[free, 0], d[free, 1], angles="xy", scale_units="xy",
              scale=2.4, width=0.006, color="0.35", pivot="middle")
    path = greedy_path(grid, policy, start, max_steps)
    py, px = np.divmod(np.array(path), w)
    ax.plot(px, py, color="tab:green", lw=2.2, marker="o", ms=3)
    ax.plot(px[0], py[0], marker="s", ms=8, color="tab:green")
    reached = path[-1] == grid.goal_index
    ax.set_title(f"{title}\ngreedy path {'reaches' if reached else 'misses'} the goal "
                 f"({len(path) - 1} moves)", fontsize=9)
    ax.set_xticks(range(w))
    ax.set_yticks(range(h))
    ax.tick_params(labelsize=6)
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)


def policy_figure(grid: GridMap, policies: dict[str, np.ndarray], path: Path, *, seed: int, max_steps: int):
    """Fig. 2: AC beside EAC, the final policy of one seed and the greedy path from one start."""
    start = int(grid.start_cells[0])
    fig, axes = plt.subplots(1, len(policies), figsize=(4.2 * len(policies), 4.4), squeeze=False)
    for ax, (algo, policy) in zip(axes[0], policies.items(), strict=True):
        policy_axes(ax, grid, policy, start, max_steps, f"{LABELS.get(algo, algo)}, seed {seed}")
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def grid_figures(run, folder: Path, *, seed: int = 0) -> list[str]:
    """Both grid figures of a `GridRun` into `folder`; returns the file names."""
    from jaxeac.presets import make

    paper = make(run.settings.preset).paper_successes if run.settings.map_file is None else None
    cumulative_success_figure({a: r.success for a, r in run.results.items()},
                              folder / "fig3_cumulative_successes.png", paper=paper)
    policy_figure(run.grid_map, {a: r.policy[seed] for a, r in run.results.items()},
                  folder / "fig2_policies.png", seed=seed, max_steps=run.settings.chances)
    return ["fig3_cumulative_successes.png", "fig2_policies.png"]


def angle_figure(angles: dict[str, np.ndarray], path: Path, *, seed: int = 0):
    """Fig. 5: chance-1 and chance-2 shoulder angles per trial: mean, 5–95 % band over seeds, one seed."""
    fig, axes = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
    for c, ax in enumerate(axes):
        for algo, theta in angles.items():
            a = theta[:, :, c]
            t = np.arange(1, a.shape[1] + 1)
            color = COLORS.get(algo)
            ax.plot(t, np.nanmean(a, axis=0), color=color, lw=2, label=f"{LABELS.get(algo, algo)} mean")
            lo, hi = np.nanpercentile(a, [5, 95], axis=0)
            ax.fill_between(t, lo, hi, color=color, alpha=0.15, lw=0)
            ax.plot(t, a[seed], color=color, lw=1, ls="--", marker="o", ms=3,
                    label=f"{LABELS.get(algo, algo)} seed {seed}")
        ax.axhline(0, color="0.5", lw=0.8)
        ax.set_title(f"chance {c + 1} (band: 5–95% of seeds)", fontsize=9)
        ax.set_xlabel("trial")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("shoulder angle θ (rad); < 0 targets the right pins")
    axes[1].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


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
    im = ax.imshow(grid, cmap="RdBu_r", origin="lower", aspect="auto",
                   vmin=-np.nanmax(np.abs(grid)), vmax=np.nanmax(np.abs(grid)))
    for (j, i), v in np.ndenumerate(grid):
        ax.text(i, j, f"{v:+.1f}", ha="center", va="center", fontsize=8)
    ax.set_xticks(range(len(xs)), [str(x) for x in xs])
    ax.set_yticks(range(len(ys)), [str(y) for y in ys])
    ax.set_xlabel(key_x)
    ax.set_ylabel(key_y)
    others = {k for row in rows for k in row} & {"alpha", "beta", "gamma", "temperature", "trials",
                                                   "chances", "preset", "map_file"} - {key_x, key_y}
    note = f" (mean over {', '.join(sorted(others))})" if others else ""
    ax.set_title(f"EAC − AC mean successes{note}", fontsize=9)
    fig.colorbar(im, ax=ax, shrink=0.8)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)
