"""Fair comparisons: every algorithm at its best setting, chosen on other seeds (`jaxeac study --tune`).

A grid over the rates each algorithm reads (actor-critic learners: α, β, γ, τ; Q-learning and
SARSA: α, γ, ε; `KEYS_OF`) runs on tuning seeds 0 … n−1 of a root key other than the
evaluation's (Eimer, Lindauer & Raileanu 2023: settings chosen on the seeds they are judged on
flatter themselves), all settings of one algorithm and task as entries of one compiled program
(traced `Hyper`, as `jaxeac.experiments.sweep`). Two selections (ties: the first in grid order):

- **per task**: each algorithm's setting with the most mean successes on that task;
- **across tasks**: each algorithm's one setting with the highest mean over tasks of its min–max
  normalised score, successes / T (`jaxeac.stats.tasks.point_estimates`' mean; the
  cross-environment setting of Patterson, Neumann, White & White 2024).

Each algorithm then runs at its selected settings on the study's evaluation seeds (same key,
same seeds: per seed what a plain run at that setting gives) and is compared with AC as the
study compares the preset (Holm over the family, the aggregate across tasks). Also recorded:
selection optimism (the chosen setting's tuning mean against its evaluation mean, Welch 95 %
interval) and sensitivity (best − median of an algorithm's cross-task scores over its grid).
`across_tasks`, the study's aggregate across tasks, is here too: the study and the selection
share its scale.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import sys

import jax.numpy as jnp
import numpy as np

from jaxeac.algorithm.config import Hyper, algorithm
from jaxeac.errors import UsageError
from jaxeac.experiments.common import check_key, check_positive_int, check_rate, welch_diff_ci95
from jaxeac.rng import KEY_LIMIT

RATES = ("alpha", "beta", "gamma", "temperature", "epsilon")
KEYS_OF = {"actor_critic": ("alpha", "beta", "gamma", "temperature"),
           "q_learning": ("alpha", "gamma", "epsilon"), "sarsa": ("alpha", "gamma", "epsilon")}
#: Host bytes the tuning results of one algorithm and task may take (success and steps per trial).
MAX_TUNE_BYTES = 2 << 30
CONDITIONS = ("preset", "per_task", "cross_task")


def keys_of(algo: str) -> tuple[str, ...]:
    """The rates `algo`'s learner reads."""
    return KEYS_OF[algorithm(algo).learner]


def parse_tune(text: str, algos) -> tuple[str | None, str, tuple[float, ...]]:
    """``[ALGO.]KEY=V1,V2,…`` → (algo or None for every algorithm with the key, key, values)."""
    if "=" not in text:
        raise UsageError(f"--tune {text!r}: write KEY=V1,V2,... (e.g. alpha=0.05,0.1) or ALGO.KEY=...")
    name, _, values = text.partition("=")
    algo, dot, key = name.strip().rpartition(".")
    algo = algo if dot else None
    if key not in RATES:
        raise UsageError(f"--tune: unknown key {key!r}; tunable keys: {', '.join(RATES)}")
    if algo is not None and algo not in algos:
        raise UsageError(f"--tune {name}: {algo!r} is not among --algos ({', '.join(algos)})")
    having = [a for a in ([algo] if algo else algos) if key in keys_of(a)]
    if not having:
        who = f"{algo} has no {key}" if algo else f"no algorithm of the study reads {key}"
        raise UsageError(
            f"--tune {name}: {who} (keys: "
            + "; ".join(f"{a}: {', '.join(keys_of(a))}" for a in ([algo] if algo else algos))
            + "); drop it or name an algorithm that reads it"
        )
    items = [v.strip() for v in values.split(",")]
    if not any(items) or not all(items):
        raise UsageError(f"--tune {name}={values}: empty value list or an empty value between commas; "
                         "give values separated by single commas (e.g. alpha=0.05,0.1)")
    parsed = []
    for item in items:
        try:
            v = float(item)
        except ValueError:
            raise UsageError(f"--tune {name}: cannot read {item!r} as a number") from None
        try:
            check_rate(key, v, upper=1.0 if key == "epsilon" else None, positive=key == "temperature")
        except UsageError as exc:
            raise UsageError(f"--tune {name}: {exc}") from None
        parsed.append(v)
    if len(set(parsed)) != len(parsed):
        raise UsageError(f"--tune {name}: a value is listed twice ({values}); list each once")
    return algo, key, tuple(parsed)


@dataclasses.dataclass(frozen=True)
class Tuning:
    """A validated tuning: per algorithm the grid of its keys, tuning seeds and their root key."""

    grids: dict  # {algo: ((key, values), ...)}, only keys the algorithm reads
    seeds: int
    key: int

    @staticmethod
    def build(texts, *, algos, seeds: int, key: int | None, eval_key: int, trials: int) -> Tuning:
        if not texts:
            raise UsageError("--tune-seeds needs a grid: give at least one --tune KEY=V1,V2,...")
        check_positive_int("--tune-seeds", seeds)
        if seeds < 2:
            raise UsageError(f"--tune-seeds {seeds}: a setting's score needs at least 2 seeds (e.g. 200)")
        key = (eval_key + 1) % KEY_LIMIT if key is None else key
        try:
            check_key(key)
        except UsageError as exc:
            raise UsageError(f"--tune-key: {exc}") from None
        if key == eval_key:
            raise UsageError(f"--tune-key {key} is the evaluation key (--key {eval_key}): tuning and "
                             "evaluation would run the same seeds; give another --tune-key (default: --key + 1)")
        given: dict = {}
        for text in texts:
            algo, k, values = parse_tune(text, algos)
            if (algo, k) in given:
                raise UsageError(f"--tune {algo + '.' if algo else ''}{k} given twice; put its values in one --tune")
            given[(algo, k)] = values
        grids = {}
        for a in algos:
            grids[a] = tuple((k, given.get((a, k), given.get((None, k)))) for k in keys_of(a)
                             if (a, k) in given or (None, k) in given)
            size = math.prod(len(v) for _, v in grids[a])
            if size * seeds * (trials * 5 + 64) > MAX_TUNE_BYTES:
                raise UsageError(f"--tune: {a}'s {size} settings x {seeds:,} tuning seeds x {trials} trials need "
                                 f"more than {MAX_TUNE_BYTES >> 30} GiB of host memory per task; give fewer "
                                 "values or fewer --tune-seeds")
        return Tuning(grids, seeds, key)

    def points(self, algo: str) -> list[dict]:
        keys = [k for k, _ in self.grids[algo]]
        combos = itertools.product(*(v for _, v in self.grids[algo]))
        return [dict(zip(keys, combo, strict=True)) for combo in combos]

    def record(self) -> dict:
        grids = {a: {k: list(v) for k, v in g} for a, g in self.grids.items()}
        return {"seeds": self.seeds, "key": self.key, "grids": grids}


def _hyper(grid, points: list[dict], algo: str, per_point: int) -> Hyper:
    """Per-entry traced rates: each point's (the preset's where it leaves a key out), `per_point` times."""
    hypers = [dataclasses.replace(grid, **p).run_config(algo).hyper() for p in points]
    return Hyper(*(jnp.repeat(jnp.stack([getattr(h, r) for h in hypers]), per_point) for r in RATES))


def _run(env, grid, algo: str, points: list[dict], *, key: int, seeds: int, chunk_size) -> np.ndarray:
    """int32 [len(points), seeds]: successes per seed of `algo` at each point, one program for all."""
    from jaxeac.running.batch import run_entries

    ids = np.tile(np.arange(seeds), len(points))
    res, _, _ = run_entries(env, grid.run_config(algo), root_key=key, seeds=ids,
                            hyper=_hyper(grid, points, algo, seeds), chunk_size=chunk_size)
    return np.asarray(res.success, bool).sum(axis=1).astype(np.int32).reshape(len(points), seeds)


def across_tasks(
    samples: dict[str, dict[str, np.ndarray]], trials: int, *, resamples: int, key: int, baseline: str = "ac"
) -> dict | None:
    """The aggregate across tasks (`jaxeac.stats.engine.compare`, Agarwal et al. 2021) of per-seed
    successes ``samples[task][algo]``: each algorithm's mean, median, IQM and optimality gap with
    95 % stratified-bootstrap intervals, and P(algo > `baseline`) averaged over tasks. None for one task.

    Scores are min–max normalised with the stated references (0, T) on every task: successes per
    seed lie in [0, T] whatever the task, so the scale is fixed before any run and the same for
    every algorithm and setting (a tuning's selection can use it), and the optimality gap is the
    share of trials short of succeeding on every one. Relative to AC would put AC at 1 by
    construction, be undefined where AC never succeeds and let a task where AC nearly never
    succeeds outweigh the rest. Every algorithm of a task ran the same seeds, so one draw of
    those seeds serves all of them (paired)."""
    if len(samples) < 2:
        return None
    from jaxeac.stats.engine import compare
    from jaxeac.stats.inputs import PerSeed

    values = {t: {a: np.asarray(x, np.float64) for a, x in per.items()} for t, per in samples.items()}
    seeds = {t: {a: np.arange(x.size).astype(str) for a, x in per.items()} for t, per in values.items()}
    per = PerSeed(values, seeds, "successes per seed over the trials", "study")
    res = compare(per, baseline=baseline, level=0.95, resamples=resamples, key=key, normalize="minmax",
                  reference_scores={t: (0.0, float(trials)) for t in values}, profile_points=min(trials + 1, 101))
    agg = res.aggregate
    agg["reference_why"] = ("min–max with the stated references (0, T) on every task: successes per seed lie "
                            "in [0, T], a scale fixed before any run and the same for every algorithm")
    agg["key"] = key
    return agg


def _verdicts(samples: dict, settings) -> dict:
    """As the study compares the preset: per task every algorithm against AC, Holm over the family,
    and the aggregate across tasks."""
    from jaxeac.stats import holm
    from jaxeac.stats.tidy import compare_samples

    rows, means = [], {}
    for i, (task, per) in enumerate(samples.items()):
        stats = compare_samples(per, baseline="ac", resamples=settings.resamples, key=settings.key + i)
        means[task] = {a: m["mean"] for a, m in stats["algorithms"].items()}
        rows += [{"task": task, **{k: v for k, v in r.items() if k != "p_holm"}} for r in stats["comparisons"]]
    for row, p in zip(rows, holm([r["p_welch"] for r in rows]) if rows else [], strict=True):
        row["p_holm"] = float(p)
    trials = settings.task_settings(next(iter(samples))).trials
    agg = across_tasks(samples, trials, resamples=settings.resamples, key=settings.key)
    return {"means": means, "comparisons": rows, "aggregate": agg}


def run_tuning(
    settings, tuning: Tuning, grids: dict, envs: dict, preset: dict, result: dict, *, progress: bool = True
) -> dict:
    """Tune, select, evaluate at the selections; `grids`/`envs`: the study's per task, `preset`:
    the study's per-seed successes {task: {algo: [N]}}, `result`: its study.json."""
    tasks, algos = list(grids), list(settings.algos)
    trials = grids[tasks[0]].trials
    scores: dict = {a: {} for a in algos}  # {algo: {task: [points, tuning seeds]}}
    for t in tasks:
        for a in algos:
            if progress:
                print(f"tune: {t}, {a}: {len(tuning.points(a))} settings x {tuning.seeds:,} seeds",
                      file=sys.stderr, flush=True)
            scores[a][t] = _run(envs[t], grids[t], a, tuning.points(a), key=tuning.key, seeds=tuning.seeds,
                                chunk_size=settings.chunk_size)
    per_algo = {}
    for a in algos:
        means = np.stack([scores[a][t].mean(axis=1) for t in tasks])  # [tasks, points]
        cross = (means / trials).mean(axis=0)  # mean over tasks of min–max (0, T) scores
        per_task = {t: int(np.argmax(means[i])) for i, t in enumerate(tasks)}
        best = int(np.argmax(cross))
        per_algo[a] = {
            "points": tuning.points(a),
            "tuning_means": {t: means[i].tolist() for i, t in enumerate(tasks)},
            "cross_task_scores": cross.tolist(),
            "per_task": per_task,
            "cross_task": best,
            "sensitivity": float(cross.max() - np.median(cross)),
            "sensitivity_per_task": {t: float((m.max() - np.median(m)) / trials) for t, m in zip(tasks, means, strict=True)},
        }
    samples = {c: {t: {} for t in tasks} for c in CONDITIONS[1:]}
    n = settings.seeds
    for t in tasks:
        for a in algos:
            if progress:
                print(f"tune: evaluating {t}, {a} at its selections on {n:,} seeds", file=sys.stderr, flush=True)
            sel = per_algo[a]
            pts = [sel["points"][sel["per_task"][t]], sel["points"][sel["cross_task"]]]
            both = _run(envs[t], grids[t], a, pts, key=settings.key, seeds=n, chunk_size=settings.chunk_size)
            samples["per_task"][t][a], samples["cross_task"][t][a] = both[0], both[1]
    optimism = {a: {} for a in algos}
    for a in algos:
        for t in tasks:
            tuned = scores[a][t][per_algo[a]["per_task"][t]]
            diff, lo, hi = welch_diff_ci95(samples["per_task"][t][a], tuned)  # tuning − evaluation
            optimism[a][t] = {"tuning_mean": float(tuned.mean()), "optimism": diff, "ci95": [lo, hi],
                              "evaluation_mean": float(samples["per_task"][t][a].mean())}
    conditions = {"preset": {"means": {t: {a: float(x.mean()) for a, x in per.items()} for t, per in preset.items()},
                             "comparisons": result["comparisons"], "aggregate": result.get("aggregate")}}
    for c in CONDITIONS[1:]:
        conditions[c] = _verdicts(samples[c], settings)
    return {**tuning.record(), "evaluation_key": settings.key, "evaluation_seeds": n,
            "selection": "per task: most mean successes on the task; across tasks: highest mean over tasks of "
                         "successes / T (min–max on (0, T)); ties: the first setting in grid order",
            "algorithms": per_algo, "optimism": optimism, "conditions": conditions}


def _mark(rows: list[dict], task: str, algo: str, level: float) -> str:
    """+ / − where `algo` is better / worse than AC on `task` at Holm p ≤ `level`, else ''."""
    row = next((r for r in rows if r["task"] == task and r["x"] == algo), None)
    return "" if row is None or row["p_holm"] > level else "+" if row["diff"] > 0 else "−"


def _setting(point: dict) -> str:
    return ", ".join(f"{SYMBOL[k]} = {v:g}" for k, v in point.items()) or "preset"


SYMBOL = {"alpha": "α", "beta": "β", "gamma": "γ", "temperature": "τ", "epsilon": "ε"}


def tuned_markdown(tu: dict, *, level: float = 0.05) -> list[str]:
    """The report's sections on the tuned study: selections, verdicts side by side, sensitivity."""
    algos, conds = tu["algorithms"], tu["conditions"]
    tasks = list(conds["per_task"]["means"])
    lines = ["## Tuned: every algorithm at its best setting", "",
             f"Tuning: {tu['seeds']:,} seeds of key {tu['key']}; evaluation: {tu['evaluation_seeds']:,} "
             f"seeds of key {tu['evaluation_key']} (disjoint). Selection — {tu['selection']}. Each condition "
             "is compared with AC as the preset is (Holm over its own family); + / −: better / worse than AC "
             f"at Holm p ≤ {level:g}.", "",
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
    lines += ["", "### Across tasks, per condition", "",
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
    return [*lines, ""]


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
    return "\n".join(lines)
