"""The comparison's figures (SPEC §6): learning curves with simultaneous bands, per-seed
ECDFs and the probability of improvement, drawn from a run folder's statistics."""

from __future__ import annotations

from pathlib import Path

import numpy as np

FIGURES = {
    "curves": "compare_curves.png",
    "distributions": "compare_distributions.png",
    "improvement": "compare_improvement.png",
}


def write_figures(stats: dict, data: dict, out: Path) -> None:
    """Learning curves with simultaneous bands, per-seed ECDFs and probability of improvement.

    data: {"measures": {name: {"baseline" | "treatment": (distinct values, their counts)}}}."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jaxeac import style

    b, t = stats["baseline"], stats["treatment"]
    colors = {b: style.color(b), t: style.color(t)}  # each algorithm's colour in every figure
    shown = {b: style.label(b), t: style.label(t)}
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
        fig.savefig(out / FIGURES["curves"], dpi=80)
        plt.close(fig)
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
    fig.savefig(out / FIGURES["distributions"], dpi=80)
    plt.close(fig)
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
    fig.savefig(out / FIGURES["improvement"], dpi=80)
    plt.close(fig)
