"""`jaxeac study` (X4): every task × algorithm against AC, Holm across the family, resumable."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from jaxeac.cli import main
from jaxeac.experiments.study import StudySettings, parse_task, run_study
from jaxeac.stats import holm


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    out = tmp_path_factory.mktemp("study")
    settings = StudySettings(tasks=("FrozenLake-4x4-v1", "grid-paper7-v0:slip=0.2"), algos=("ac", "eac", "sarsa"),
                             seeds=40, trials=30, resamples=400)
    return out, settings, run_study(settings, out, progress=False)


def test_study_compares_every_algorithm_with_ac_and_holm_spans_the_family(study):
    out, settings, result = study
    rows = result["comparisons"]
    assert [(r["task"], r["x"], r["y"]) for r in rows] == [
        (t, a, "ac") for t in settings.tasks for a in ("eac", "sarsa")]
    np.testing.assert_allclose([r["p_holm"] for r in rows], holm([r["p_welch"] for r in rows]))
    assert result["comparisons_in_family"] == 4
    # the per-task numbers are those of the task's own run folder
    from jaxeac.results import load_grid_results

    loaded = load_grid_results(out / "tasks" / "FrozenLake-4x4-v1", ("ac", "eac"), 30)
    means = {a: float(loaded[a].successes.mean()) for a in ("ac", "eac")}
    assert result["tasks"]["FrozenLake-4x4-v1"]["algorithms"]["eac"]["mean"] == pytest.approx(means["eac"])
    assert rows[0]["diff"] == pytest.approx(means["eac"] - means["ac"])
    summary = json.loads((out / "tasks" / "grid-paper7-v0-slip0.2" / "summary.json").read_text())
    assert (summary["config"]["env"], summary["config"]["slip"], summary["config"]["chances"]) == (
        "grid-paper7-v0", 0.2, 40)
    report = (out / "report.md").read_text()
    assert "## FrozenLake-4x4-v1" in report and "| sarsa |" in report and "(4 comparisons)" in report
    assert (out / "fig_study.png").stat().st_size > 1000  # one figure, a panel per task
    assert "![every task: cumulative successes per trial](fig_study.png)" in report


def test_study_rerun_reuses_the_task_folders(study):
    out, settings, result = study
    stamp = (out / "tasks" / "FrozenLake-4x4-v1" / "results.parquet").stat().st_mtime_ns
    again = run_study(settings, out, progress=False)
    assert (out / "tasks" / "FrozenLake-4x4-v1" / "results.parquet").stat().st_mtime_ns == stamp
    assert again["timeline"]["tasks_summed"].get("run", 0.0) == 0.0  # nothing run again
    same = [{k: v for k, v in r.items() if k != "timeline"} for r in (again, result)]
    assert json.dumps(same[0], sort_keys=True) == json.dumps(same[1], sort_keys=True)


def test_study_keeps_a_timeline_per_task_and_phase(study):
    out, settings, result = study
    assert "timeline" in json.loads((out / "study.json").read_text())
    tl = result["timeline"]
    assert list(tl["tasks"]) == list(settings.tasks)
    for phases in tl["tasks"].values():
        assert {"run", "compile", "device_run", "finish", "curves"} <= set(phases)
    assert {"statistics", "figure"} <= set(tl["study"]) and tl["total_s"] > 0
    from jaxeac.experiments.study import timeline_text

    text = timeline_text(tl)
    assert "all tasks" in text and "FrozenLake-4x4-v1" in text


def test_parse_task():
    assert parse_task("grid-paper-v0:slip=0.25") == ("grid-paper-v0", 0.25)
    assert parse_task("CliffWalking-v1") == ("CliffWalking-v1", 0.0)


def test_study_command_refuses_another_kind_of_folder(tmp_path, capsys):
    (tmp_path / "summary.json").write_text("{}")
    assert main(["study", "--tasks", "FrozenLake-4x4-v1", "--out", str(tmp_path), "--quiet"]) == 2
    assert "holds a grid or bowling run" in capsys.readouterr().err


def test_study_summary_across_tasks(study):
    from jaxeac.experiments.study import summary_table

    out, settings, result = study
    lines = summary_table(result).splitlines()
    assert "Holm-adjusted p ≤ 0.05 over 4 comparisons" in lines[0]
    assert lines[1].split() == ["task", "ac", "eac", "sarsa"]
    rows = {ln.split()[0]: ln.split()[1:] for ln in lines[3:]}
    assert set(rows) == set(settings.tasks)
    for row in result["comparisons"]:
        cell = rows[row["task"]][["ac", "eac", "sarsa"].index(row["x"])]
        assert cell.startswith(f"{result['tasks'][row['task']]['algorithms'][row['x']]['mean']:.1f}")
        assert cell.endswith("+") == (row["p_holm"] <= 0.05 and row["diff"] > 0)


def test_study_command_shows_progress_within_a_task_and_a_summary(tmp_path, capsys):
    assert main(["study", "--tasks", "FrozenLake-4x4-v1", "--algos", "ac", "eac", "--seeds", "16", "--trials",
                 "10", "--resamples", "400", "--timeline", "--out", str(tmp_path / "s")]) == 0
    captured = capsys.readouterr()
    assert "study: timeline FrozenLake-4x4-v1: run" in captured.err and "timeline (wall s;" in captured.out
    assert "study: task 1/1 FrozenLake-4x4-v1 (2 algorithms)" in captured.err and "32/32" in captured.err
    assert "mean successes per seed (10 trials)" in captured.out and "FrozenLake-4x4-v1" in captured.out


def test_study_compiles_one_program_per_algorithm_for_tasks_of_one_chance_budget(tmp_path, monkeypatch):
    """Three tasks with C = 100 (a deterministic one, a stochastic one, a larger one): each algorithm's
    run compiles once and E8's trials loop of eac once, for all three tasks (tables as inputs)."""
    from jaxeac.running import batch, diagnostics

    built, diagnosed = [], []
    make_batch_run, keyed = batch.make_batch_run, diagnostics._keyed_program
    monkeypatch.setattr(batch, "make_batch_run", lambda *a, **k: built.append(a[1].agent) or make_batch_run(*a, **k))
    monkeypatch.setattr(diagnostics, "_keyed_program",
                        lambda key, *a: (key in [d[0] for d in diagnosed] or diagnosed.append((key, a[1]))) and False
                        or keyed(key, *a))
    batch._COMPILED.clear()
    diagnostics._PROGRAMS.clear()
    settings = StudySettings(tasks=("FrozenLake-4x4-v1", "FrozenLake-4x4-slippery-v1", "CliffWalking-v1"),
                             algos=("ac", "eac"), seeds=8, trials=10, resamples=400)
    result = run_study(settings, tmp_path, progress=False)
    assert len(built) == 2 and len(diagnosed) == 1
    assert result["comparisons_in_family"] == 3
    for task in settings.tasks:  # each task's folder: its own states' policies, its own config
        summary = json.loads((tmp_path / "tasks" / task / "summary.json").read_text())
        assert summary["config"]["env"] == task and "memory_diagnostics" in summary


def test_study_aggregates_across_tasks_min_max_on_zero_to_t(study):
    out, settings, result = study
    agg = result["aggregate"]
    assert agg["tasks"] == list(settings.tasks)
    assert agg["normalization"]["method"] == "minmax"
    assert agg["normalization"]["reference"] == {t: [0.0, 30.0] for t in settings.tasks}
    # the point estimates are rliable's on the per-seed successes / T
    means = [result["tasks"][t]["algorithms"]["eac"]["mean"] / 30 for t in settings.tasks]
    assert agg["algorithms"]["eac"]["mean"]["estimate"] == pytest.approx(np.mean(means))
    for a in settings.algos:
        m = agg["algorithms"][a]
        for k in ("iqm", "mean", "median", "optimality_gap"):
            lo, hi = m[k]["ci"]
            assert lo <= m[k]["estimate"] + 1e-12 and m[k]["estimate"] <= hi + 1e-12
        assert m["optimality_gap"]["estimate"] == pytest.approx(1 - m["mean"]["estimate"])  # scores ≤ 1
    pairs = {(r["x"], r["y"]): r for r in agg["pairs"]}
    assert set(pairs) == {("eac", "ac"), ("sarsa", "ac")}
    assert 0 <= pairs["eac", "ac"]["estimate"] <= 1
    report = (out / "report.md").read_text()
    assert "## Across tasks" in report and "| eac |" in report.split("## Across tasks")[1]
    assert "P(> ac) over tasks" in report


def test_one_task_study_has_no_aggregate(tmp_path):
    settings = StudySettings(tasks=("FrozenLake-4x4-v1",), algos=("ac", "eac"), seeds=8, trials=10, resamples=400)
    result = run_study(settings, tmp_path, progress=False)
    assert result["aggregate"] is None and "## Across tasks" not in (tmp_path / "report.md").read_text()


def test_diagnostics_beside_the_runs_give_the_same_folders(tmp_path, monkeypatch, capsys):
    """Where E8 goes beside the runs (accelerators), every task's diagnostics start with the study and
    its folder is finished when they are in, on threads or in a helper process (GPUs): the same
    summaries and statistics as one task at a time; a helper that dies midway leaves its tasks' E8 to
    the study's own process, with a line saying so."""
    from jaxeac.experiments import grid, study_runs
    from jaxeac.running import helper

    class DiesAtItsFirstTask(helper.Helper):
        def submit(self, fn, /, *args, **kwargs):
            future = super().submit(fn, *args, **kwargs)
            if fn is grid.diagnose_grid:
                self.kill()
            return future

    settings = StudySettings(tasks=("FrozenLake-4x4-v1", "CliffWalking-v1"), algos=("ac", "eac"), seeds=8,
                             trials=10, resamples=400)
    results = {}
    for how in ("after", "threads", "helper", "helper_dies"):
        monkeypatch.setitem(grid.DIAGNOSE_BESIDE_THE_RUN, "cpu", how != "after")
        monkeypatch.setitem(study_runs.DIAGNOSE_IN_HELPER, "cpu", how.startswith("helper"))
        monkeypatch.setattr(helper, "Helper", DiesAtItsFirstTask if how == "helper_dies" else helper.Helper)
        capsys.readouterr()
        results[how] = run_study(settings, tmp_path / how, progress=False)
        results[how, "stderr"] = capsys.readouterr().err
        for task in settings.tasks:
            summary = json.loads((tmp_path / how / "tasks" / task / "summary.json").read_text())
            assert summary["memory_diagnostics"]["eac"]["successes_match_run"]
            results[how, task] = summary["memory_diagnostics"]
    assert "finish" not in results["threads"]["timeline"]["tasks"][settings.tasks[0]]
    assert 0 < results["helper"]["timeline"]["helper_peak_rss_gib"] < 4
    assert "helper_peak_rss_gib" not in results["threads"]["timeline"]
    assert "counting its E8 diagnostics in this process" in results["helper_dies", "stderr"]
    assert "counting" not in results["helper", "stderr"]
    png = (tmp_path / "after" / "fig_study.png").read_bytes()
    for how in ("threads", "helper", "helper_dies"):
        for task in settings.tasks:
            assert results[how, task] == results["after", task]
        assert results[how]["comparisons"] == results["after"]["comparisons"]
        assert (tmp_path / how / "fig_study.png").read_bytes() == png  # drawn here, or by the helper


@pytest.mark.parametrize("argv, match", [
    (["--tasks", "FrozenLake-4x4-v1:slip=abc"], "--tasks: task 'FrozenLake-4x4-v1:slip=abc': cannot read 'abc'"),
    (["--tasks", "FrozenLake-4x4-v1:slip"], "--tasks: task 'FrozenLake-4x4-v1:slip': write NAME or NAME:slip=P"),
    (["--tasks", "FrozenLake-4x4-v1:=0.1"], "--tasks: task 'FrozenLake-4x4-v1:=0.1': write NAME"),
    (["--tasks", "CliffWalking-v1:slip=0", "CliffWalking-v1:slip=0.0"], "--tasks names one task twice"),
    (["--algos", "ac", "ac"], "--algos: algos lists an algorithm twice (ac ac)"),
    (["--algos", "ac"], "--algos ac: a study compares algorithms with ac"),
    (["--seeds", "1"], "--seeds 1: a comparison needs at least 2 seeds"),
])
def test_study_refuses_before_any_compute(tmp_path, capsys, argv, match):
    """One `error:` line naming the flag, exit 2, and nothing run or written."""
    assert main(["study", "--seeds", "4", *argv, "--out", str(tmp_path / "s")]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and match in err[0], err
    assert not (tmp_path / "s").exists()


def test_study_checks_sizes_on_the_runs_own_environments(tmp_path, monkeypatch):
    """The up-front size check sees each task's environment as its runs will (tables padded to the
    layout of its group, `task_envs`), so tasks of one layout share every answer resolved there
    (on GPUs the fused kernel's probe: 32 for the 11 default tasks instead of 88)."""
    from jaxeac.experiments import common, study
    from jaxeac.running.loops import program_key

    seen = {}
    monkeypatch.setattr(common, "check_grid_resources", lambda grid, env: seen.setdefault(grid.env, env))

    def stop(*args, **kwargs):
        raise KeyboardInterrupt  # the check is done: no compute

    monkeypatch.setattr(study, "run_study", stop)
    tasks = ["FrozenLake-4x4-v1", "FrozenLake-4x4-slippery-v1", "CliffWalking-v1"]
    assert main(["study", "--tasks", *tasks, "--seeds", "4", "--out", str(tmp_path / "s"), "--quiet"]) == 130
    settings = StudySettings(tasks=tuple(tasks), algos=("ac", "eac"), seeds=4)
    want = study.task_envs({t: settings.task_settings(t) for t in tasks})
    assert {program_key(seen[t]) for t in tasks} == {program_key(want[t]) for t in tasks}
    assert len({program_key(seen[t]) for t in tasks[:2]}) == 1  # FrozenLake and its slippery variant: one layout


def test_study_with_compact_outputs_brings_back_measures_only(tmp_path, monkeypatch):
    """Above `STUDY_FULL_OUTPUT_SEEDS` a task's results.parquet holds per-seed measures only (and no
    per_seed.csv), so its runs bring back the measures taken on the device, not every trial's log:
    the same study.json."""
    import pyarrow.parquet as pq

    from jaxeac import results
    from jaxeac.experiments import study_runs
    from jaxeac.running import outputs

    settings = StudySettings(tasks=("FrozenLake-4x4-v1",), algos=("ac", "eac"), seeds=8, trials=10, resamples=400)
    full = run_study(settings, tmp_path / "full", progress=False)
    monkeypatch.setattr(study_runs, "STUDY_FULL_OUTPUT_SEEDS", 4)
    prepared = []
    prepare = outputs.CompactCollector.prepare
    monkeypatch.setattr(outputs.CompactCollector, "prepare",
                        lambda self, start, chunk, pool: prepared.append(chunk.measures is not None)
                        or prepare(self, start, chunk, pool))
    compact = run_study(settings, tmp_path / "compact", progress=False)
    assert prepared and all(prepared)  # measured on the device
    columns = {f: pq.read_schema(tmp_path / f / "tasks" / "FrozenLake-4x4-v1" / results.RESULTS_FILE).names
               for f in ("full", "compact")}
    assert set(columns["compact"]) < set(columns["full"])  # no per-trial steps, no policies
    csv = [(tmp_path / f / "tasks" / "FrozenLake-4x4-v1" / "per_seed.csv").exists() for f in ("full", "compact")]
    assert csv == [True, False]

    def numbers(r):
        return {k: v for k, v in r.items() if k not in ("timeline",)}

    assert numbers(compact) == numbers(full)


def test_statistics_take_tasks_as_they_come():
    """`TaskStatistics` (the study's one engine pass, each task's statistics from when its successes
    are in): tasks added in any order while the pass runs give `compare`'s numbers of the whole; a
    pass stopped while it waits for tasks ends with an error, not a hang."""
    from jaxeac.experiments.study import TaskStatistics, _seed_ids
    from jaxeac.perseed import PerSeed
    from jaxeac.stats.engine import compare

    tasks, algos, n, trials = ("t0", "t1", "t2"), ("ac", "eac", "sarsa"), 40, 20
    rng = np.random.default_rng(8)
    samples = {t: {a: rng.binomial(trials, rng.uniform(0.2, 0.8), n).astype(np.int32) for a in algos}
               for t in tasks}
    stats = TaskStatistics(tasks, algos, n, trials, resamples=400, key=3)
    for t in reversed(tasks):
        stats.add(t, samples[t])
    per_task, rows, agg = stats.result()
    whole = compare(PerSeed({t: {a: x.astype(np.float64) for a, x in s.items()} for t, s in samples.items()},
                            {t: {a: _seed_ids(n) for a in algos} for t in tasks}, "successes", "study"),
                    baseline="ac", resamples=400, key=3, normalize="minmax",
                    reference_scores={t: (0.0, float(trials)) for t in tasks}, profile_points=trials + 1)
    assert [(r["task"], r["x"], r["diff_ci95"], r["p_holm"]) for r in rows] == [
        (r["task"], r["x"], r["diff_ci"], r["p_welch_holm"]) for r in whole.rows]
    assert [per_task[a["task"]]["algorithms"][a["algo"]]["iqm_ci95"] for a in whole.algorithms] == [
        a["iqm_ci"] for a in whole.algorithms]
    assert agg["algorithms"] == whole.aggregate["algorithms"] and agg["key"] == 3
    waiting = TaskStatistics(tasks, algos, n, trials, resamples=400, key=3)
    waiting.add("t0", samples["t0"])
    waiting.stop()
    with pytest.raises(RuntimeError, match="stopped"):
        waiting.result()


def test_study_figure_draws_a_panel_per_task_as_each_ends():
    """`StudyFigure`: each task's panel is drawn when it is added, in the study's order whatever the
    order of arrival, with the mean cumulative successes of its counts; `finish` gives the PNG
    and raises what a panel's drawing raised."""
    from jaxeac.experiments.study_figure import StudyFigure
    from jaxeac.stats.cumulative import cumulative_counts

    success = np.array([[1, 0, 1], [0, 0, 1]], bool)  # 2 seeds x 3 trials: means 0.5, 0.5, 1.5
    counts = {"ac": cumulative_counts(success), "eac": cumulative_counts(~success)}
    with StudyFigure(["a", "b", "c"], 2) as fig:
        fig.add("c", counts)
        fig.add("a", counts)
        fig.add("b", counts)
        png = fig.finish().result()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    assert [ax.get_title() for ax in fig._fig.axes[:3]] == ["a", "b", "c"]
    ac = fig._by_task["c"].get_lines()[0]
    assert ac.get_label() == "AC" and np.allclose(ac.get_ydata(), [0.5, 0.5, 1.5])
    with StudyFigure(["a"], 2) as broken:
        broken.add("a", {"ac": np.zeros(3)})  # not [T, T + 1] counts
        with pytest.raises(ValueError):
            broken.finish().result()


def test_study_figure_drawn_by_a_helper_is_the_same_png():
    """Given a helper, the panels are drawn there (the lines computed here): the same PNG, byte for
    byte; a helper that has gone before the figure is finished leaves it to be drawn here."""
    from jaxeac.experiments.study_figure import FIGURE_LANE, StudyFigure
    from jaxeac.running.helper import Helper
    from jaxeac.stats.cumulative import cumulative_counts

    rng = np.random.default_rng(3)
    counts = {t: {a: cumulative_counts(rng.random((20, 12)) < p) for a, p in (("ac", 0.3), ("eac", 0.6))}
              for t in ("a", "b", "c")}

    def draw(helper=None, kill=False):
        with StudyFigure(list(counts), 20, helper=helper) as fig:
            for task in ("c", "a", "b"):
                fig.add(task, counts[task])
            if kill:
                helper.kill()
            return fig.finish().result(), hasattr(fig, "_fig")  # a matplotlib figure in this process

    here, _ = draw()
    lanes = {FIGURE_LANE: 1}
    with Helper(threads=1, lanes=lanes) as helper:
        busy = helper.submit(time.sleep, 20)  # E8's jobs hold every thread of the helper's own
        assert draw(helper) == (here, False) and not busy.done()  # the figure's lane never waits for them
        helper.kill()
    with Helper(threads=2) as helper:  # without a figure lane: drawn with its other jobs; killed: here
        assert draw(helper, kill=True) == (here, True)
    with Helper(threads=2) as helper:
        assert draw(helper) == (here, False)


def test_tasks_of_one_program_share_their_state_size_traced_once(monkeypatch):
    """`state_bytes_per_seed` sizes a lane as the compiled program holds it, on the layout's
    padded tables (a small task in a large layout counts the layout's states), once per program
    and config: tasks of one layout share the answer without tracing again."""
    import jax

    from jaxeac.running import carry

    grids = {t: StudySettings(tasks=(t,), algos=("eac",), seeds=4).task_settings(t)
             for t in ("FrozenLake-4x4-v1", "FrozenLake-8x8-v1")}
    from jaxeac.experiments.study import task_envs

    envs = task_envs(grids)
    small, big = envs["FrozenLake-4x4-v1"], envs["FrozenLake-8x8-v1"]
    assert small.n_states == 16 and small.layout.states == big.n_states == 64
    cfg = grids["FrozenLake-4x4-v1"].run_config("eac")
    monkeypatch.setattr(carry, "_STATE_BYTES", {})
    traces = []
    eval_shape = jax.eval_shape
    monkeypatch.setattr(jax, "eval_shape", lambda *a, **k: traces.append(1) or eval_shape(*a, **k))
    size = carry.state_bytes_per_seed(small, cfg)
    assert carry.state_bytes_per_seed(big, cfg) == size and len(traces) == 1
    own = carry.flat_init(big, cfg.resolve(big), np.zeros(2, np.uint32))  # the 8x8 map is the layout itself
    assert size == sum(x.size * x.dtype.itemsize for x in jax.tree.leaves(own))


def test_aggregate_keeps_each_tasks_draw_where_the_counts_fit(monkeypatch):
    """A task's shared draw, binned per value for the aggregate, is kept as the task ends where
    every task's counts would fit (`MAX_KEPT_BYTES`), so the aggregate after the last task draws
    nothing again; without room it draws each task again: the same numbers either way."""
    from jaxeac.experiments.study import TaskStatistics
    from jaxeac.stats import core, groups

    tasks, algos, n, trials = ("t0", "t1"), ("ac", "eac"), 30, 12
    rng = np.random.default_rng(5)
    samples = {t: {a: rng.binomial(trials, rng.uniform(0.2, 0.8), n).astype(np.int32) for a in algos}
               for t in tasks}
    import threading

    calls = []  # the threads that bin a draw: a task's own, or the aggregate's after the last task
    per_value = groups.SharedDraw.per_value
    monkeypatch.setattr(groups.SharedDraw, "per_value", lambda self, xs: calls.append(
        threading.current_thread().name.split("_")[0]) or per_value(self, xs))
    results = {}
    # 100,000 bytes: every task's counts per value fit (2 tasks x 2 algorithms x at most 13 values
    # x 400 resamples x 4 bytes), though the draws of the seeds themselves would not (120 x 400 x 4)
    for budget in (100_000, 0):
        monkeypatch.setattr(core, "MAX_KEPT_BYTES", budget)
        monkeypatch.setattr(groups, "MAX_KEPT_BYTES", budget)
        calls.clear()
        stats = TaskStatistics(tasks, algos, n, trials, resamples=400, key=2)
        for t in tasks:
            stats.add(t, samples[t])
        results[budget] = stats.result()
        assert calls == ["jaxeac-task-stats"] * 2 if budget else calls == ["jaxeac-statistics"] * 2, calls
    assert results[0] == results[100_000]


def test_tasks_run_side_by_side_are_taken_as_their_runs_end():
    """The study takes each task (its curves, its statistics) as its runs end, not in the study's
    order: a first task that compiles the programs no longer holds back the others' statistics."""
    from concurrent.futures import Future

    from jaxeac.experiments.study_runs import as_they_end

    ahead = {t: Future() for t in ("a", "b", "c")}
    order = as_they_end(["loaded", "a", "b", "c"], ahead)
    assert next(order) == "loaded"  # not run side by side: first, in the study's order
    ahead["c"].set_result(None)
    assert next(order) == "c"
    ahead["b"].set_exception(RuntimeError("b failed"))
    assert next(order) == "b"
    ahead["a"].set_result(None)
    assert list(order) == ["a"]


def test_a_task_that_fails_side_by_side_stops_the_study_with_its_own_error(tmp_path, monkeypatch):
    """A task run side by side that fails stops the study with that task's error, whichever task's
    end the study reads first (those after it in its lane are not run and carry the same error)."""
    from jaxeac.experiments import study_runs

    run = study_runs.TaskRunner.run

    def first_fails(self, task, grid, folder, progress):
        if task == "FrozenLake-4x4-v1":
            raise MemoryError("the real cause")
        return run(self, task, grid, folder, progress)

    monkeypatch.setitem(study_runs.TASKS_SIDE_BY_SIDE, "cpu", 2)
    monkeypatch.setattr(study_runs.TaskRunner, "run", first_fails)
    settings = StudySettings(tasks=("FrozenLake-4x4-v1", "CliffWalking-v1", "FrozenLake-4x4-slippery-v1"),
                             algos=("ac", "eac"), seeds=4, trials=5, resamples=400)
    with pytest.raises(MemoryError, match="the real cause"):
        run_study(settings, tmp_path, progress=False)
    assert not (tmp_path / "study.json").exists()


def test_the_cli_starts_e8s_helper_before_its_checks_and_never_leaves_it_running(tmp_path, monkeypatch):
    """`jaxeac study` (where E8 goes to a helper: GPUs) starts the helper process before its checks,
    so that its start overlaps them; the study then runs E8 there, and a study refused by a check
    leaves no helper behind."""
    from jaxeac.experiments import grid, study_runs

    monkeypatch.setitem(grid.DIAGNOSE_BESIDE_THE_RUN, "cpu", True)
    monkeypatch.setitem(study_runs.DIAGNOSE_IN_HELPER, "cpu", True)
    started = []
    start = study_runs.diagnostics_helper
    monkeypatch.setattr(study_runs, "diagnostics_helper", lambda *a: started.append(start(*a)) or started[-1])
    (tmp_path / "a_file").write_text("not a folder")
    argv = ["study", "--tasks", "FrozenLake-4x4-v1", "--algos", "ac", "eac", "--seeds", "6", "--trials", "8",
            "--resamples", "400", "--quiet"]
    assert main([*argv, "--out", str(tmp_path / "a_file")]) == 2  # refused by the output folder's check
    assert len(started) == 1 and not started[0].process._process.is_alive()
    assert main([*argv, "--out", str(tmp_path / "s")]) == 0
    assert len(started) == 2 and not started[1].process._process.is_alive()
    study = json.loads((tmp_path / "s" / "study.json").read_text())
    assert 0 < study["timeline"]["helper_peak_rss_gib"] < 4  # the runner used (and closed) the early helper


def test_the_cli_sends_every_task_e8_to_the_helper_before_its_checks(tmp_path, monkeypatch):
    """`jaxeac study` (E8 in a helper: GPUs) sends each task's E8 to the helper once, before its
    checks: its programs' compiles, then its seeds, which need nothing from the run (R1, R2); the
    study then counts every task's from those jobs, the same counts as in its own process."""
    from jaxeac.experiments import common, grid, study_runs
    from jaxeac.running import helper

    sent, at_the_checks = [], []

    class Counting(helper.Helper):
        def submit(self, fn, /, *args, **kwargs):
            sent.append(fn.__name__)
            return super().submit(fn, *args, **kwargs)

    check = common.check_grid_resources

    def checked_after_the_jobs(*args, **kwargs):
        at_the_checks.append(list(sent))
        return check(*args, **kwargs)

    argv = ["study", "--tasks", "FrozenLake-4x4-v1", "CliffWalking-v1", "--algos", "ac", "eac", "--seeds", "6",
            "--trials", "8", "--resamples", "400", "--quiet"]
    assert main([*argv, "--out", str(tmp_path / "here")]) == 0  # CPUs: E8 in the study's process
    monkeypatch.setitem(grid.DIAGNOSE_BESIDE_THE_RUN, "cpu", True)
    monkeypatch.setitem(study_runs.DIAGNOSE_IN_HELPER, "cpu", True)
    monkeypatch.setattr(helper, "Helper", Counting)
    monkeypatch.setattr(common, "check_grid_resources", checked_after_the_jobs)
    assert main([*argv, "--out", str(tmp_path / "helper")]) == 0
    assert at_the_checks[0].count("prepare_diagnostics") == 1  # one program: eac's, both tasks' layout
    assert at_the_checks[0].count("diagnose_grid") == 2  # a job per task, before the first check
    assert sent.count("diagnose_grid") == 2  # and none sent again as the runs start
    for task in ("FrozenLake-4x4-v1", "CliffWalking-v1"):
        counts = [json.loads((tmp_path / how / "tasks" / task / "summary.json").read_text())["memory_diagnostics"]
                  for how in ("here", "helper")]
        assert counts[0] == counts[1] and counts[1]["eac"]["successes_match_run"]


def test_the_helper_ends_once_its_jobs_are_done_while_the_statistics_run(tmp_path, monkeypatch):
    """Once every task's E8 job and the figure have gone to the helper, it is ended as soon as they
    are done (`TaskRunner.release_helper`): the statistics still running do not share the host's
    memory with an idle helper."""
    from jaxeac.experiments import grid, study, study_runs

    monkeypatch.setitem(grid.DIAGNOSE_BESIDE_THE_RUN, "cpu", True)
    monkeypatch.setitem(study_runs.DIAGNOSE_IN_HELPER, "cpu", True)
    started, alive_at_the_statistics = [], []
    start = study_runs.diagnostics_helper
    monkeypatch.setattr(study_runs, "diagnostics_helper", lambda *a: started.append(start(*a)) or started[-1])
    result = study.TaskStatistics.result

    def statistics_after_the_helper(self):
        deadline = time.monotonic() + 60
        while started[0].process._process.is_alive() and time.monotonic() < deadline:
            time.sleep(0.05)
        alive_at_the_statistics.append(started[0].process._process.is_alive())
        return result(self)

    monkeypatch.setattr(study.TaskStatistics, "result", statistics_after_the_helper)
    settings = StudySettings(tasks=("FrozenLake-4x4-v1",), algos=("ac", "eac"), seeds=6, trials=8,
                             resamples=400)
    out = study.run_study(settings, tmp_path / "s", progress=False)
    assert alive_at_the_statistics == [False]  # ended before the statistics were read, not by the study's end
    assert 0 < out["timeline"]["helper_peak_rss_gib"] < 4
    assert (tmp_path / "s" / "fig_study.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_helper_is_released_only_after_every_e8_job_even_one_whose_folder_is_done():
    """`release_helper` waits for every task's E8 job, also those `diagnosed` has given up (their
    folders finished), before it ends the helper."""
    from jaxeac.experiments.study_runs import TaskRunner
    from jaxeac.running.helper import Helper

    helper = Helper(threads=1)
    try:
        job = helper.submit(time.sleep, 1.0)
        runner = TaskRunner.__new__(TaskRunner)  # only what `release_helper` reads
        runner.helper, runner.diagnosed, runner._jobs, runner._closer = helper, {}, [job], None
        closed = []
        helper.close = lambda *a, **k: closed.append(job.done())  # when the helper is ended, is the job done?
        runner.release_helper()
        runner._closer.join(60)
        assert closed == [True]
    finally:
        Helper.close(helper)
