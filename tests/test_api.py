"""The public API (`import jaxeac`): one name per job, checked arguments, and the same results as
the command line (SPEC R1/R2: a fixed command and key give the same per-seed results whichever
way they are run)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

import jaxeac

TRIALS, SEEDS, KEY = 30, 24, 3


def _cfg(name: str, trials: int = TRIALS):
    return jaxeac.RunConfig(trials=trials, agent=jaxeac.algorithm(name))


def test_the_public_names():
    assert jaxeac.__all__ == ["RunConfig", "algorithm", "compare", "load", "make", "registered", "run", "trace"]
    from jaxeac.algorithm.config import AgentConfig

    assert isinstance(jaxeac.algorithm("eac", memory="buffer", capacity=8), AgentConfig)
    with pytest.raises(AttributeError, match="no attribute 'run_seeds'"):
        jaxeac.run_seeds  # noqa: B018


def test_run_gives_the_runners_results_and_trace_gives_one_of_its_seeds():
    from jaxeac.running.batch import run_seeds

    env = jaxeac.make("grid-paper7-v0", chances=12)
    eac = jaxeac.run(env, _cfg("eac"), seeds=SEEDS, key=KEY)
    direct = run_seeds(env, _cfg("eac"), root_key=KEY, n_seeds=SEEDS)
    np.testing.assert_array_equal(eac.success, direct.success)
    np.testing.assert_array_equal(eac.policy, direct.policy)
    both = jaxeac.run(env, [_cfg("ac"), _cfg("eac")], seeds=SEEDS, key=KEY)
    assert list(both) == ["ac", "eac"]
    np.testing.assert_array_equal(both["eac"].success, eac.success)
    _, trials = jaxeac.trace(env, _cfg("eac"), key=KEY, seed=7)  # R1: seed 7 of the same key
    np.testing.assert_array_equal(np.asarray(trials.success), eac.success[7])


def test_compare_two_results_or_arrays():
    env = jaxeac.make("grid-paper7-v0", chances=12)
    runs = jaxeac.run(env, ["ac", "eac"], seeds=SEEDS, key=KEY)
    res = jaxeac.compare(runs["ac"], runs["eac"], resamples=500)
    (s,) = res.rows
    assert s["n_y"] == s["n_x"] == SEEDS and res.level == 0.95
    assert s["diff"] == pytest.approx(runs["eac"].successes.mean() - runs["ac"].successes.mean())
    assert s["analysis"] == "paired"  # two results of one run: seed i of each shares its key
    wide = jaxeac.compare(runs["ac"].successes, runs["eac"].successes, resamples=2000, level=0.99).rows[0]
    assert wide["diff_ci"][0] < s["diff_ci"][0] and wide["diff_ci"][1] > s["diff_ci"][1]


def _numbers(record):
    """stats.json without what differs between any two runs of it (timings, its own folder)."""
    if isinstance(record, dict):
        return {k: _numbers(v) for k, v in record.items() if k not in ("timing", "run_dir", "path")}
    if isinstance(record, list):
        return [_numbers(v) for v in record]
    return record


def test_the_library_writes_the_command_lines_folder(tmp_path):
    """The same run through `jaxeac run` and through `jaxeac.run(..., out=)` + `jaxeac.compare`:
    byte-identical results.parquet and the same numbers in stats.json."""
    cli, lib = tmp_path / "cli", tmp_path / "lib"
    proc = subprocess.run([sys.executable, "-m", "jaxeac", "run", "--env", "grid-paper7-v0",
                           "--trials", str(TRIALS), "--seeds", str(SEEDS), "--key", str(KEY), "--quiet",
                           "--out", str(cli)], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    env = "grid-paper7-v0"
    with pytest.raises(TypeError, match="registered name"):  # the folder names its world, as the CLI's does
        jaxeac.run(jaxeac.make(env), ["ac", "eac"], seeds=SEEDS, key=KEY, out=lib)
    with pytest.raises(ValueError, match="eac.alpha is a schedule"):
        jaxeac.run(env, jaxeac.RunConfig(trials=TRIALS, agent=jaxeac.algorithm("eac"), alpha=lambda t: 0.1),
                   seeds=SEEDS, key=KEY, out=lib)
    with pytest.raises(ValueError, match="differs from what its flags state in loop"):
        jaxeac.run(env, jaxeac.RunConfig(trials=TRIALS, agent=jaxeac.algorithm("eac"), loop="trials"),
                   seeds=SEEDS, key=KEY, out=lib)
    jaxeac.run(env, {"ac": _cfg("ac"), "eac": _cfg("eac")}, seeds=SEEDS, key=KEY, out=lib)
    assert (lib / "results.parquet").read_bytes() == (cli / "results.parquet").read_bytes()
    jaxeac.compare(lib)
    assert _numbers(json.loads((lib / "stats.json").read_text())) == _numbers(
        json.loads((cli / "stats.json").read_text()))
    commands = [json.loads((d / "summary.json").read_text())["command"] for d in (cli, lib)]
    assert commands[0].startswith("jaxeac run --env grid-paper7-v0 ") and commands[1] is None  # none typed
    loaded = jaxeac.load(lib)
    assert loaded.algos == ("ac", "eac") and loaded.trials == TRIALS
    np.testing.assert_array_equal(loaded.per_seed["eac"]["successes"], loaded.success("eac").sum(1))


@pytest.mark.parametrize(("call", "error", "message"), [
    (lambda: jaxeac.run("grid-paper-v0", "eac", seeds=0), ValueError, "seeds must be a positive integer"),
    (lambda: jaxeac.run("grid-paper-v0", "eac", seeds=2.5), ValueError, "seeds must be a positive integer"),
    (lambda: jaxeac.run(42, "eac", seeds=2), TypeError, "env must be an environment"),
    (lambda: jaxeac.run("grid-paper-v0", 3, seeds=2), TypeError, "config must be a RunConfig or an algorithm"),
    (lambda: jaxeac.run("grid-paper-v0", [], seeds=2), ValueError, "empty sequence"),
    (lambda: jaxeac.run("grid-paper-v0", ["eac", "eac"], seeds=2), ValueError, "names an algorithm twice"),
    (lambda: jaxeac.compare([1.0, 2.0], [1.0, 2.0], level=95), ValueError, "level is the confidence level"),
    (lambda: jaxeac.compare([1.0, 2.0]), TypeError, "takes a run folder's path"),
    (lambda: jaxeac.compare([1.0], [2.0, 3.0]), ValueError, "baseline must be per-seed numbers"),
    (lambda: jaxeac.compare([1.0, 2.0], [1.0, 3.0], resamples=0), ValueError, "resamples must be a positive"),
    (lambda: jaxeac.load("/nonexistent/run"), ValueError, "holds no run"),
])
def test_bad_arguments_are_named_before_any_compute(call, error, message):
    with pytest.raises(error, match=message):
        call()


def test_release_0_1_spellings_warn_and_name_the_public_one():
    import jaxeac.running
    from jaxeac.running.batch import run_seeds

    with pytest.warns(DeprecationWarning, match=r"jaxeac.running.run_seeds is internal; use jaxeac.run"):
        old = jaxeac.running.run_seeds
    assert old is run_seeds
    with pytest.warns(DeprecationWarning, match="use jaxeac.RunConfig"):
        from jaxeac.running import RunConfig
    assert RunConfig is jaxeac.RunConfig
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        jaxeac.running.nothing  # noqa: B018


def test_compare_pairs_results_of_the_same_seeds_and_never_bare_arrays_unasked():
    env = jaxeac.make("grid-paper7-v0", chances=12)
    runs = jaxeac.run(env, ["ac", "eac"], seeds=SEEDS, key=KEY)
    assert jaxeac.compare(runs["ac"], runs["eac"], resamples=400).rows[0]["analysis"] == "paired"
    a, b = runs["ac"].successes, runs["eac"].successes
    assert jaxeac.compare(a, b, resamples=400).rows[0]["analysis"] == "unpaired"
    assert jaxeac.compare(a, b, resamples=400, paired=True).rows[0]["analysis"] == "paired"
    with pytest.raises(ValueError, match="paired=True needs as many values"):
        jaxeac.compare(a, b[:-1], resamples=400, paired=True)
