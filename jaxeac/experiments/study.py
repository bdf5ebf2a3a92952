"""Beyond the paper's grid: every task × every algorithm, compared with AC (`jaxeac study`, X4).

Each task (a registered environment, `jaxeac.registered()`, optionally with a slip
probability) runs every algorithm — AC, EAC, EAC's ablations and the value-based
baselines Q-learning and SARSA (X3) — over the same seeds, with one fixed setting of the
step sizes for all tasks (the paper preset's, G6; ε for the baselines), and C the task's
own episode limit. The declared family of comparisons is every algorithm other than AC
against AC on every task; Holm (1979) adjusts Welch's p across that whole family.
Per comparison: mean successes of 200 trials (the primary measure, SPEC §6) with a BCa
CI, the difference from AC with a BCa CI, Hedges' g, the IQM and the probability of
improvement (`jaxeac.stats.tidy.compare_samples`). Results are what the run found.

A task's run folder is kept under ``tasks/`` and reused by a rerun with the same settings,
so a study killed midway resumes where it stopped; ``study.json``, ``report.md`` and one
figure per task (``fig_<task>.png``) are written when every task is done.
"""

from __future__ import annotations

import dataclasses
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

from jaxeac.algorithm.config import ALGORITHMS, BASELINES
from jaxeac.errors import UsageError
from jaxeac.experiments.common import check_algos, check_key, check_positive_int, finished_run, plain_json
from jaxeac.experiments.grid import GridSettings

#: The tasks of a full study: the classic tabular tasks, the paper's grid, and the grid made slippery.
DEFAULT_TASKS = (
    "grid-paper-v0", "grid-paper-v0:slip=0.1", "FrozenLake-4x4-v1", "FrozenLake-4x4-slippery-v1",
    "FrozenLake-8x8-v1", "FrozenLake-8x8-slippery-v1", "CliffWalking-v1", "WindyGridworld-v0",
    "WindyGridworld-stochastic-v0", "FourRooms-v0", "FourRooms-stochastic-v0",
)
DEFAULT_ALGOS = (*ALGORITHMS, *BASELINES)


def parse_task(text: str) -> tuple[str, float]:
    """``NAME`` or ``NAME:slip=P`` → (name, slip); bad forms and unknown names are `UsageError`s."""
    from jaxeac.envs import registered

    name, _, option = text.partition(":")
    slip = 0.0
    if option:
        key, _, value = option.partition("=")
        if key != "slip" or not value:
            raise UsageError(f"task {text!r}: write NAME or NAME:slip=P (e.g. grid-paper-v0:slip=0.1)")
        try:
            slip = float(value)
        except ValueError:
            raise UsageError(f"task {text!r}: cannot read {value!r} as a probability") from None
        if not 0.0 <= slip <= 1.0:
            raise UsageError(f"task {text!r}: slip must lie in [0, 1] (got {slip:g})")
    if name not in registered():
        raise UsageError(f"unknown environment {name!r}; choose one of {', '.join(registered())}")
    return name, slip


@dataclasses.dataclass(frozen=True)
class StudySettings:
    """What a study runs: tasks (``NAME`` or ``NAME:slip=P``), algorithms, seeds and one setting
    of the rates for every task (None: the preset's)."""

    tasks: tuple[str, ...] = DEFAULT_TASKS
    algos: tuple[str, ...] = DEFAULT_ALGOS
    seeds: int = 10_000
    trials: int | None = None
    key: int = 0
    epsilon: float = 0.1
    resamples: int = 10_000
    chunk_size: int | None = None
    lanes: int | None = None  # seeds in flight per device (RunConfig.lanes); None: automatic

    def validate(self) -> None:
        if not self.tasks:
            raise UsageError("no tasks; name at least one (see `jaxeac.registered()`)")
        for task in self.tasks:
            parse_task(task)
        if len(set(self.tasks)) != len(self.tasks):
            raise UsageError("a task is listed twice; list each once")
        check_algos(self.algos)
        if "ac" not in self.algos:
            raise UsageError("a study compares every algorithm with ac: --algos must include ac")
        check_positive_int("seeds", self.seeds)
        check_positive_int("resamples", self.resamples)
        check_key(self.key)
        self.task_settings(self.tasks[0])  # rates and sizes checked once, as a task will use them

    def task_settings(self, task: str) -> GridSettings:
        name, slip = parse_task(task)
        return GridSettings(env=name, slip=slip, algos=tuple(self.algos), seeds=self.seeds, trials=self.trials,
                            key=self.key, epsilon=self.epsilon, chunk_size=self.chunk_size,
                            lanes=self.lanes).resolved()


def folder_name(task: str) -> str:
    """A task's folder under ``tasks/``: its name, ``:slip=P`` as ``-slipP``."""
    return task.replace(":slip=", "-slip")


def run_study(settings: StudySettings, out: str | Path, *, progress: bool = True,
              on_task: Callable[[str, dict], None] | None = None) -> dict:
    """Run (or reuse) every task's run folder, compare, and write study.json, report.md, figures."""
    from jaxeac import plots
    from jaxeac.experiments.grid import run_grid_to_folder
    from jaxeac.io import atomic_write_json, atomic_write_text, staged_dir
    from jaxeac.results import OutputOptions
    from jaxeac.stats import holm
    from jaxeac.stats.tidy import compare_samples

    settings.validate()
    out = Path(out)
    from tqdm import tqdm

    tasks = {}
    n = len(settings.tasks)
    for k, task in enumerate(settings.tasks, 1):
        grid = settings.task_settings(task)
        folder = out / "tasks" / folder_name(task)
        if finished_run(folder, plain_json(dataclasses.asdict(grid))):
            if progress:
                print(f"study: task {k}/{n} {task}: done earlier, reusing {folder}", file=sys.stderr,
                      flush=True)
        else:
            with tqdm(total=len(grid.algos) * grid.seeds, unit="seed", disable=not progress, file=sys.stderr,
                      desc=f"study: task {k}/{n} {task} ({len(grid.algos)} algorithms)") as bar:
                run_grid_to_folder(grid, folder, options=OutputOptions.auto(grid.seeds), figures=False,
                                   progress=bar.update)
        tasks[task] = (grid, _successes(folder, grid))
    rows, figures, per_task = [], {}, {}
    for i, (task, (grid, success)) in enumerate(tasks.items()):
        samples = {a: success[a].sum(axis=1) for a in grid.algos}
        stats = compare_samples(samples, baseline="ac", resamples=settings.resamples, key=settings.key + i)
        per_task[task] = {"env": grid.env, "slip": grid.slip, "chances": grid.chances, "trials": grid.trials,
                          "algorithms": stats["algorithms"]}
        for row in stats["comparisons"]:
            rows.append({"task": task, **{k: v for k, v in row.items() if k != "p_holm"}})
        if on_task is not None:
            on_task(task, per_task[task])
    for row, p in zip(rows, holm([r["p_welch"] for r in rows]) if rows else [], strict=True):
        row["p_holm"] = float(p)
    first = settings.task_settings(settings.tasks[0])
    result = {
        "family": "every algorithm but ac against ac, on every task; Holm across all of them",
        "comparisons_in_family": len(rows), "seeds": settings.seeds, "key": settings.key,
        "resamples": settings.resamples,
        "rates": {"alpha": first.alpha, "beta": first.beta, "gamma": first.gamma,
                  "temperature": first.temperature, "epsilon": first.epsilon, "trials": first.trials},
        "tasks": per_task, "comparisons": rows,
    }
    with staged_dir(out, replaces=("study.json", "report.md", "fig_*.png")) as stage:
        for task, (_, success) in tasks.items():
            name = f"fig_{folder_name(task)}.png"
            plots.cumulative_success_figure(success, stage / name)
            figures[task] = name
        result["figures"] = figures
        atomic_write_json(stage / "study.json", result)
        atomic_write_text(stage / "report.md", report_markdown(result))
    return result


def _successes(folder: Path, grid: GridSettings) -> dict[str, np.ndarray]:
    from jaxeac.results import load_grid_results

    loaded = load_grid_results(folder, grid.algos, grid.trials)
    return {a: np.asarray(loaded[a].success, bool) for a in grid.algos}


def report_markdown(result: dict) -> str:
    """The study's report: one table per task, every algorithm against AC."""
    r = result["rates"]
    lines = [
        "# AC, EAC, its ablations and value-based baselines on tabular tasks",
        "",
        f"{result['seeds']:,} seeds per algorithm and task, {r['trials']} trials each; the same rates on every "
        f"task (α = {r['alpha']:g}, β = {r['beta']:g}, γ = {r['gamma']:g}, τ = {r['temperature']:g}; "
        f"ε = {r['epsilon']:g} for Q-learning and SARSA); C = each task's own episode limit. Measure: "
        "successful trials per seed (of all trials). Family: " + result["family"] + f" "
        f"({result['comparisons_in_family']} comparisons). CIs: BCa, {result['resamples']:,} resamples.",
        "",
    ]
    by_task: dict[str, list[dict]] = {}
    for row in result["comparisons"]:
        by_task.setdefault(row["task"], []).append(row)
    for task, info in result["tasks"].items():
        algos = info["algorithms"]
        lines += [f"## {task}", "", f"C = {info['chances']} chances per trial. ![{task}]({result['figures'][task]})",
                  "", "| algorithm | mean successes | IQM [95% CI] | − AC [95% CI] | Hedges' g | P(> AC) | Holm p |",
                  "|---|---|---|---|---|---|---|"]
        ac = algos["ac"]
        lines.append(f"| ac | {ac['mean']:.2f} | {ac['iqm']:.2f} [{ac['iqm_ci95'][0]:.2f}, {ac['iqm_ci95'][1]:.2f}] "
                     "| | | | |")
        for row in by_task.get(task, []):
            a = algos[row["x"]]
            lo, hi = row["diff_ci95"]
            lines.append(
                f"| {row['x']} | {a['mean']:.2f} | {a['iqm']:.2f} [{a['iqm_ci95'][0]:.2f}, {a['iqm_ci95'][1]:.2f}] "
                f"| {row['diff']:+.2f} [{lo:+.2f}, {hi:+.2f}] | {row['hedges_g']:+.2f} | "
                f"{row['p_improvement']:.3f} | {_p(row['p_holm'])} |")
        lines.append("")
    return "\n".join(lines)


def summary_table(result: dict, *, level: float = 0.05) -> str:
    """The study at a glance, for a terminal: per task (rows) each algorithm's mean successes,
    marked + (better than AC) or − (worse) where its Holm-adjusted p is at most `level`."""
    algos = list(next(iter(result["tasks"].values()))["algorithms"])
    marks = {(r["task"], r["x"]): ("+" if r["diff"] > 0 else "−") if r["p_holm"] <= level else " "
             for r in result["comparisons"]}
    head = ["task", *algos]
    body = [[task, *(f"{info['algorithms'][a]['mean']:.1f}{marks.get((task, a), ' ')}" for a in algos)]
            for task, info in result["tasks"].items()]
    widths = [max(len(r[i]) for r in [head, *body]) for i in range(len(head))]
    lines = [f"mean successes per seed ({result['rates']['trials']} trials); + / −: better / worse than ac, "
             f"Holm-adjusted p ≤ {level:g} over {result['comparisons_in_family']} comparisons"]
    for i, r in enumerate([head, *body]):
        cells = (c.rjust(w) for c, w in zip(r[1:], widths[1:], strict=True))
        lines.append("  ".join([r[0].ljust(widths[0]), *cells]))
        if i == 0:
            lines.append("  ".join("-" * w for w in widths))
    return "\n".join(lines)


def _p(p: float) -> str:
    return "< 1e-16" if p < 1e-16 else f"{p:.2g}"
