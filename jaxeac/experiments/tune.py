"""Fair comparisons: every algorithm at its best setting, chosen on other seeds (`jaxeac study --tune`).

A grid over the rates each algorithm reads (actor-critic learners: α, β, γ, τ; Q-learning and
SARSA: α, γ, ε; `KEYS_OF`) runs on tuning seeds 0 … n−1 of a root key other than the
evaluation's (seed i's key is ``fold_in(root, i)``, SPEC R1, so another root gives other seeds;
Eimer, Lindauer & Raileanu 2023: settings chosen on the seeds they are judged on flatter
themselves), all settings of one algorithm and task as entries of one compiled program (traced
`Hyper`, as `jaxeac.experiments.sweep`). The measure is the study's, successes per seed (SPEC §6). Two selections (ties: the first in grid order):

- **per task**: each algorithm's setting with the most mean successes on that task;
- **across tasks**: each algorithm's one setting with the highest mean over tasks of its min–max
  normalised score, successes / T (`jaxeac.stats.tasks.point_estimates`' mean; the
  cross-environment setting of Patterson, Neumann, White & White 2024).

Each algorithm then runs at its selected settings on the study's evaluation seeds (same key,
same seeds: per seed what a plain run at that setting gives) and is compared with AC by the test
behind the study's + / − on the preset (Welch, Holm over the condition's family) and by the
aggregate across tasks (at most `AGGREGATE_RESAMPLES` resamples, its costly part). Also recorded:
selection optimism (the chosen setting's tuning mean against its evaluation mean, Welch 95 %
interval) and sensitivity (best − median of an algorithm's cross-task scores over its grid).
`across_tasks`, the study's aggregate across tasks, is here too: the study and the selection
share its scale.

Sensitivity (`sensitivity`): per algorithm, task and key, mean successes against the key's values
with the other keys at the task's selection and a 95 % t band over the tuning seeds (drawn by
`jaxeac.experiments.tune_figures`); best − median with a 95 % interval from resampling the tuning
seeds within each task (the same draws for every algorithm: paired, as every algorithm ran the same
seeds), and each algorithm's difference from AC. Head to head (`head_to_head`): EAC − AC,
Q-learning and SARSA per task (Welch 95 %) and over tasks, preset and per-task tuned.

Resume: each algorithm × task's tuning and evaluation successes are written atomically under
``tune/`` of the study folder (`Tuning.folder`) and reused by a rerun with the same settings; a
folder whose ``tune/setup.json`` records another grid, seeds or key is refused before any compute.
The report's sections are `jaxeac.experiments.tune_report`'s.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
from pathlib import Path

import numpy as np

from jaxeac.algorithm.config import algorithm
from jaxeac.errors import UsageError
from jaxeac.experiments.common import check_key, check_positive_int, check_rate, plain_json, welch_diff_ci95
from jaxeac.experiments.tune_measures import claim, curves, head_to_head, sensitivity
from jaxeac.experiments.tune_report import CONDITIONS, tuned_markdown, tuned_summary
from jaxeac.experiments.tune_runs import RATES, TuningRuns
from jaxeac.rng import KEY_LIMIT
from jaxeac.stats.closed_form import holm, welch_t

KEYS_OF = {"actor_critic": ("alpha", "beta", "gamma", "temperature"),
           "q_learning": ("alpha", "gamma", "epsilon"), "sarsa": ("alpha", "gamma", "epsilon")}
#: Host bytes the tuning results of one algorithm and task may take (success and steps per trial).
MAX_TUNE_BYTES = 2 << 30
#: Seed resamples of the sensitivity's interval.
SENSITIVITY_RESAMPLES = 2000
#: At most this many resamples for the tuned conditions' aggregates across tasks (the costly part).
AGGREGATE_RESAMPLES = 2000


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
    folder: Path | None = dataclasses.field(default=None, compare=False)  # the study's: resume under tune/

    @staticmethod
    def build(texts, *, algos, seeds: int, key: int | None, eval_key: int, trials: int, out=None) -> Tuning:
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
        tuning = Tuning(grids, seeds, key, None if out is None else Path(out))
        tuning.check_folder()
        return tuning

    def check_folder(self) -> None:
        """Refuse a study folder whose ``tune/setup.json`` records another tuning (resuming it would mix two)."""
        if self.folder is None or not (path := self.folder / "tune" / "setup.json").is_file():
            return
        from jaxeac.io import read_json_object

        saved, now = read_json_object(path), plain_json(self.record())
        if saved != now:
            diff = ", ".join(f"{k} {json.dumps(saved.get(k))} there, {json.dumps(now[k])} now"
                             for k in now if saved.get(k) != now[k])
            raise UsageError(f"--tune: {self.folder} holds a tuning with another setup ({diff}); give another "
                             f"--out, or remove {self.folder / 'tune'} to tune afresh")

    def points(self, algo: str) -> list[dict]:
        keys = [k for k, _ in self.grids[algo]]
        combos = itertools.product(*(v for _, v in self.grids[algo]))
        return [dict(zip(keys, combo, strict=True)) for combo in combos]

    def record(self) -> dict:
        grids = {a: {k: list(v) for k, v in g} for a, g in self.grids.items()}
        return {"seeds": self.seeds, "key": self.key, "grids": grids}


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
    from jaxeac.perseed import PerSeed
    from jaxeac.stats.engine import compare

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
    """As the study's verdicts on the preset: per task every algorithm against AC with Welch's test,
    Holm over the family (the test behind the study's + / −), and the aggregate across tasks
    (`across_tasks`, at most `AGGREGATE_RESAMPLES` resamples: it is the costly part)."""
    rows, means = verdict_rows(samples)
    trials = settings.task_settings(next(iter(samples))).trials
    agg = across_tasks(samples, trials, resamples=min(settings.resamples, AGGREGATE_RESAMPLES), key=settings.key)
    return {"means": means, "comparisons": rows, "aggregate": agg}


def verdict_rows(samples: dict) -> tuple[list, dict]:
    """Per task, every algorithm against AC: the Welch interval and p, Holm over the family; and
    the means {task: {algo: mean}}."""
    rows, means = [], {}
    for task, per in samples.items():
        means[task] = {a: float(np.mean(x)) for a, x in per.items()}
        for a, x in per.items():
            if a != "ac":
                diff, lo, hi = welch_diff_ci95(per["ac"], x)
                rows.append({"task": task, "x": a, "y": "ac", "diff": diff, "diff_ci95": [lo, hi],
                             "p_welch": float(welch_t(per["ac"], x).pvalue)})
    for row, p in zip(rows, holm([r["p_welch"] for r in rows]), strict=True):
        row["p_holm"] = float(p)
    return rows, means


def tuning_runs(settings, tuning: Tuning, grids: dict, envs: dict, *, progress: bool = True) -> TuningRuns:
    """The tuning's runs for a study (its `grids`/`envs` per task), kept under ``tune/`` of
    `tuning.folder` (checked, and its setup recorded, here) and reused on a rerun."""
    store = None if tuning.folder is None else tuning.folder / "tune"
    if store is not None:
        from jaxeac.io import atomic_write_json

        tuning.check_folder()
        store.mkdir(parents=True, exist_ok=True)
        if not (store / "setup.json").is_file():
            atomic_write_json(store / "setup.json", tuning.record())
    return TuningRuns(settings, tuning, grids, envs, store, progress)


def select(tuning: Tuning, scores: dict, tasks: list, algos: list, trials: int) -> dict:
    """Per algorithm its points, tuning means, selections (per task, across tasks), sensitivity and
    curves, from the tuning's successes `scores` {algo: {task: [points, tuning seeds]}}."""
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
            "curves": {t: curves(tuning.points(a), per_task[t], scores[a][t]) for t in tasks},
        }
    return per_algo


def run_tuning(
    settings, tuning: Tuning, grids: dict, envs: dict, preset: dict, result: dict, *, progress: bool = True,
    runs: TuningRuns | None = None, scores=None, samples=None, phase=None,
) -> dict:
    """Tune, select, evaluate at the selections; `grids`/`envs`: the study's per task, `preset`:
    the study's per-seed successes {task: {algo: [N]}}, `result`: its study.json. With
    `tuning.folder`, each algorithm × task's runs are kept under ``tune/`` and reused on a rerun.
    `runs`, `scores` (a future of ``runs.tune()``) and `samples` (of ``runs.evaluate``): runs started
    earlier (`tuning_runs`);
    `phase(name)`: a context timing each part (the study's timeline)."""
    import contextlib

    phase = phase or (lambda name: contextlib.nullcontext())
    tasks, algos = list(grids), list(settings.algos)
    trials = grids[tasks[0]].trials
    runs = runs or tuning_runs(settings, tuning, grids, envs, progress=progress)
    with phase("tuning_runs"):
        scores = runs.tune() if scores is None else scores.result()  # {algo: {task: [points, tuning seeds]}}
    per_algo = select(tuning, scores, tasks, algos, trials)
    with phase("evaluation_runs"):
        samples = runs.evaluate(per_algo, preset) if samples is None else samples.result()
    n = settings.seeds
    optimism = {a: {} for a in algos}
    for a in algos:
        for t in tasks:
            tuned = scores[a][t][per_algo[a]["per_task"][t]]
            diff, lo, hi = welch_diff_ci95(samples["per_task"][t][a], tuned)  # tuning − evaluation
            optimism[a][t] = {"tuning_mean": float(tuned.mean()), "optimism": diff, "ci95": [lo, hi],
                              "evaluation_mean": float(samples["per_task"][t][a].mean())}
    conditions = {"preset": {"means": {t: {a: float(x.mean()) for a, x in per.items()} for t, per in preset.items()},
                             "comparisons": result["comparisons"], "aggregate": result.get("aggregate")}}
    with phase("tuned_verdicts"):
        for c in CONDITIONS[1:]:
            conditions[c] = _verdicts(samples[c], settings)
    with phase("sensitivity"):
        sens = sensitivity(scores, tasks, trials, resamples=SENSITIVITY_RESAMPLES, key=settings.key,
                           same_keys=lambda a: keys_of(a) == keys_of("ac"))
    out = {**tuning.record(), "evaluation_key": settings.key, "evaluation_seeds": n,
           "selection": "per task: most mean successes on the task; across tasks: highest mean over tasks of "
                        "successes / T (min–max on (0, T)); ties: the first setting in grid order",
           "algorithms": per_algo, "optimism": optimism, "conditions": conditions,
           "sensitivity": {**sens, "claim": claim(sens)},
           "head_to_head": head_to_head({"preset": preset, **samples}, trials)}
    if tuning.folder is not None:
        from jaxeac.experiments.tune_figures import SENSITIVITY_FIGURE, sensitivity_figure

        sensitivity_figure(out, trials, tuning.folder / SENSITIVITY_FIGURE)
        out["figure"] = SENSITIVITY_FIGURE
    return out


__all__ = ["CONDITIONS", "KEYS_OF", "RATES", "Tuning", "across_tasks", "keys_of", "parse_tune", "run_tuning",
           "tuned_markdown", "tuned_summary"]  # the report's sections, where study and the command line look
