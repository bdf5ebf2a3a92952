"""`Comparison`: the one result of `jaxeac.stats.engine.compare`, and its renderings.

Rows of a table: per task and pair (`rows`), per task and algorithm (`algorithms`), and the
aggregate across tasks (`aggregate`, `jaxeac.stats.tasks`). `to_dict` is the JSON written
(level-neutral keys: ``diff_ci`` and a top-level ``level``), `markdown` the report and `lines`
what the command line prints. A run folder's comparison also keeps the folder's full
statistics (`stats`, the content of its stats.json).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

from jaxeac.fmt import compact, compact_interval, p_sig, percent
from jaxeac.stats.large import PATH_RULE

SCHEMA = "jaxeac.compare/2"


@dataclass
class Comparison:
    level: float
    family: str
    family_size: int
    resamples: int
    key: int | None
    source: dict
    tasks: list
    algorithms: list = field(default_factory=list)
    rows: list = field(default_factory=list)
    aggregate: dict | None = None
    resampling: dict | None = None
    stats: dict | None = None  # a run folder's stats.json

    @classmethod
    def from_run(cls, stats: dict) -> Comparison:
        """The rows of a run folder's statistics (one per measure; the task is the experiment)."""
        b, t = stats["baseline"], stats["treatment"]
        paired = (stats.get("paired") or {}).get("measures", {})
        rows = []
        for m in [stats["primary"], *stats["secondary"].values()]:
            pr = paired.get(m["measure"])
            rows.append(
                {
                    "task": stats["experiment"],
                    "measure": m["measure"],
                    "x": t,
                    "y": b,
                    "n_x": m["n_treatment"],
                    "n_y": m["n_baseline"],
                    "mean_x": m["mean_treatment"],
                    "mean_y": m["mean_baseline"],
                    "diff": m["diff"],
                    "diff_ci": m["diff_ci"],
                    "p_welch": m["p_welch"],
                    "p_holm": m.get("p_holm"),
                    "hedges_g": m["hedges_g"],
                    "p_improvement": m["prob_improvement"],
                    "p_improvement_ci": m["prob_improvement_ci"],
                    "analysis": "paired" if pr else "unpaired",
                    "paired": None
                    if pr is None
                    else {k: pr[k] for k in ("n", "mean_diff", "mean_diff_ci", "p_paired_t", "d_z")},
                }
            )
        scale = stats["settings"]["scale"]
        return cls(
            level=stats["level"],
            family=f"{t} vs {b}",
            family_size=len(rows),
            resamples=stats["settings"]["resamples"],
            key=stats["settings"]["key"],
            source={
                "source": stats.get("run_dir"),
                "format": "run folder",
                "per_seed_value": stats["primary"].get("description"),
            },
            tasks=[stats["experiment"]],
            rows=rows,
            resampling={"rule": PATH_RULE, "path": scale["path"]},
            stats=stats,
        )

    def to_dict(self) -> dict:
        if self.stats is not None:
            return self.stats
        out = asdict(self)
        del out["stats"]
        return {"schema": SCHEMA, **out}

    # ------------------------------------------------------------ text
    def lines(self) -> list[str]:
        """What `jaxeac compare` prints: one line per comparison, the answering analysis first."""
        pct = percent(self.level)
        out = [
            f"{self.source.get('per_seed_value')}; family: {self.family}, Holm over {self.family_size} "
            f"comparison(s); {pct} intervals"
        ]
        if self.source.get("excluded_total"):
            out.append(f"failed seeds excluded (missing or NaN values): {self.source['excluded_total']}")
        for r in self.rows:
            where = f"[{r['task']}] " if r.get("task") and len(self.tasks) > 1 else ""
            what = f"{r['x']} - {r['y']}" + (f" on {r['measure']}" if r.get("measure") else "")
            if r.get("paired"):
                pr = r["paired"]
                out.append(
                    f"{where}{what}, paired (same seeds): {compact(pr['mean_diff'], 4, sign=True)} "
                    f"({pct} CI {compact_interval(pr['mean_diff_ci'], 4)}), paired t p = "
                    f"{p_sig(pr['p_paired_t'])}, Holm p = {p_sig(r['p_holm'])}"
                )
                lead = f"{where}  unpaired (secondary): "
            else:
                lead = f"{where}{what}: "
            holm = "" if r.get("paired") else f", Holm p = {p_sig(r['p_holm'])}"
            out.append(
                f"{lead}{compact(r['diff'], 4, sign=True)} ({pct} CI {compact_interval(r['diff_ci'], 4)}), "
                f"Welch p = {p_sig(r['p_welch'])}{holm}, P({r['x']} > {r['y']}) = "
                f"{compact(r['p_improvement'])} {compact_interval(r['p_improvement_ci'])}"
            )
        if self.aggregate:
            out += agg_lines(self.aggregate, pct)
        return out

    def markdown(self) -> str:
        pct = percent(self.level)
        src = self.source
        lines = [
            "# Comparison of per-seed results",
            "",
            f"Source: `{src['source']}` ({src['format']}); {src['per_seed_value']}.",
            f"Family: {self.family} ({self.family_size} comparison(s)); Holm's adjustment over the "
            "family, on "
            "the paired t test where a pair ran the same seed ids (the paired result answers; the unpaired "
            "one is secondary), else on Welch's. Intervals: "
            f"{pct} BCa from {self.resamples:,} bootstrap resamples, seeds resampled within each algorithm "
            f"and task (Agarwal et al. 2021); key {self.key}. diff = mean(X) − mean(Y); P(X > Y) counts ties "
            "as one half.",
            f"Resampling path: {self.resampling['rule']} ("
            + (f"groups: {', '.join(f'{k}: {v}' for k, v in self.resampling['groups'].items())}"
               if "groups" in self.resampling else f"path: {self.resampling.get('path')}") + ").",
            f"Failed seeds excluded: {src.get('excluded_total', 0)} ({src.get('failed_seed_rule', '')}).",
            "",
        ]
        for task in self.tasks:
            rows = [r for r in self.rows if r["task"] == task]
            if len(self.tasks) > 1:
                lines += [f"## Task {task}", ""]
            lines += [
                f"| X | Y | design | paired diff [{pct} CI] | paired t p | Holm p | unpaired diff [{pct} CI] "
                f"(secondary where paired) | Welch p | Hedges' g | P(X > Y) [{pct} CI] |",
                "|---|---|---|---|---:|---:|---|---:|---:|---|",
            ]
            for r in rows:
                pr = r["paired"]
                paired = (
                    (
                        f"{compact(pr['mean_diff'], 4)} {compact_interval(pr['mean_diff_ci'], 4)} | "
                        f"{p_sig(pr['p_paired_t'])}"
                    )
                    if pr
                    else "— | —"
                )
                lines.append(
                    f"| {r['x']} | {r['y']} | {r['analysis']} | {paired} | {p_sig(r['p_holm'])} | "
                    f"{compact(r['diff'], 4)} {compact_interval(r['diff_ci'], 4)} | {p_sig(r['p_welch'])} | "
                    f"{compact(r['hedges_g'])} | {compact(r['p_improvement'])} "
                    f"{compact_interval(r['p_improvement_ci'])} |"
                )
            lines += [
                "",
                f"| algorithm | n | failed, excluded | mean | IQM [{pct} CI] |",
                "|---|---:|---:|---:|---|",
            ]
            for a in (a for a in self.algorithms if a["task"] == task):
                lines.append(
                    f"| {a['algo']} | {a['n']} | {a['excluded']} | {compact(a['mean'], 4)} | "
                    f"{compact(a['iqm'], 4)} {compact_interval(a['iqm_ci'], 4)} |"
                )
            lines.append("")
        if self.aggregate:
            lines += agg_markdown(self.aggregate, pct)
        elif len(self.tasks) > 1:
            lines += [
                "## Across tasks",
                "",
                "Not computed: the aggregates across tasks need the scores on one "
                "scale; pass --normalize minmax (with --reference-scores), baseline or none.",
                "",
            ]
        return "\n".join(lines) + "\n"


def agg_lines(agg: dict, pct: str) -> list[str]:
    out = [f"across {len(agg['tasks'])} tasks ({agg['normalization']['text']}):"]
    for a, m in agg["algorithms"].items():
        out.append(
            "  "
            + a
            + ": "
            + ", ".join(
                f"{k} {compact(v['estimate'], 4)} {compact_interval(v['ci'], 4)}" for k, v in m.items()
            )
        )
    for r in agg["pairs"]:
        out.append(
            f"  P({r['x']} > {r['y']}) averaged over tasks = {compact(r['estimate'])} "
            f"{compact_interval(r['ci'])}"
        )
    return out


def agg_markdown(agg: dict, pct: str) -> list[str]:
    names = list(next(iter(agg["algorithms"].values())))
    lines = [
        "## Across tasks",
        "",
        f"Scores: {agg['normalization']['text']}. {agg['method']}",
        "",
        "| algorithm | " + " | ".join(f"{k} [{pct} CI]" for k in names) + " |",
        "|---|" + "---|" * len(names),
    ]
    for a, m in agg["algorithms"].items():
        lines.append(
            f"| {a} | "
            + " | ".join(f"{compact(m[k]['estimate'], 4)} {compact_interval(m[k]['ci'], 4)}" for k in names)
            + " |"
        )
    lines += ["", f"| X | Y | P(X > Y), mean over tasks [{pct} CI] |", "|---|---|---|"]
    for r in agg["pairs"]:
        lines.append(f"| {r['x']} | {r['y']} | {compact(r['estimate'])} {compact_interval(r['ci'])} |")
    prof = agg["profiles"]
    lines += [
        "",
        f"Performance profiles (share of runs with a score above τ, {pct} bands) at "
        f"{len(prof['tau'])} thresholds are in the JSON (`aggregate.profiles`).",
        "",
    ]
    return lines
