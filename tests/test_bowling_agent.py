"""AC/EAC on bowling (SPEC B2-B6, E1-E6): memory logic by hand, runs and the command line."""

from __future__ import annotations

import csv
import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxeac.algorithm.agent import init_agent
from jaxeac.algorithm.config import Hyper, algorithm
from jaxeac.algorithm.memory import dense_tables
from jaxeac.cli import main
from jaxeac.experiments.bowling import (
    FULL_RACK,
    N_MASKS,
    BowlingSettings,
    learn_from_throw,
    mask_index,
    run_bowling_algo,
)
from jaxeac.running.config import RunConfig

HYPER = Hyper(jnp.float32(0.1), jnp.float32(0.3), jnp.float32(1.0), jnp.float32(1.0))


def test_mask_index():
    assert int(mask_index(np.ones(10, bool))) == FULL_RACK == 1023
    assert int(mask_index(np.zeros(10, bool))) == 0
    standing = np.zeros(10, bool)
    standing[[0, 9]] = True  # pins 1 and 10
    assert int(mask_index(standing)) == 1 + 512


def throw_(cfg, agent, state, action, knocked, after, last):
    """One throw under the paper's rules (B5): the state is the standing mask, all down = success."""
    cleared = jnp.bool_(after == 0)
    return learn_from_throw(cfg, agent, jnp.int32(state), jnp.int32(action), jnp.bool_(True),
                            jnp.int32(knocked), jnp.int32(after), cleared, cleared, last, jnp.bool_(True), HYPER)


@pytest.mark.parametrize("tables", ["split", "rows"])
def test_strike_is_a_success_and_is_remembered_e4(tables):
    cfg = RunConfig(trials=5, agent=algorithm("eac", tables=tables), gamma=1.0)
    agent = init_agent(cfg.agent.resolve(), N_MASKS, 3, 2, 5)
    agent = throw_(cfg, agent, FULL_RACK, 2, 10, 0, False)  # strike on chance 1: the trial ends
    assert int(agent.trial) == 1 and bool(agent.outcomes[0])
    # (3) with a terminal s': δ = 10 − 0 = 10 → V(1023) = 1, p(1023, 2) = 3
    assert float(agent.values[FULL_RACK]) == pytest.approx(1.0)
    assert float(agent.preferences[FULL_RACK, 2]) == pytest.approx(3.0)
    success, _ = dense_tables(agent.memory, agent.trial, agent.outcomes)
    assert int(success[FULL_RACK]) == 2


def test_fewer_pins_than_last_trial_flags_the_throw_e6():
    cfg = RunConfig(trials=5, agent=algorithm("eac"), gamma=1.0)
    agent = init_agent(cfg.agent.resolve(), N_MASKS, 3, 2, 5)
    # trial 1: 5 then 3 pins (no strike, no spare: a failure)
    agent = throw_(cfg, agent, FULL_RACK, 0, 5, 100, False)
    agent = throw_(cfg, agent, 100, 1, 3, 7, True)
    assert int(agent.trial) == 1 and not bool(agent.outcomes[0])
    # trial 2: 4 pins (< 5) with angle 1, then 6 (> 3): only chance 1's (state, action) is flagged
    agent = throw_(cfg, agent, FULL_RACK, 1, 4, 200, False)
    agent = throw_(cfg, agent, 200, 2, 6, 0, True)  # clears the rack: a spare is a success (B5)
    assert bool(agent.outcomes[1])
    _, failed = dense_tables(agent.memory, agent.trial, agent.outcomes)
    assert not np.asarray(failed).any()  # a successful trial flags nothing
    # trial 3 fails: 2 pins (< 4) at chance 1 and 1 pin (< 6) at chance 2 → both throws flagged
    agent = throw_(cfg, agent, FULL_RACK, 0, 2, 300, False)
    agent = throw_(cfg, agent, 300, 0, 1, 5, True)
    _, failed = dense_tables(agent.memory, agent.trial, agent.outcomes)
    flagged = {(int(s), int(a)) for s, a in zip(*np.nonzero(np.asarray(failed)), strict=True)}
    assert flagged == {(FULL_RACK, 0), (300, 0)}
    success, _ = dense_tables(agent.memory, agent.trial, agent.outcomes)
    assert int(success[FULL_RACK]) == 1 and int(success[200]) == 2  # trial 2's spare path


@pytest.fixture(scope="module")
def small_run():
    settings = BowlingSettings(seeds=3, trials=3, chunk_size=2, key=4)
    settings.validate()
    return settings, {a: run_bowling_algo(settings, a) for a in ("ac", "eac")}


def test_run_records_are_consistent_b5_b6(small_run):
    settings, results = small_run
    for r in results.values():
        assert r.knocked.shape == (3, 3, 2) and r.action.shape == (3, 3, 2)
        assert (r.returns <= 10).all() and (r.returns >= 0).all()
        strike = r.knocked[:, :, 0] == 10
        assert (r.action[:, :, 1][strike] == -1).all()  # no chance 2 after a strike
        np.testing.assert_array_equal(r.success, r.returns == 10)
        th1, th2, best = r.best_path()
        np.testing.assert_array_equal(best, r.returns.max(axis=1))
        assert np.all(np.abs(th1) <= settings.theta_max + 1e-9)


def test_rerun_and_chunking_identical_r1_r2(small_run):
    settings, results = small_run
    again = run_bowling_algo(BowlingSettings(seeds=3, trials=3, chunk_size=3, key=4), "eac")
    np.testing.assert_array_equal(again.knocked, results["eac"].knocked)
    np.testing.assert_array_equal(again.action, results["eac"].action)


def test_bowling_cli_end_to_end(tmp_path, capsys):
    out = tmp_path / "b"
    argv = ["bowling", "--seeds", "2", "--trials", "2", "--out", str(out), "--quiet", "--no-compare"]
    assert main(argv) == 0
    assert sorted(p.name for p in out.iterdir()) == ["bowling.npz", "curves.npz", "fig5_angles.png",
                                                      "per_seed.csv", "summary.json", "table1.md"]
    rows = list(csv.DictReader((out / "per_seed.csv").open()))
    curves = np.load(out / "curves.npz")
    for algo in ("ac", "eac"):
        mine = [int(r["return"]) for r in rows if r["algo"] == algo]
        np.testing.assert_array_equal(mine, curves[f"{algo}_return"].sum(1))
    summary = json.loads((out / "summary.json").read_text())
    assert summary["primary_measure"] == "return" and summary["experiment"] == "bowling"
    assert summary["physics"]["solver"] == {"method": "newton", "iterations": 4, "ls_iterations": 8,
                                            "contact_cap": 32, "pair_cap": 0, "sleep": True}  # B7, recorded
    assert "Table I" in (out / "table1.md").read_text()


@pytest.mark.parametrize(("argv", "message"), [
    (["bowling", "--angles", "1"], "K >= 2"),
    (["bowling", "--seeds", "0"], "positive integer"),
    (["bowling", "--backend", "gpu"], "unknown bowling backend 'gpu'"),
    (["bowling", "--noise-angle", "-0.1"], "noise_angle"),
    (["bowling", "--noise-speed", "-1"], "noise_speed"),
    (["bowling", "--theta-max", "0"], "theta_max"),
    (["throw", "--angle", "0.5"], "outside"),
    (["throw", "--angle", "0", "--noise-angle", "-1"], "noise_angle"),
    (["throw", "--angle", "0", "--backend", "cuda"], "backend"),
    (["bowling", "--solver", "pgs"], "unknown solver 'pgs'"),
    (["bowling", "--iterations", "0"], "positive integer"),
    (["throw", "--angle", "0", "--contact-cap", "0"], "positive integer"),
    (["throw", "--angle", "0", "--pair-cap", "-2"], "non-negative"),
])
def test_bowling_bad_input(argv, message, tmp_path, capsys):
    out = tmp_path / "never"
    extra = ["--out", str(out)] if argv[0] == "bowling" else []
    assert main([*argv, *extra]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and message in err, err
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.parametrize("command", ["bowling", "throw"])
def test_warp_backend_without_warp_lang_is_a_usage_error(command, monkeypatch, tmp_path, capsys):
    """No warp-lang: one line naming the fix, exit 2, nothing written."""
    from jaxeac.envs.bowling import backend_mjx

    monkeypatch.setattr(backend_mjx._mjx_warp, "WARP_INSTALLED", False)
    out = tmp_path / "never"
    argv = ["--seeds", "2", "--out", str(out)] if command == "bowling" else ["--angle", "0"]
    argv = [command, *argv]
    assert main([*argv, "--backend", "warp"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and 'pip install "jaxeac[warp]"' in err, err
    assert not out.exists()


def test_throw_cli_json(capsys, tmp_path):
    assert main(["throw", "--angle", "0", "--angle", "0.1", "--render", str(tmp_path / "deck.png")]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["theta_max"] == 0.1
    centre, miss = data["throws"]
    assert centre["knocked"] >= 5 and miss["knocked"] == 0 and all(miss["standing"])
    assert len(list(tmp_path.glob("deck*.png"))) == 2


@pytest.mark.slow
@pytest.mark.parametrize("backend", ["mjx", "warp"])
def test_mjx_backend_runs_as_one_jit(backend):
    """B7: learning and physics as one compiled function (warp: skipped without warp-lang)."""
    if backend == "warp":
        pytest.importorskip("warp")
    settings = BowlingSettings(seeds=2, trials=2, backend=backend, chunk_size=2)
    r = run_bowling_algo(settings, "eac")
    assert r.compile_seconds > 0 and r.knocked.shape == (2, 2, 2)
    assert (r.returns >= 0).all() and (r.returns <= 10).all()
    assert ((r.action[:, :, 1] == -1) == (r.knocked[:, :, 0] == 10)).all()  # chance 2 only after no strike
    jax.clear_caches()


def test_trial_rules_states_by_hand():
    """B5 / B5a: the mask state is the standing pins; the tree's chance 2 hangs under angle k."""
    from jaxeac.experiments.bowling import TrialRules

    mask, tree = TrialRules(), TrialRules("tree")
    assert (mask.n_states(21), mask.first_state) == (1024, FULL_RACK)
    assert (tree.n_states(21), tree.first_state) == (22, 0)
    standing = np.zeros(10, bool)
    standing[[0, 9]] = True
    assert int(mask.next_state(standing, 7)) == 513
    assert int(tree.next_state(standing, 7)) == 8


@pytest.mark.parametrize(("state", "success_pins"), [("mask", 10), ("tree", 10), ("mask", 7), ("tree", 8)])
def test_success_follows_the_rules_and_runs_keep_r1(state, success_pins):
    """B5b: a trial succeeds when it knocks at least `success_pins` pins (10: all down, B5); under
    either state (B5a) a seed's run does not depend on the chunk it ran in (R1)."""
    settings = BowlingSettings(seeds=4, trials=4, key=2, state=state, success_pins=success_pins)
    settings.validate()
    whole = run_bowling_algo(settings, "eac")
    np.testing.assert_array_equal(whole.success, whole.returns >= success_pins)
    split = run_bowling_algo(dataclasses.replace(settings, chunk_size=2), "eac")
    np.testing.assert_array_equal(whole.action, split.action)
    np.testing.assert_array_equal(whole.knocked, split.knocked)


def test_tree_state_changes_what_eac_learns():
    """B5a: keying chance 2 on the chance-1 angle is a different agent: same seeds, other actions."""
    runs = {s: run_bowling_algo(BowlingSettings(seeds=6, trials=6, key=1, state=s), "eac") for s in ("mask", "tree")}
    np.testing.assert_array_equal(runs["mask"].action[:, 0, 0], runs["tree"].action[:, 0, 0])  # same first throw
    assert not np.array_equal(runs["mask"].action, runs["tree"].action)


@pytest.mark.parametrize(("argv", "message"), [
    (["bowling", "--state", "leaf"], "unknown bowling state"),
    (["bowling", "--success-pins", "11"], "success pins 11"),
])
def test_bad_trial_rules_exit_2(tmp_path, capsys, argv, message):
    out = tmp_path / "b"
    assert main([*argv, "--out", str(out), "--seeds", "2"]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and not out.exists()


def test_backend_auto_picks_the_c_engine_on_cpus(tmp_path):
    """B7: `auto` (the default) is the C engine where JAX runs on CPUs, and summary.json records
    the engine picked, not `auto`."""
    from jaxeac.envs.bowling.scene import check_backend, default_backend

    assert jax.default_backend() == "cpu"
    assert default_backend() == check_backend("auto") == "c"
    assert BowlingSettings().backend == "auto" and BowlingSettings().resolved().backend == "c"
    out = tmp_path / "b"
    assert main(["bowling", "--seeds", "2", "--trials", "1", "--out", str(out), "--quiet", "--no-compare"]) == 0
    assert json.loads((out / "summary.json").read_text())["config"]["backend"] == "c"
