"""The tuned study's sensitivity figure: per task (rows) and key (columns), each algorithm's mean
successes against the key's values with the other keys at the task's selection, a 95 % t band over
the tuning seeds (`jaxeac.experiments.tune_measures.curves`), its selected value marked."""

from __future__ import annotations

import io
from pathlib import Path

from jaxeac.experiments.tune_report import SYMBOL

SENSITIVITY_FIGURE = "tune_sensitivity.png"  # not fig_*: the study's staged write replaces those


def sensitivity_figure(tu: dict, trials: int, path: Path) -> None:
    """Draw `tu` (the tuning's record, with ``algorithms[a]["curves"][task][key]``) to `path`."""
    import matplotlib.pyplot as plt

    from jaxeac import style
    from jaxeac.io import atomic_write_bytes

    algos = tu["algorithms"]
    tasks = list(tu["conditions"]["per_task"]["means"]) if "conditions" in tu else \
        list(next(iter(algos.values()))["curves"])
    keys = [k for k in SYMBOL if any(k in c for s in algos.values() for c in s["curves"].values())]
    if not keys:
        return
    fig, axes = plt.subplots(len(tasks), len(keys), figsize=(3.3 * len(keys), 2.4 * len(tasks) + 0.6),
                             squeeze=False)
    for i, t in enumerate(tasks):
        for j, k in enumerate(keys):
            ax = axes[i, j]
            for a, s in sorted(algos.items(), key=lambda item: item[0] in ("ac", "eac")):  # AC, EAC on top
                c = s["curves"].get(t, {}).get(k)
                if c is None:
                    continue
                lo, hi = zip(*c["ci95"], strict=True)
                ax.plot(c["values"], c["mean"], color=style.color(a), lw=1.8 if a in ("ac", "eac") else 1.2,
                        marker="o", ms=2.5, label=style.label(a))
                ax.fill_between(c["values"], lo, hi, color=style.color(a), alpha=0.2, lw=0)
                at = c["values"].index(c["chosen"])
                ax.plot([c["chosen"]], [c["mean"][at]], marker="*", ms=8, color=style.color(a), mec="white",
                        mew=0.5, ls="none")
            panel = [c for s in algos.values() if (c := s["curves"].get(t, {}).get(k))]
            values = sorted({v for c in panel for v in c["values"]})
            if values and min(values) > 0 and max(values) / min(values) >= 2.5:
                ax.set_xscale("log")
            if values:
                ax.set_xticks(values, [f"{v:g}" for v in values])
                ax.minorticks_off()
                lo = min(b[0] for c in panel for b in c["ci95"])
                hi = max(b[1] for c in panel for b in c["ci95"])
                pad = max(0.0, 0.1 * trials - (hi - lo)) / 2 + 0.02 * trials  # at least a tenth of T in view
                ax.set_ylim(max(lo - pad, -0.02 * trials), min(hi + pad, 1.02 * trials))
            ax.tick_params(labelsize=7)
            ax.grid(alpha=0.3)
            ax.set_title(f"{t}: {SYMBOL[k]}", fontsize=8)
            ax.set_xlabel(f"{SYMBOL[k]} ({k})", fontsize=8)
            if j == 0:
                ax.set_ylabel(f"mean successes (of {trials})", fontsize=8)
    handles: dict = {}
    for ax in axes.flat:
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(lab, h)
    labels = [style.label(a) for a in algos if style.label(a) in handles]  # the study's order
    fig.legend([handles[lab] for lab in labels], labels, loc="lower center", ncol=min(8, len(labels)), fontsize=8,
               title=f"mean successes over {tu['seeds']:,} tuning seeds, the other keys at the task's selection "
                     "(shaded: 95 % CI of the mean; ★ the selected value)", title_fontsize=8)
    fig.tight_layout(rect=(0, 0.6 / (2.4 * len(tasks) + 0.6), 1, 1))
    buf = io.BytesIO()
    fig.savefig(buf, dpi=90, format="png")
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())
