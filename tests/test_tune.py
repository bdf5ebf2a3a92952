"""`jaxeac study --tune` (issue 43): tuning on other seeds, two selections, evaluation at them."""

from __future__ import annotations

import json

import numpy as np
import pytest

from jaxeac.cli import main
from jaxeac.experiments.study import StudySettings, run_study
from jaxeac.experiments.tune import Tuning, _run, keys_of, parse_tune

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
    ],
)
def test_bad_tuning_input_is_one_error_line_before_any_compute(tmp_path, capsys, flags, names):
    out = tmp_path / "s"
    code = main(["study", "--tasks", "FrozenLake-4x4-v1", "--out", str(out), "--quiet", *flags])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("error: ") and names in err[0]
    assert not out.exists()
