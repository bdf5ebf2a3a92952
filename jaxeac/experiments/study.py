"""Beyond the paper's grid: every task × every algorithm, compared with AC (`jaxeac study`, X4).

(Over 400 lines: the study end to end: tasks, one-pass statistics, timeline, report; how the tasks
run side by side, with E8 beside them, is `jaxeac.experiments.study_runs`.)

Each task (a registered environment, `jaxeac.registered()`, optionally with a slip
probability) runs every algorithm — AC, EAC, EAC's ablations and the value-based
baselines Q-learning and SARSA (X3) — over the same seeds, with one fixed setting of the
step sizes for all tasks (the paper preset's, G6; ε for the baselines), and C the task's
own episode limit. The declared family of comparisons is every algorithm other than AC
against AC on every task; Holm (1979) adjusts Welch's p across that whole family.
Per comparison: mean successes of 200 trials (the primary measure, SPEC §6) with a BCa
CI, the difference from AC with a BCa CI, Hedges' g, the IQM and the probability of
improvement (`TaskStatistics`). Results are what the run found.

Fixed costs are paid once per study, not per task: a finite task's tables are inputs of its
compiled programs (`jaxeac.envs.tabular.TableLayout`, C among them), padded to the largest task of
its group (tasks with the same actions and r̃ rule: every default task), so one program per
algorithm serves every task of the group (the run's and E8's); the figure is one, a panel per
task drawn as the task ends (`StudyFigure`). On accelerators several tasks run side by side
(`jaxeac.experiments.study_runs`; tasks of one group share each program, compiled by the first to
need it), E8's programs compile ahead of the runs (on GPUs in a helper process), and a tuned
study's tuning runs start with the study's and its evaluation runs beside the statistics
(`jaxeac.experiments.tune_runs`).

A task's run folder is kept under ``tasks/`` (its results.parquet streamed a chunk at a time)
and reused by a rerun with the same settings, so a study killed midway resumes where it
stopped. Of each task only its per-seed successes (int32 [N] per algorithm) stay in memory; the
statistics of every task and the aggregate across tasks are one pass of the statistics engine
(`TaskStatistics`) that takes each task as its runs end.
``study.json`` (with a ``timeline``: where the time went, per task and phase), ``report.md`` and
``fig_study.png`` are written when every task is done.
"""

from __future__ import annotations

import dataclasses
import functools
import sys
import threading
import time
from collections.abc import Callable
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from jaxeac.algorithm.config import ALGORITHMS, BASELINES
from jaxeac.errors import UsageError
from jaxeac.experiments.common import check_algos, check_key, check_positive_int, finished_run, plain_json
from jaxeac.experiments.grid import GridSettings
from jaxeac.experiments.study_figure import STUDY_FIGURE, StudyFigure
from jaxeac.experiments.study_runs import (
    TaskRunner,
    Timeline,
    as_they_end,
    side_by_side,
    start_tasks,
    task_folder,
)
from jaxeac.running.threads import in_background

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

    name, colon, option = text.partition(":")
    slip = 0.0
    if colon and not option:
        raise UsageError(f"task {text!r}: nothing after ':'; write NAME or NAME:slip=P (e.g. grid-paper-v0:slip=0.1)")
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
            try:
                parse_task(task)
            except UsageError as exc:
                raise UsageError(f"--tasks: {exc}") from None
        seen: dict = {}
        for task in self.tasks:  # `T`, `T:slip=0` and `T:slip=0.0` are one task
            if (same := seen.setdefault(parse_task(task), task)) != task or list(self.tasks).count(task) > 1:
                raise UsageError(f"--tasks names one task twice ({same!r} and {task!r}); list each once")
        try:
            check_algos(self.algos)
        except UsageError as exc:  # the message names the flag, as every other refusal here
            raise UsageError(str(exc) if str(exc).startswith("--algos") else f"--algos: {exc}") from None
        if "ac" not in self.algos:
            raise UsageError("a study compares every algorithm with ac: --algos must include ac")
        if len(set(self.algos)) < 2:
            raise UsageError(f"--algos {' '.join(self.algos)}: a study compares algorithms with ac; "
                             "name ac and at least one other (e.g. --algos ac eac)")
        check_positive_int("seeds", self.seeds)
        if self.seeds < 2:
            raise UsageError(f"--seeds {self.seeds}: a comparison needs at least 2 seeds per algorithm "
                             "(e.g. --seeds 100)")
        check_positive_int("resamples", self.resamples)
        from jaxeac.stats.engine import check_resamples

        check_resamples(self.resamples, 0.95)  # too few for the CIs: refused here, not after the runs
        check_key(self.key)
        self.task_settings(self.tasks[0])  # rates and sizes checked once, as a task will use them

    def task_settings(self, task: str) -> GridSettings:
        name, slip = parse_task(task)
        return GridSettings(env=name, slip=slip, algos=tuple(self.algos), seeds=self.seeds,
                            trials=self.trials, key=self.key, epsilon=self.epsilon,
                            chunk_size=self.chunk_size, lanes=self.lanes).resolved()


@dataclasses.dataclass(frozen=True)
class _TaskSettings(GridSettings):
    """A study task's `GridSettings` (the same fields, so its run folder's config is a plain grid
    run's) whose environment is the task's tables padded to its group's layout (`task_envs`)."""

    def make_env(self):
        return self.__dict__.get("_env") or GridSettings.make_env(self)

    @classmethod
    def of(cls, grid: GridSettings, env) -> _TaskSettings:
        out = cls(**{f.name: getattr(grid, f.name) for f in dataclasses.fields(GridSettings)})
        object.__setattr__(out, "_env", env)
        return out


def task_envs(grids: dict[str, GridSettings]) -> dict:
    """Each task's environment, its tables padded to the `TableLayout` covering every task with its
    actions and r̃ rule, whatever its C (the paper grid as its table, `grid_task`: the same runs), so
    one compiled program per algorithm serves all of them. Environments without tables are left as
    they are."""
    from jaxeac.envs.grid import GridWorld
    from jaxeac.envs.tabular import TableLayout, TabularEnv
    from jaxeac.envs.tasks import grid_task

    envs = {}
    for task, grid in grids.items():
        env = grid.make_env()
        if isinstance(env, GridWorld):
            env = TabularEnv(grid_task(env.map, env.n_chances, name=grid.env))
        envs[task] = env
    groups: dict = {}
    for task, env in envs.items():
        if isinstance(env, TabularEnv):
            groups.setdefault((env.n_actions, env.rtilde_rule), []).append(task)
    for tasks in groups.values():
        layout = TableLayout.covering([envs[t] for t in tasks])
        for t in tasks:
            envs[t] = envs[t].padded(layout)
    return envs


def study_tasks(settings: StudySettings, out: str | Path, grids: dict | None = None, envs: dict | None = None
                ) -> tuple[dict, dict]:
    """({task: its run's settings}, those of the tasks whose folder in `out` is not finished with
    them): what `run_study` runs. `grids` and `envs`: `settings`'s tasks' and `task_envs`, if known."""
    grids = grids or {task: settings.task_settings(task) for task in settings.tasks}
    envs = envs or task_envs(grids)
    tasks = {task: _TaskSettings.of(grids[task], envs[task]) for task in settings.tasks}
    todo = {t: g for t, g in tasks.items()
            if not finished_run(task_folder(Path(out), t), plain_json(dataclasses.asdict(g)))}
    return tasks, todo


def _said(tl: Timeline, progress: bool):
    """`tl.phase` of the study's, with a progress line as each ends (a study stopped midway says
    where it got)."""
    @contextmanager
    def phase(name: str):
        t0 = time.perf_counter()
        with tl.phase(name):
            yield
        if progress:
            seconds = time.perf_counter() - t0
            print(f"study: {name.replace('_', ' ')} done in {seconds:.1f} s", file=sys.stderr, flush=True)

    return phase


def timeline_text(tl: dict) -> str:
    """study.json's ``timeline`` as lines for a terminal (`jaxeac study --timeline`)."""
    keys = list(tl["tasks_summed"])
    width = max([len("all tasks"), *(len(t) for t in tl["tasks"])])
    cells = [max(7, len(k)) for k in keys]
    lines = [f"timeline (wall s; {tl['total_s']:.1f} s in all)",
             "  ".join(["task".ljust(width), *(k.rjust(c) for k, c in zip(keys, cells, strict=True))])]
    for task, p in [*tl["tasks"].items(), ("all tasks", tl["tasks_summed"])]:
        lines.append("  ".join([task.ljust(width), *(f"{p.get(k, 0.0):.2f}".rjust(c)
                                                     for k, c in zip(keys, cells, strict=True))]))
    lines.append("study: " + ", ".join(f"{k} {v:.2f}" for k, v in tl["study"].items()))
    return "\n".join(lines)


def run_study(settings: StudySettings, out: str | Path, *, progress: bool = True,
              on_task: Callable[[str, dict], None] | None = None, tuning=None,
              timeline: bool = False, helper=None) -> dict:
    """Run (or reuse) every task's run folder, compare, and write study.json, report.md, the figure;
    with a `jaxeac.experiments.tune.Tuning`, also tune and evaluate at the selections (``tuning``).

    On accelerators each task's E8 diagnostics run beside the runs and its folder is finished (its
    summary.json) when they are in, while later tasks run (on GPUs in a helper process that has every
    task's E8 from its start and also draws the figure: `helper`, one started earlier by
    `jaxeac.experiments.study_runs.diagnostics_helper`, which the study then owns); the statistics of
    all tasks are one pass (`TaskStatistics`), each task's from when its successes are in."""
    from jaxeac.experiments.tune import run_tuning
    from jaxeac.io import atomic_write_bytes, atomic_write_json, atomic_write_text, staged_dir
    from jaxeac.stats.cumulative import cumulative_counts

    settings.validate()
    out = Path(out)
    from tqdm import tqdm

    tl = Timeline()
    said = _said(tl, progress)
    with tl.phase("setup"):
        grids = {task: settings.task_settings(task) for task in settings.tasks}
        envs = task_envs(grids)
        tasks, todo = study_tasks(settings, out, grids, envs)
    kept = {}
    n = len(settings.tasks)
    side = side_by_side(todo)
    tuned = None
    if tuning is not None and side:  # the tuning's runs beside the study's: the device has room
        from jaxeac.experiments.tune import tuning_runs

        tuner = tuning_runs(settings, tuning, grids, envs, progress=progress)
        tuned = in_background(tuner.tune, "jaxeac-study")
    first = grids[settings.tasks[0]]
    stats = TaskStatistics(settings.tasks, first.algos, settings.seeds, first.trials, resamples=settings.resamples,
                           key=settings.key)
    timed = functools.partial(_timed, tl, "figure")
    with (TaskRunner(todo, tl, helper) as runner, _stopped_on_error(stats),
          StudyFigure(settings.tasks, settings.seeds, timed, helper=runner.helper) as figure):
        ahead = start_tasks(runner, todo, out, side, progress)
        for task in as_they_end(list(tasks), ahead):  # a task's statistics start as soon as its runs end
            i, grid, folder = settings.tasks.index(task), tasks[task], task_folder(out, task)
            if task not in todo:
                if progress:
                    print(f"study: task {i + 1}/{n} {task}: done earlier, reusing {folder}", file=sys.stderr,
                          flush=True)
                with tl.phase("load", task):
                    success, samples = _successes(folder, grid)
            else:
                if task in ahead:
                    results = ahead[task].result()
                else:
                    desc = f"study: task {i + 1}/{n} {task} ({len(grid.algos)} algorithms)"
                    with tqdm(total=len(grid.algos) * grid.seeds, unit="seed", disable=not progress,
                              file=sys.stderr, desc=desc) as bar:
                        results = runner.run(task, grid, folder, bar.update)
                success = {a: r.success for a, r in results.items()}
                samples = {a: np.asarray(r.successes) for a, r in results.items()}
                del results
                ahead.pop(task, None)
            # One task's success curves in memory at a time: its panel is drawn from their counts.
            with tl.phase("curves", task):
                figure.add(task, {a: cumulative_counts(success[a]) for a in grid.algos})
            del success
            kept[task] = {a: x.astype(np.int32) for a, x in samples.items()}  # per-seed successes, all tasks
            stats.add(task, kept[task])  # its statistics start, beside the later tasks' runs
            if timeline:  # as each task ends: a study stopped midway still shows where its time went
                phases = ", ".join(f"{k} {v:.2f} s" for k, v in tl.tasks[task].items())
                print(f"study: timeline {task}: {phases}", file=sys.stderr, flush=True)
        kept = {task: kept[task] for task in settings.tasks}  # in the study's order again
        evaluated = None
        if tuned is not None:  # the evaluation runs beside the statistics (tuning runs done or nearly)
            from jaxeac.experiments.tune import select

            algos = list(settings.algos)
            evaluated = in_background(lambda: tuner.evaluate(
                select(tuning, tuned.result(), list(tasks), algos, first.trials), kept), "jaxeac-evaluation")
        png = figure.finish()  # the legend and the PNG, beside the statistics
        runner.release_helper(png)  # every job has gone to the helper: it ends once they are done
        with said("statistics"):  # the last tasks' and the aggregate, while the last diagnostics finish
            per_task, rows, aggregate = stats.result()
        with said("diagnostics_wait"):
            runner.finish()
        with tl.phase("figure_wait"):  # before the runner's helper, which may draw it, is closed
            png = png.result()
    for task, info in per_task.items():
        g = grids[task]
        per_task[task] = {"env": g.env, "slip": g.slip, "chances": g.chances, "trials": g.trials, **info}
        if on_task is not None:
            on_task(task, per_task[task])
    result = {
        "family": "every algorithm but ac against ac, on every task; Holm across all of them",
        "comparisons_in_family": len(rows), "seeds": settings.seeds, "key": settings.key,
        "resamples": settings.resamples,
        "rates": {"alpha": first.alpha, "beta": first.beta, "gamma": first.gamma,
                  "temperature": first.temperature, "epsilon": first.epsilon, "trials": first.trials},
        "tasks": per_task, "comparisons": rows,
        "aggregate": aggregate,
    }
    if tuning is not None:
        with said("tuning"):
            result["tuning"] = run_tuning(settings, tuning, grids, envs, kept, result, progress=progress,
                                          runs=tuner if tuned else None, scores=tuned, samples=evaluated,
                                          phase=said)
    with staged_dir(out, replaces=("study.json", "report.md", "fig_*.png")) as stage:
        atomic_write_bytes(stage / STUDY_FIGURE, png)
        result["figures"] = {task: STUDY_FIGURE for task in settings.tasks}
        result["timeline"] = tl.record()  # writing study.json itself is the one phase left out
        atomic_write_json(stage / "study.json", result)
        atomic_write_text(stage / "report.md", report_markdown(result))
    return result


@contextmanager
def _stopped_on_error(stats: TaskStatistics):
    """Stop `stats`' pass if the block fails (its threads wait for tasks that will not come)."""
    try:
        yield
    except BaseException:
        stats.stop()
        raise


def _timed(tl: Timeline, phase: str, work: Callable, *args):
    with tl.phase(phase):
        return work(*args)


class TaskStatistics:
    """Every task's statistics and the aggregate across tasks: one pass of the statistics engine
    (`jaxeac.stats.core.compare_as_tasks_end`, with the settings of
    `jaxeac.experiments.tune.across_tasks`, so the aggregate is that function's, bit for bit) that
    starts with the study and takes each task's per-seed successes as they come (`add`, in any
    order): a task's statistics run as soon as its runs end, beside the later tasks' runs.
    `result` waits for the pass; `stop` ends it unfinished (a study stopped midway)."""

    def __init__(self, tasks, algos, n: int, trials: int, *, resamples: int, key: int):
        from jaxeac.perseed import PerSeed
        from jaxeac.stats.core import compare_as_tasks_end

        self.key, self.n_tasks, self.stopped = key, len(tasks), False
        self.arrived = {t: threading.Event() for t in tasks}
        values = {t: {a: np.empty(n, np.float64) for a in algos} for t in tasks}  # filled by `add`
        seeds = {t: {a: _seed_ids(n) for a in algos} for t in tasks}
        self.per = PerSeed(values, seeds, "successes per seed over the trials", "study")
        self.future = in_background(functools.partial(
            compare_as_tasks_end, self.per, ready=self._ready, baseline="ac", level=0.95, resamples=resamples,
            key=key, normalize="minmax", reference_scores={t: (0.0, float(trials)) for t in tasks},
            profile_points=min(trials + 1, 101)), "jaxeac-statistics")

    def _ready(self, task: str) -> None:
        self.arrived[task].wait()
        if self.stopped:
            raise RuntimeError("study stopped before its statistics")

    def add(self, task: str, samples: dict[str, np.ndarray]) -> None:
        """Task `task`'s per-seed successes {algo: int [N]}: its statistics may start."""
        for a, x in samples.items():
            self.per.values[task][a][:] = x
        self.arrived[task].set()

    def stop(self) -> None:
        self.stopped = True
        for event in self.arrived.values():
            event.set()

    def result(self) -> tuple[dict, list[dict], dict | None]:
        """({task: {"algorithms": {algo: n, mean, iqm, iqm_ci95}}}, the rows (each algorithm but ac
        against ac per task: difference of means with a BCa CI, Welch's p, Hedges' g, IQMs,
        P(X > ac); ``p_holm``: Holm over Welch's p of every row), the aggregate or None for one task)."""
        res = self.future.result()
        per_task: dict = {t: {"algorithms": {}} for t in res.tasks}
        for a in res.algorithms:
            per_task[a["task"]]["algorithms"][a["algo"]] = {"n": a["n"], "mean": a["mean"], "iqm": a["iqm"],
                                                            "iqm_ci95": a["iqm_ci"]}
        rows = []
        for r in res.rows:
            ax, ay = per_task[r["task"]]["algorithms"][r["x"]], per_task[r["task"]]["algorithms"][r["y"]]
            rows.append({"task": r["task"], "x": r["x"], "y": r["y"], "n_x": r["n_x"], "n_y": r["n_y"],
                         "mean_x": r["mean_x"], "mean_y": r["mean_y"], "diff": r["diff"],
                         "diff_ci95": r["diff_ci"], "p_welch": r["p_welch"], "hedges_g": r["hedges_g"],
                         "iqm_x": ax["iqm"], "iqm_x_ci95": ax["iqm_ci95"], "iqm_y": ay["iqm"],
                         "iqm_y_ci95": ay["iqm_ci95"], "p_improvement": r["p_improvement"],
                         "p_improvement_ci95": r["p_improvement_ci"], "p_holm": r["p_welch_holm"]})
        agg = res.aggregate
        if self.n_tasks < 2:
            agg = None
        elif agg is not None:
            agg["reference_why"] = ("min–max with the stated references (0, T) on every task: successes per seed "
                                    "lie in [0, T], a scale fixed before any run and the same for every algorithm")
            agg["key"] = self.key
        return per_task, rows, agg


@functools.lru_cache(maxsize=4)
def _seed_ids(n: int) -> np.ndarray:
    """Seeds 0 … n − 1 as the strings `across_tasks` names them (``np.arange(n).astype(str)``: the same
    values, so the same order and draws) in the narrowest width, one array shared by every algorithm
    and task of n seeds: at 100,000 seeds × 88 runs, 2 MiB instead of 740 MiB of '<U21'."""
    ids = np.arange(n).astype(f"<U{len(str(max(n - 1, 0)))}")
    ids.flags.writeable = False
    return ids


def _successes(folder: Path, grid: GridSettings) -> tuple[dict, dict[str, np.ndarray]]:
    """A finished task folder's ({algo: `SuccessBits` [N, T]}, {algo: successes per seed [N]})."""
    from jaxeac.results import load_grid_results

    loaded = load_grid_results(folder, grid.algos, grid.trials, compact=True)
    return ({a: loaded[a].success for a in grid.algos},
            {a: np.asarray(loaded[a].successes) for a in grid.algos})


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
    figure = next(iter(result["figures"].values()), None)
    if figure:
        lines += [f"![every task: cumulative successes per trial]({figure})", ""]
    for task, info in result["tasks"].items():
        algos = info["algorithms"]
        lines += [f"## {task}", "", f"C = {info['chances']} chances per trial.",
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
    if result.get("aggregate"):
        lines += across_markdown(result["aggregate"])
    if result.get("tuning"):
        from jaxeac.experiments.tune import tuned_markdown

        lines += tuned_markdown(result["tuning"])
    return "\n".join(lines)


def across_markdown(agg: dict, title: str = "Across tasks") -> list[str]:
    """The report's section on the aggregate across tasks (`across_tasks`)."""
    def cell(m):
        return f"{m['estimate']:.3f} [{m['ci'][0]:.3f}, {m['ci'][1]:.3f}]"

    pairs = {r["x"]: r for r in agg["pairs"]}
    base = agg["pairs"][0]["y"] if agg["pairs"] else "ac"
    lines = [f"## {title}", "", f"{len(agg['tasks'])} tasks; scores {agg['normalization']['text']} (0, T): "
             f"{agg['reference_why']}. {agg['method']}", "",
             f"| algorithm | IQM [95% CI] | mean [95% CI] | median [95% CI] | optimality gap [95% CI] "
             f"| P(> {base}) over tasks [95% CI] |", "|---|---|---|---|---|---|"]
    for a, m in agg["algorithms"].items():
        pi = cell(pairs[a]) if a in pairs else ""
        lines.append(f"| {a} | {cell(m['iqm'])} | {cell(m['mean'])} | {cell(m['median'])} "
                     f"| {cell(m['optimality_gap'])} | {pi} |")
    return [*lines, ""]


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
