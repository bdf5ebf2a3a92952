"""The report's sections on a tuned study (`jaxeac.experiments.tune`): selections, verdicts under
the preset and both tunings side by side, sensitivity (figure, numbers, the claim "EAC is less
sensitive to its rates"), EAC head to head with AC, Q-learning and SARSA, and a terminal summary.
Markdown from the tuning's JSON record alone."""

from __future__ import annotations

CONDITIONS = ("preset", "per_task", "cross_task")
SYMBOL = {"alpha": "α", "beta": "β", "gamma": "γ", "temperature": "τ", "epsilon": "ε"}
NAMES = {"ac": "AC", "eac": "EAC", "q_learning": "Q-learning", "sarsa": "SARSA"}


def _mark(rows: list[dict], task: str, algo: str, level: float) -> str:
    """+ / − where `algo` is better / worse than AC on `task` at Holm p ≤ `level`, else ''."""
    row = next((r for r in rows if r["task"] == task and r["x"] == algo), None)
    return "" if row is None or row["p_holm"] > level else "+" if row["diff"] > 0 else "−"


def _setting(point: dict) -> str:
    return ", ".join(f"{SYMBOL[k]} = {v:g}" for k, v in point.items()) or "preset"


def tuned_markdown(tu: dict, *, level: float = 0.05) -> list[str]:
    """The report's sections on the tuned study: selections, verdicts side by side, sensitivity."""
    algos, conds = tu["algorithms"], tu["conditions"]
    tasks = list(conds["per_task"]["means"])
    lines = ["## Tuned: every algorithm at its best setting", "",
             f"Tuning: {tu['seeds']:,} seeds of key {tu['key']}; evaluation: {tu['evaluation_seeds']:,} "
             f"seeds of key {tu['evaluation_key']} (disjoint). Selection — {tu['selection']}. Each condition "
             "is compared with AC as the preset is (Welch, Holm over its own family); + / −: better / worse "
             f"than AC at Holm p ≤ {level:g}.", "",
             "| algorithm | grid | cross-task setting | its score (tuning) | sensitivity (best − median) |",
             "|---|---|---|---|---|"]
    for a, s in algos.items():
        grid = "; ".join(f"{SYMBOL[k]} ∈ {{{', '.join(f'{v:g}' for v in vals)}}}"
                         for k, vals in tu["grids"][a].items())
        lines.append(f"| {a} | {grid or 'preset only'} | {_setting(s['points'][s['cross_task']])} | "
                     f"{s['cross_task_scores'][s['cross_task']]:.3f} | {s['sensitivity']:.3f} |")
    for t in tasks:
        lines += ["", f"### {t}", "", "| algorithm | preset | per-task tuned (setting) | cross-task tuned "
                  "| optimism, per-task (tuning − evaluation) [95% CI] |", "|---|---|---|---|---|"]
        for a in algos:
            cells = []
            for c in CONDITIONS:
                mark = _mark(conds[c]["comparisons"], t, a, level)
                cells.append(f"{conds[c]['means'][t][a]:.2f}{mark}")
            cells[1] += f" ({_setting(algos[a]['points'][algos[a]['per_task'][t]])})"
            o = tu["optimism"][a][t]
            lines.append(f"| {a} | {' | '.join(cells)} | {o['optimism']:+.2f} [{o['ci95'][0]:+.2f}, "
                         f"{o['ci95'][1]:+.2f}] |")
        best = [max(algos, key=lambda a, c=c: conds[c]["means"][t][a]) for c in CONDITIONS]
        lines += ["", f"Highest mean: {' / '.join(best)} (preset / per-task / cross-task; the leaders are not "
                  "tested against each other, only against AC)."]
    res = [(c, conds[c]["aggregate"].get("resamples")) for c in CONDITIONS if conds[c].get("aggregate")]
    lines += ["", "### Across tasks, per condition", "", "Stratified bootstrap: " + ", ".join(
        f"{c} {r:,} resamples" for c, r in res if r) + ".", "",
              "| algorithm | " + " | ".join(f"IQM {c} [95% CI] | P(> ac) {c}" for c in CONDITIONS) + " |",
              "|---|" + "---|---|" * len(CONDITIONS)]
    for a in algos:
        cells = []
        for c in CONDITIONS:
            agg = conds[c]["aggregate"]
            if agg is None:
                cells += ["", ""]
                continue
            m = agg["algorithms"][a]["iqm"]
            pi = next((r["estimate"] for r in agg["pairs"] if r["x"] == a), None)
            cells += [f"{m['estimate']:.3f} [{m['ci'][0]:.3f}, {m['ci'][1]:.3f}]", "" if pi is None else f"{pi:.3f}"]
        lines.append(f"| {a} | " + " | ".join(cells) + " |")
    if "sensitivity" in tu:
        lines += sensitivity_markdown(tu)
    if "head_to_head" in tu:
        lines += head_to_head_markdown(tu["head_to_head"])
    return [*lines, ""]


def _ci(m: dict, fmt: str = "+.3f") -> str:
    return f"{m['estimate']:{fmt}} [{m['ci95'][0]:{fmt}}, {m['ci95'][1]:{fmt}}]"


def claim_line(tu: dict) -> str:
    c = tu["sensitivity"]["claim"]
    if "ci95" not in c:
        return f'"EAC is less sensitive to its rates than AC": {c["verdict"]}.'
    k = len(tu["conditions"]["per_task"]["means"])
    return (f'"EAC is less sensitive to its rates than AC": **{c["verdict"]}** (EAC − AC, best − median of the '
            f'cross-task score: {_ci(c)}; per task, less sensitive on {c["tasks_less"]} and more on '
            f'{c["tasks_more"]} of {k} tasks, 95 % intervals excluding 0).')


def sensitivity_markdown(tu: dict) -> list[str]:
    """Sensitivity: the curves' figure, best − median per algorithm and task, the claim."""
    sens = tu["sensitivity"]
    tasks = list(tu["conditions"]["per_task"]["means"])
    lines = ["", "### Sensitivity to the rates", ""]
    if tu.get("figure"):
        lines += [f"![mean successes against each key, the others at the task's selection]({tu['figure']})", ""]
    lines += [f"Curves (figure; numbers in study.json, `tuning.algorithms.*.curves`): per task and key, mean "
              "successes at each value with the other keys at the task's selection, 95 % t band over the tuning "
              f"seeds. Sensitivity: {sens['method']} ({sens['resamples']:,} resamples). Each algorithm "
              "is scored over its own grid: the actor-critic learners share one, Q-learning and SARSA read ε "
              "instead of β and τ.", "",
              "| algorithm | sensitivity across tasks [95% CI] | − AC [95% CI] | tasks less / more sensitive than AC | "
              + " | ".join(tasks) + " |", "|---|---|---|---|" + "---|" * len(tasks)]
    for a, s in sens["algorithms"].items():
        m = s.get("minus_ac")
        vs = "" if a == "ac" or m is None else _ci(m)
        counts = "" if a == "ac" or m is None else f"{m['tasks_less']} / {m['tasks_more']}"
        cells = " | ".join(f"{s['per_task'][t]['estimate']:.3f}" for t in tasks)
        lines.append(f"| {a} | {_ci(s, '.3f')} | {vs} | {counts} | {cells} |")
    return [*lines, "", claim_line(tu)]


def head_to_head_markdown(h2h: dict) -> list[str]:
    """Does EAC still beat AC, Q-learning and SARSA when each is at its best? Per task and over tasks."""
    pre, tun = h2h["preset"], h2h["per_task"]
    rivals = list(tun["rivals"])
    if not rivals:
        return []
    tasks = list(tun["leaders"])
    lines = ["", "### Does EAC still beat AC, Q-learning and SARSA when each is at its best?", "",
             "EAC − X in mean successes [Welch 95 % CI], under the preset and with both at their per-task "
             "selections; last row: mean over tasks of (EAC − X) / T [95 % CI]. Leader: highest mean of all "
             "algorithms.", "",
             "| task | " + " | ".join(f"EAC − {NAMES.get(r, r)}: preset | per-task tuned" for r in rivals)
             + " | leader: preset → tuned |", "|---|" + "---|---|" * len(rivals) + "---|"]

    def cell(c):
        return f"{c['diff']:+.1f} [{c['ci95'][0]:+.1f}, {c['ci95'][1]:+.1f}]"

    for t in tasks:
        cells = [cell(cond["rivals"][r]["per_task"][t]) for r in rivals for cond in (pre, tun)]
        lead = pre["leaders"][t] + (f" → **{tun['leaders'][t]}**" if tun["leaders"][t] != pre["leaders"][t] else " (same)")
        lines.append(f"| {t} | " + " | ".join(cells) + f" | {lead} |")
    over = [f"{c['rivals'][r]['over_tasks']['diff']:+.3f} [{c['rivals'][r]['over_tasks']['ci95'][0]:+.3f}, "
            f"{c['rivals'][r]['over_tasks']['ci95'][1]:+.3f}]" for r in rivals for c in (pre, tun)]
    lines += ["| over tasks (/ T) | " + " | ".join(over) + " | |", ""]
    for r in rivals:
        lines.append(f"- EAC vs {NAMES.get(r, r)}: " + "; ".join(
            f"{name}: higher on {c['rivals'][r]['higher']}, lower on {c['rivals'][r]['lower']} of {len(tasks)} tasks"
            + (f" (lower: {', '.join(t for t in tasks if c['rivals'][r]['per_task'][t]['verdict'] == 'lower')})"
               if c["rivals"][r]["lower"] else "")
            for name, c in (("preset", pre), ("per-task tuned", tun), ("cross-task tuned", h2h["cross_task"]))))
    changed = tun.get("leader_changed", [])
    lines.append("- Leader after per-task tuning: " + ("unchanged on every task" if not changed else "changed on "
                 + ", ".join(f"{t} ({pre['leaders'][t]} → {tun['leaders'][t]})" for t in changed)) + ".")
    return lines


def tuned_summary(tu: dict, *, level: float = 0.05) -> str:
    """For a terminal: per task and algorithm, mean successes under the preset, per-task-tuned and
    cross-task-tuned settings (+ / −: better / worse than AC at Holm p ≤ `level`)."""
    conds = tu["conditions"]
    lines = [f"tuned ({tu['seeds']:,} tuning seeds, key {tu['key']}): mean successes preset / per-task tuned / "
             f"cross-task tuned; + / −: vs ac, Holm p ≤ {level:g}"]
    for t in conds["per_task"]["means"]:
        cells = []
        for a in tu["algorithms"]:
            vals = []
            for c in CONDITIONS:
                mark = _mark(conds[c]["comparisons"], t, a, level)
                vals.append(f"{conds[c]['means'][t][a]:.1f}{mark}")
            cells.append(f"{a} {'/'.join(vals)}")
        lines.append(f"  {t}: " + "; ".join(cells))
    if "sensitivity" in tu:
        lines.append("  " + claim_line(tu).replace("**", ""))
    if "head_to_head" in tu:
        h = tu["head_to_head"]["per_task"]
        lines.append("  per-task tuned, EAC vs " + "; ".join(
            f"{r}: higher on {v['higher']}, lower on {v['lower']} of {len(h['leaders'])} tasks" for r, v in h["rivals"].items()))
    return "\n".join(lines)
