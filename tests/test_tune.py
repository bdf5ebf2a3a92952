"""`jaxeac study --tune` (issue 43): tuning on other seeds, two selections, evaluation at them."""

from __future__ import annotations

import json

import numpy as np
import pytest

from jaxeac.cli import main
from jaxeac.experiments.study import StudySettings, run_study
from jaxeac.experiments.tune import Tuning, keys_of, parse_tune
from jaxeac.experiments.tune_runs import _run

TASKS = ("FrozenLake-4x4-v1", "grid-paper7-v0:slip=0.2")
ALGOS = ("ac", "eac", "sarsa")


@pytest.fixture(scope="module")
def tuned(tmp_path_factory):
    out = tmp_path_factory.mktemp("tuned")
    settings = StudySettings(tasks=TASKS, algos=ALGOS, seeds=30, trials=20, resamples=400)
    tuning = Tuning.build(
        ["alpha=0.1,0.3", "beta=0.3,1", "sarsa.epsilon=0.05,0.2"],
        algos=ALGOS,
        seeds=16,
        key=None,
        eval_key=0,
        trials=20,
        out=out,
    )
    return out, settings, tuning, run_study(settings, out, progress=False, tuning=tuning)


def test_each_algorithm_gets_a_grid_over_the_keys_it_reads():
    assert keys_of("eac") == ("alpha", "beta", "gamma", "temperature")
    assert keys_of("q_learning") == ("alpha", "gamma", "epsilon")
    t = Tuning.build(
        ["alpha=0.1,0.3", "beta=0.3,1", "epsilon=0.05,0.2"],
        algos=("ac", "q_learning"),
        seeds=4,
        key=None,
        eval_key=7,
        trials=20,
    )
    assert t.key == 8  # default: the evaluation key + 1
    assert dict(t.grids["ac"]) == {"alpha": (0.1, 0.3), "beta": (0.3, 1.0)}
    assert dict(t.grids["q_learning"]) == {"alpha": (0.1, 0.3), "epsilon": (0.05, 0.2)}
    assert len(t.points("ac")) == 4 and len(t.points("q_learning")) == 4
    assert parse_tune("sarsa.epsilon=0.1", ("ac", "sarsa")) == ("sarsa", "epsilon", (0.1,))


def test_tuning_runs_on_the_tuning_key_and_selections_follow_the_scores(tuned):
    out, settings, tuning, result = tuned
    tu = result["tuning"]
    assert (tu["key"], tu["evaluation_key"], tu["seeds"]) == (1, 0, 16)
    assert tu["grids"]["sarsa"] == {"alpha": [0.1, 0.3], "epsilon": [0.05, 0.2]}
    for _a, s in tu["algorithms"].items():
        means = np.array([s["tuning_means"][t] for t in TASKS])
        for i, t in enumerate(TASKS):
            assert s["per_task"][t] == int(np.argmax(means[i]))
        cross = (means / 20).mean(0)
        np.testing.assert_allclose(s["cross_task_scores"], cross)
        assert s["cross_task"] == int(np.argmax(cross))
        assert s["sensitivity"] == pytest.approx(cross.max() - np.median(cross))
    # tuning means are those of the tuning key's seeds, not the evaluation's
    from jaxeac.experiments.study import task_envs

    grids = {t: settings.task_settings(t) for t in TASKS}
    envs = task_envs(grids)
    t = TASKS[0]
    pts = tu["algorithms"]["eac"]["points"]
    got = _run(envs[t], grids[t], "eac", pts, key=tuning.key, seeds=16, chunk_size=None)
    assert got.mean(1).tolist() == pytest.approx(tu["algorithms"]["eac"]["tuning_means"][t])
    other = _run(envs[t], grids[t], "eac", pts, key=0, seeds=16, chunk_size=None)
    assert not np.array_equal(got, other)


def test_evaluation_at_a_selection_is_a_plain_run_at_that_setting(tuned):
    import dataclasses

    from jaxeac.running.batch import run_seeds

    out, settings, tuning, result = tuned
    tu = result["tuning"]
    for t in TASKS:
        for a in ALGOS:
            s = tu["algorithms"][a]
            point = s["points"][s["per_task"][t]]
            grid = dataclasses.replace(settings.task_settings(t), **point).resolved()
            plain = run_seeds(grid.make_env(), grid.run_config(a), root_key=0, n_seeds=30)
            successes = np.asarray(plain.success).sum(1)
            assert tu["conditions"]["per_task"]["means"][t][a] == pytest.approx(successes.mean())
    # and per seed: the entries path with a selection equals the plain run
    from jaxeac.experiments.study import task_envs

    grids = {t: settings.task_settings(t) for t in TASKS}
    t, point = TASKS[1], {"alpha": 0.3, "beta": 1.0}
    both = _run(task_envs(grids)[t], grids[t], "ac", [{}, point], key=0, seeds=30, chunk_size=None)
    grid = dataclasses.replace(grids[t], **point)
    plain = run_seeds(grid.make_env(), grid.run_config("ac"), root_key=0, n_seeds=30)
    np.testing.assert_array_equal(both[1], np.asarray(plain.success).sum(1))
    preset = run_seeds(grids[t].make_env(), grids[t].run_config("ac"), root_key=0, n_seeds=30)
    np.testing.assert_array_equal(both[0], np.asarray(preset.success).sum(1))


def test_side_by_side_on_accelerators_gives_the_cpu_paths_results(tuned, tmp_path, monkeypatch):
    """On accelerators the tuning runs beside the study's runs and the evaluation beside its
    statistics (`TASKS_SIDE_BY_SIDE`, `DIAGNOSE_BESIDE_THE_RUN`), and E8 on the platform
    `DIAGNOSE_ON` names; forced on here, every number of study.json but the timings is the CPU
    path's, and so is every task's E8."""
    from jaxeac.experiments import grid, study_runs

    monkeypatch.setitem(study_runs.TASKS_SIDE_BY_SIDE, "cpu", 2)
    monkeypatch.setitem(grid.DIAGNOSE_BESIDE_THE_RUN, "cpu", True)
    monkeypatch.setitem(study_runs.DIAGNOSE_ON, "cpu", "cpu")
    out, settings, _, _ = tuned
    tuning = Tuning.build(["alpha=0.1,0.3", "beta=0.3,1", "sarsa.epsilon=0.05,0.2"], algos=ALGOS, seeds=16,
                          key=None, eval_key=0, trials=20, out=tmp_path)
    run_study(settings, tmp_path, progress=False, tuning=tuning)

    def numbers(folder):
        saved = json.loads((folder / "study.json").read_text())
        return {k: v for k, v in saved.items() if k not in ("timeline", "environment", "seconds")}

    assert numbers(tmp_path) == numbers(out)
    for task in TASKS:
        e8 = [json.loads((study_runs.task_folder(f, task) / "summary.json").read_text())["memory_diagnostics"]
              for f in (tmp_path, out)]
        assert e8[0] == e8[1] and e8[0]


def test_tuned_report_and_json(tuned):
    out, settings, tuning, result = tuned
    saved = json.loads((out / "study.json").read_text())
    assert set(saved["tuning"]["conditions"]) == {"preset", "per_task", "cross_task"}
    cond = saved["tuning"]["conditions"]["cross_task"]
    assert len(cond["comparisons"]) == 4 and cond["aggregate"]["tasks"] == list(TASKS)
    for a in ALGOS:
        for t in TASKS:
            o = saved["tuning"]["optimism"][a][t]
            assert o["optimism"] == pytest.approx(o["tuning_mean"] - o["evaluation_mean"])
    report = (out / "report.md").read_text()
    assert "## Tuned: every algorithm at its best setting" in report
    assert "### Across tasks, per condition" in report and "sensitivity" in report
    assert report.count("Highest mean: ") == len(TASKS)


@pytest.mark.parametrize(
    ("flags", "names"),
    [
        (["--tune", "epsilon=0.1", "--algos", "ac", "eac"], "--tune epsilon"),
        (["--tune", "ac.epsilon=0.1"], "--tune ac.epsilon"),
        (["--tune", "alpha=2"], "--tune alpha"),
        (["--tune", "alpha="], "--tune alpha"),
        (["--tune-seeds", "10"], "--tune"),
        (["--tune", "alpha=0.1", "--tune-key", "3", "--key", "3"], "--tune-key 3"),
        (["--tune", "alpha=0.1,0.2", "--tune", "beta=0.1,0.2", "--tune-seeds", "100000000"], "--tune"),
        (["--tune", "epsilon=0.1,1.5"], "--tune epsilon"),
        (["--tune", "temperature=0,1"], "--tune temperature"),
        (["--tune", "gamma=0.9,1.2"], "--tune gamma"),
        (["--tune", "alpha=nan"], "--tune alpha"),
        (["--tune", "lr=0.1"], "'lr'"),
        (["--tune", "alpha"], "--tune 'alpha'"),
        (["--tune", "alpha=0.1,,0.2"], "--tune alpha"),
        (["--tune", "alpha=0.1,0.1"], "--tune alpha"),
        (["--tune", "alpha=0.1", "--tune", "alpha=0.2"], "--tune alpha"),
        (["--tune", "q_learning.alpha=0.1", "--algos", "ac", "eac"], "--tune q_learning.alpha"),
        (["--tune", "alpha=0.1", "--tune-seeds", "1"], "--tune-seeds 1"),
        (["--tune", "alpha=0.1", "--tune-key", "0"], "--tune-key 0"),  # --key 0: the same seeds
    ],
)
def test_bad_tuning_input_is_one_error_line_before_any_compute(tmp_path, capsys, flags, names):
    out = tmp_path / "s"
    code = main(["study", "--tasks", "FrozenLake-4x4-v1", "--out", str(out), "--quiet", *flags])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("error: ") and names in err[0]
    assert not out.exists()


def test_sensitivity_curves_bands_figure_and_claim(tuned):
    out, settings, tuning, result = tuned
    tu = result["tuning"]
    for a, s in tu["algorithms"].items():
        for t in TASKS:
            chosen = s["points"][s["per_task"][t]]
            assert set(s["curves"][t]) == set(dict(tuning.grids[a]))  # every key with two values
            for k, c in s["curves"][t].items():
                assert c["chosen"] == chosen[k] and c["values"] == sorted(c["values"])
                for v, m, (lo, hi) in zip(c["values"], c["mean"], c["ci95"], strict=True):
                    i = s["points"].index({**chosen, k: v})  # the other keys at the task's selection
                    assert m == pytest.approx(s["tuning_means"][t][i]) and lo <= m <= hi
    sens = tu["sensitivity"]["algorithms"]
    for a, s in tu["algorithms"].items():
        assert sens[a]["estimate"] == pytest.approx(s["sensitivity"])
        lo, hi = sens[a]["ci95"]
        assert lo <= hi and 0 <= hi <= 1
        for t in TASKS:
            assert sens[a]["per_task"][t]["estimate"] == pytest.approx(s["sensitivity_per_task"][t])
    m, claim = sens["eac"]["minus_ac"], tu["sensitivity"]["claim"]
    assert m["estimate"] == pytest.approx(sens["eac"]["estimate"] - sens["ac"]["estimate"])
    assert claim["verdict"] == ("holds" if m["ci95"][1] < 0 else "refuted: EAC is more sensitive"
                                if m["ci95"][0] > 0 else "not shown: the interval includes 0")
    assert (out / tu["figure"]).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    report = (out / "report.md").read_text()
    assert "### Sensitivity to the rates" in report and f"]({tu['figure']})" in report
    assert '"EAC is less sensitive to its rates than AC": **' + claim["verdict"] + "**" in report


def test_head_to_head_per_task_and_over_tasks(tuned):
    out, settings, tuning, result = tuned
    h2h, conds = result["tuning"]["head_to_head"], result["tuning"]["conditions"]
    assert set(h2h["per_task"]["rivals"]) == {"ac", "sarsa"}  # q_learning is not in this study
    for c in ("preset", "per_task", "cross_task"):
        for r, row in h2h[c]["rivals"].items():
            for t in TASKS:
                cell = row["per_task"][t]
                assert cell["diff"] == pytest.approx(conds[c]["means"][t]["eac"] - conds[c]["means"][t][r])
                assert cell["ci95"][0] < cell["diff"] < cell["ci95"][1]
            mean = np.mean([row["per_task"][t]["diff"] for t in TASKS]) / 20
            assert row["over_tasks"]["diff"] == pytest.approx(mean)
        for t in TASKS:
            assert h2h[c]["leaders"][t] == max(ALGOS, key=lambda a, t=t: conds[c]["means"][t][a])
    report = (out / "report.md").read_text()
    assert "### Does EAC still beat AC, Q-learning and SARSA when each is at its best?" in report
    assert "Leader after per-task tuning:" in report


def test_a_tuned_study_killed_midway_resumes_where_it_stopped(tuned, tmp_path, monkeypatch, capsys):
    import shutil

    from jaxeac.experiments import tune_runs

    out, settings, tuning, result = tuned
    folder = tmp_path / "again"
    shutil.copytree(out, folder)
    # A run killed midway: the files written so far are whole (atomic), the rest absent.
    (folder / "tune" / "grid-paper7-v0-slip0.2" / "sarsa.tuning.npz").unlink()
    (folder / "tune" / "grid-paper7-v0-slip0.2" / "eac.evaluation.npz").unlink()
    calls = []
    real, real_evaluate = tune_runs._run, tune_runs._evaluate

    def counting(env, grid, algo, points, **kw):
        calls.append((grid.env, algo, kw["key"]))
        return real(env, grid, algo, points, **kw)

    def counting_evaluate(env, grid, jobs, **kw):
        calls.extend({(grid.env, a, kw["key"]) for a, _ in jobs})
        return real_evaluate(env, grid, jobs, **kw)

    monkeypatch.setattr(tune_runs, "_run", counting)
    monkeypatch.setattr(tune_runs, "_evaluate", counting_evaluate)
    again = Tuning.build(["alpha=0.1,0.3", "beta=0.3,1", "sarsa.epsilon=0.05,0.2"], algos=ALGOS, seeds=16,
                         key=None, eval_key=0, trials=20, out=folder)
    redone = run_study(settings, folder, progress=True, tuning=again)
    assert sorted(calls) == [("grid-paper7-v0", "eac", 0), ("grid-paper7-v0", "sarsa", 1)]
    assert capsys.readouterr().err.count("(done earlier, reusing") == 2 * len(TASKS) * len(ALGOS) - 2
    for k in ("algorithms", "optimism", "sensitivity", "head_to_head"):
        assert json.dumps(redone["tuning"][k], sort_keys=True) == json.dumps(result["tuning"][k],
                                                                                sort_keys=True)


def test_a_kept_result_is_reused_only_with_the_same_settings(tmp_path):
    from jaxeac.experiments.tune_runs import _cached

    path = tmp_path / "t" / "ac.tuning.npz"
    x, reused = _cached(path, {"trials": 20}, lambda: np.arange(6, dtype=np.int32).reshape(2, 3))
    assert not reused and path.is_file() and not list(path.parent.glob(".*.tmp"))
    y, reused = _cached(path, {"trials": 20}, lambda: pytest.fail("computed again"))
    assert reused and np.array_equal(x, y)
    z, reused = _cached(path, {"trials": 10}, lambda: np.zeros((2, 3), np.int32))  # other settings: run again
    assert not reused and not z.any() and not _cached(path, {"trials": 10}, lambda: None)[0].any()
    path.write_bytes(b"damaged")
    assert not _cached(path, {"trials": 10}, lambda: np.ones((1, 1), np.int32))[1]


def test_a_folder_tuned_with_another_setup_is_refused_before_any_compute(tuned, tmp_path, capsys):
    import shutil

    out, settings, tuning, result = tuned
    folder = tmp_path / "other"
    shutil.copytree(out, folder)
    before = sorted(p.relative_to(folder) for p in folder.rglob("*"))
    code = main(["study", "--tasks", *TASKS, "--algos", *ALGOS, "--seeds", "30", "--trials", "20", "--quiet",
                 "--out", str(folder), "--tune", "alpha=0.1,0.2", "--tune-seeds", "16"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("error: --tune: ")
    assert "another setup" in err[0] and "grids" in err[0] and "another --out" in err[0]
    assert sorted(p.relative_to(folder) for p in folder.rglob("*")) == before


def test_tuned_verdicts_use_the_test_behind_the_studys_marks():
    """Welch's p and Holm over the family (every algorithm against AC on every task), as the
    engine gives them: the test behind the study's + / − marks."""
    from jaxeac.experiments.tune import verdict_rows
    from jaxeac.stats.core import compare_per_seed

    rng = np.random.default_rng(3)
    per = {t: {"ac": rng.integers(0, 20, 50), "eac": rng.integers(2, 22, 60),
               "sarsa": rng.integers(0, 21, 40)} for t in ("t1", "t2")}
    rows, means = verdict_rows(per)
    engine = compare_per_seed(per, baseline="ac", paired="unpaired", resamples=400, key=0)
    want = {(r["task"], r["x"]): (r["p_welch"], r["p_welch_holm"]) for r in engine.rows}
    assert len(rows) == len(want) == 4
    for r in rows:
        assert (r["p_welch"], r["p_holm"]) == pytest.approx(want[(r["task"], r["x"])], rel=1e-9)
        assert r["diff"] == pytest.approx(means[r["task"]][r["x"]] - means[r["task"]]["ac"])
    same = {"t": {"ac": np.zeros(5), "eac": np.zeros(5), "sarsa": np.ones(5)}}
    assert [r["p_welch"] for r in verdict_rows(same)[0]] == [1.0, 0.0]  # constant samples


def test_tuning_and_evaluation_compile_nothing_beyond_the_study(tmp_path, monkeypatch):
    """On CPUs the tuning's runs (padded to the study's chunk) and the evaluation's (plain runs at
    the selected rates) take the programs the study compiled: every compile comes before them."""
    import jaxeac.running.batch as batch
    from jaxeac.experiments import tune_runs

    phase, compiled = ["study"], []
    real = batch._compiled

    def counting(*args, **kw):
        program, seconds = real(*args, **kw)
        if seconds > 0:
            compiled.append(phase[0])
        return program, seconds

    monkeypatch.setattr(batch, "_compiled", counting)
    def marking(name):
        method = getattr(tune_runs.TuningRuns, name)

        def marked(self, *a, **kw):
            phase[0] = name
            return method(self, *a, **kw)

        return marked

    for name in ("tune", "evaluate"):
        monkeypatch.setattr(tune_runs.TuningRuns, name, marking(name))
    settings = StudySettings(tasks=TASKS, algos=ALGOS, seeds=30, trials=12, resamples=400)
    tuning = Tuning.build(["alpha=0.1,0.3", "beta=0.3,1", "sarsa.epsilon=0.05,0.2"], algos=ALGOS, seeds=16,
                          key=None, eval_key=0, trials=12, out=tmp_path)
    run_study(settings, tmp_path, progress=False, tuning=tuning)
    assert phase[0] == "evaluate" and compiled == ["study"] * len(compiled) and compiled
